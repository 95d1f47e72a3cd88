"""Execute the notebooks top to bottom, each in a fresh kernel (nbclient): ``make reproduce`` and the tests.

``python -m slmlab.run_notebooks [--jobs N] NB.ipynb ...`` runs them (``N`` at a time, each in its own kernel),
with the working directory set to the notebook's folder, and fails (exit 1) if one raises. Outputs are not written back:
notebooks stay committed without outputs; what they produce goes to ``$SLMLAB_FIGURES``.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

__all__ = ["run_notebook", "main", "THREAD_VARIABLES"]

#: the thread counts of the numerical libraries a kernel loads (OpenBLAS, OpenMP, MKL), set to 1 unless given
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_notebook(path: str | os.PathLike, *, timeout_s: int = 900, env: dict | None = None) -> float:
    """Execute one notebook in a fresh ``python3`` kernel; return the wall time [s]. Raises on a failing cell."""
    import nbformat  # the notebook tools: needed only here, and the package's other users never load them
    from nbclient import NotebookClient  # (as above)

    path = Path(path)
    nb = nbformat.read(path, as_version=4)
    old = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    os.environ.setdefault("MPLBACKEND", "Agg")
    for var in THREAD_VARIABLES:  # notebooks run side by side, one core each: BLAS threads would fight over them
        os.environ.setdefault(var, "1")
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
    """``[--timing FILE] [--jobs N] NOTEBOOK.ipynb ...``: run the notebooks, ``N`` at a time (each in its own
    kernel process), and write the wall time [s] to ``FILE``."""
    args = list(argv if argv is not None else sys.argv[1:])
    timing, jobs = None, 1
    while args[:1] in (["--timing"], ["--jobs"]) and len(args) > 1:
        if args[0] == "--timing":  # write the total wall time [s] to this file
            timing = Path(args[1])
        else:
            jobs = max(1, int(args[1]))
        args = args[2:]
    paths = sorted(args)
    if not paths:
        print("usage: python -m slmlab.run_notebooks [--timing FILE] [--jobs N] NOTEBOOK.ipynb ...", file=sys.stderr)
        return 2

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(run_notebook, p): p for p in paths}
        for f in as_completed(futures):
            try:
                dt = f.result()
            except Exception as exc:  # noqa: BLE001 - report which notebook failed, then fail
                print(f"FAILED {futures[f]}: {type(exc).__name__}: {str(exc)[-2000:]}", file=sys.stderr)
                for g in futures:
                    g.cancel()
                return 1
            print(f"{futures[f]} done in {dt:.1f} s", flush=True)
    total = time.perf_counter() - t0
    print(f"{len(paths)} notebooks in {total:.1f} s (wall time, {jobs} at a time)")
    if timing is not None:
        timing.write_text(f"{total:.1f}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
