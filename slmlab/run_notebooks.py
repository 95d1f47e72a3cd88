"""Execute the notebooks top to bottom, each in a fresh kernel (nbclient): ``make reproduce`` and the tests.

``python -m slmlab.run_notebooks [--jobs N] NB.ipynb ...`` runs them (``N`` at a time, each in its own kernel),
with the working directory set to the notebook's folder, and fails (exit 1) if one raises. With
``--durations FILE`` (JSON, notebook name to seconds) the notebooks that took longest last time start first, and
the file is updated: two at a time, starting the longest last would leave one core idle at the end. A notebook
the file does not time (a fresh clone's first run) is placed by the seconds its metadata expects at full size
(``"slmlab": {"full_size_seconds": ...}``, a scheduling hint only: relative, from one machine). Outputs
are not written back: notebooks stay committed without outputs; what they produce goes to ``$SLMLAB_FIGURES``.
Each kernel's BLAS runs one thread (:data:`THREAD_VARIABLES`) and, on an x86-64 CPU with AVX2, the same
kernels (:func:`pinned_blas`), so that the figures' last digits do not depend on the CPU.
"""

from __future__ import annotations

import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from .io import atomic_write_text

__all__ = ["run_notebook", "longest_first", "expected_seconds", "main", "THREAD_VARIABLES", "BLAS_CORE",
           "pinned_blas"]

#: the thread counts of the numerical libraries a kernel loads (OpenBLAS, OpenMP, MKL, and OpenCV's own pool,
#: which reads ``OPENCV_FOR_THREADS_NUM`` when it loads), set to 1 unless given
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")


#: the OpenBLAS kernels (numpy's and SciPy's) a kernel uses on any x86-64 CPU with AVX2 and FMA: OpenBLAS picks
#: them by the CPU, and the sums of an AVX-512 Intel's kernels round differently from an AMD's, moving iterative
#: solves (a dot's fitted centre, a pinhole calibration) in the fifth significant digit and so a table's last one
BLAS_CORE = "Haswell"


def pinned_blas(cpuinfo: str | os.PathLike = "/proc/cpuinfo") -> dict:
    """``{"OPENBLAS_CORETYPE": BLAS_CORE}`` where the CPU can run those kernels (its flags, from ``cpuinfo``, hold
    ``avx2`` and ``fma``), else nothing (another CPU, or no such file: OpenBLAS chooses)."""
    try:
        flags = next((line.split(":", 1)[1].split() for line in Path(cpuinfo).read_text().splitlines()
                      if line.startswith("flags")), [])
    except (OSError, UnicodeDecodeError):
        return {}
    return {"OPENBLAS_CORETYPE": BLAS_CORE} if {"avx2", "fma"} <= set(flags) else {}


def run_notebook(path: str | os.PathLike, *, timeout_s: int = 900, env: dict | None = None) -> float:
    """Execute one notebook in a fresh ``python3`` kernel; return the wall time [s]. Raises on a failing cell."""
    import nbformat  # the notebook tools: needed only here, and the package's other users never load them
    from nbclient import NotebookClient  # (as above)

    path = Path(path)
    nb = nbformat.read(path, as_version=4)
    old = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    os.environ.setdefault("MPLBACKEND", "Agg")
    for var in THREAD_VARIABLES:  # notebooks run side by side, one core each: BLAS and OpenCV threads would fight
        os.environ.setdefault(var, "1")
    for var, value in pinned_blas().items():  # the same sums on every such CPU: the same figures
        os.environ.setdefault(var, value)
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


def longest_first(paths: list[Path], durations: dict[str, float]) -> list[Path]:
    """The notebooks by their last duration [s], longest first; those never timed first of all (in name order)."""
    return sorted(paths, key=lambda p: (p.name in durations, -durations.get(p.name, 0.0), p.name))


def expected_seconds(paths: list[Path]) -> dict[str, float]:
    """The full-size seconds each notebook's metadata expects (``metadata.slmlab.full_size_seconds``), for those
    that say: the order of a first run, before any duration is recorded."""
    out = {}
    for p in paths:
        try:
            hint = json.loads(p.read_text()).get("metadata", {}).get("slmlab", {}).get("full_size_seconds")
        except (OSError, ValueError, AttributeError):
            continue
        if isinstance(hint, (int, float)):
            out[p.name] = float(hint)
    return out


def _read_durations(path: Path | None) -> dict[str, float]:
    if path is None:
        return {}
    try:
        return {str(k): float(v) for k, v in json.loads(path.read_text()).items()}
    except (AttributeError, OSError, ValueError, TypeError):  # no file, or a damaged one: name order
        return {}


def main(argv: list[str] | None = None) -> int:
    """``[--timing FILE] [--durations FILE] [--jobs N] NOTEBOOK.ipynb ...``: run the notebooks, ``N`` at a time
    (each in its own kernel process), longest first by ``--durations``; write the wall time [s] to ``--timing``."""
    args = list(argv if argv is not None else sys.argv[1:])
    options = {"--timing": None, "--durations": None, "--jobs": "1"}
    while args[:1] and args[0] in options and len(args) > 1:
        options[args[0]], args = args[1], args[2:]
    timing, record = (Path(options[k]) if options[k] else None for k in ("--timing", "--durations"))
    jobs = max(1, int(options["--jobs"]))
    durations = _read_durations(record)
    paths = [Path(a) for a in args]
    paths = longest_first(paths, {**expected_seconds(paths), **durations})
    if not paths:
        print("usage: python -m slmlab.run_notebooks [--timing FILE] [--durations FILE] [--jobs N] NOTEBOOK.ipynb ...",
              file=sys.stderr)
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
            durations[futures[f].name] = round(dt, 1)
    total = time.perf_counter() - t0
    print(f"{len(paths)} notebooks in {total:.1f} s (wall time, {jobs} at a time)")
    if timing is not None:
        atomic_write_text(timing, f"{total:.1f}\n")
    if record is not None:
        atomic_write_text(record, json.dumps(dict(sorted(durations.items())), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
