"""Execute the notebooks top to bottom, each in a fresh kernel (nbclient): ``make reproduce`` and the tests.

``python -m slmlab.notebooks NB.ipynb ...`` runs them in the order given, with the working directory set to
the notebook's folder, and fails (exit 1) at the first notebook that raises. Outputs are not written back:
notebooks stay committed without outputs; what they produce goes to ``$SLMLAB_FIGURES``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

__all__ = ["run_notebook", "main"]


def run_notebook(path: str | os.PathLike, *, timeout_s: int = 900, env: dict | None = None) -> float:
    """Execute one notebook in a fresh ``python3`` kernel; return the wall time [s]. Raises on a failing cell."""
    import nbformat
    from nbclient import NotebookClient

    path = Path(path)
    nb = nbformat.read(path, as_version=4)
    old = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    os.environ.setdefault("MPLBACKEND", "Agg")
    try:
        t0 = time.perf_counter()
        NotebookClient(nb, timeout=timeout_s, kernel_name="python3",
                       resources={"metadata": {"path": str(path.parent.resolve())}}).execute()
        return time.perf_counter() - t0
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def main(argv: list[str] | None = None) -> int:
    args = list(argv if argv is not None else sys.argv[1:])
    timing = None
    if args[:1] == ["--timing"] and len(args) > 1:  # write the total wall time [s] to this file
        timing, args = Path(args[1]), args[2:]
    paths = sorted(args)
    if not paths:
        print("usage: python -m slmlab.notebooks NOTEBOOK.ipynb ...", file=sys.stderr)
        return 2
    total = 0.0
    for p in paths:
        print(f"running {p} ...", flush=True)
        try:
            dt = run_notebook(p)
        except Exception as exc:  # noqa: BLE001 - report which notebook failed, then fail
            print(f"FAILED {p}: {type(exc).__name__}: {str(exc)[-2000:]}", file=sys.stderr)
            return 1
        total += dt
        print(f"  done in {dt:.1f} s", flush=True)
    print(f"{len(paths)} notebooks in {total:.1f} s")
    if timing is not None:
        timing.write_text(f"{total:.1f}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
