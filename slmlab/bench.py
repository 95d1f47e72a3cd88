"""``python -m slmlab bench``: speed beside the field's reference implementations, in one process.

Each line gives our time, the reference's time on the same work, their ratio and the target. Timings are
the best of several repeats (``time.perf_counter``), single-threaded NumPy/OpenCV as on a 2-core machine.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["BenchLine", "best_time", "run"]


@dataclass
class BenchLine:
    name: str
    ours_s: float
    reference: str
    reference_s: float
    target: str
    met: bool

    @property
    def ratio(self) -> float:
        """Reference time over our time (above 1: we are faster)."""
        return self.reference_s / self.ours_s if self.ours_s > 0 else float("inf")


def best_time(fn, repeat: int = 5) -> float:
    """Best wall time of ``repeat`` calls of ``fn()`` [s]."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _bench_simulate() -> BenchLine:
    import cv2

    from .simulate import paper_test, preset, simulate_set

    m = preset("paper")
    session = paper_test(1)
    ours = best_time(lambda: simulate_set(m, session, seed=0), repeat=5)
    # reference: OpenCV projecting the same number of points through a pinhole + distortion model, both views
    n = int(sum(len(v) for v in session.stage_positions().values() for _ in [0]) * 49 + 27 * 29)
    pts = np.random.default_rng(0).normal(size=(n, 3)) + [0, 0, 300.0]
    K = np.array([[1e5, 0, 1024], [0, 1e5, 1024], [0, 0, 1.0]])
    dist = np.array([0.01, 0.0, 1e-4, 1e-4, 0.0])
    rvec, tvec = np.zeros(3), np.zeros(3)
    ref = best_time(lambda: [cv2.projectPoints(pts, rvec, tvec, K, dist) for _ in range(2)], repeat=5)
    return BenchLine(f"simulate Test 1 set, points mode ({n} dots x 2 views, with noise and truth)", ours,
                     "cv2.projectPoints, same number of points, 2 views (projection only)", ref,
                     "well under 1 s", ours < 0.5)


BENCHES = [_bench_simulate]


def machine() -> str:
    import os

    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, NumPy {np.__version__}"


def run(as_json: bool = False) -> int:
    """Run every benchmark and print a table (or JSON); return 0."""
    import cv2

    cv2.setNumThreads(1)
    lines = [b() for b in BENCHES]
    if as_json:
        print(json.dumps({"machine": machine(),
                          "lines": [{**asdict(l), "ratio": l.ratio} for l in lines]}, indent=2))
        return 0
    print(f"machine: {machine()}")
    print(f"{'benchmark':<70} {'ours [s]':>10} {'ref [s]':>10} {'ref/ours':>9}  target")
    for l in lines:
        print(f"{l.name:<70} {l.ours_s:10.4f} {l.reference_s:10.4f} {l.ratio:9.2f}  {l.target}"
              f" ({'met' if l.met else 'NOT met'})")
        print(f"{'  reference: ' + l.reference}")
    return 0
