"""Shared fixtures. Expensive fixtures are session-scoped, also in the test modules: on an xdist worker the tests of
several modules interleave, and a module-scoped fixture would be torn down and built again each time its module's
tests resume (a 34 s rendered set was built twice)."""

import os

import pytest


@pytest.fixture(scope="session")
def paper_set():
    """A Test 1 calibration set of the paper preset (seed 1), in memory."""
    import slmlab

    return slmlab.simulate_set(slmlab.preset("paper"), slmlab.paper_test(1), seed=1)


@pytest.fixture(scope="session")
def dataset_folder():
    """``dataset_folder(name)``: the registered dataset's folder (:func:`slmlab.datasets.fetch`, every file
    SHA-256 checked, fetched once per session); the test is skipped, with the one-line reason, when the dataset
    cannot be had here (no cache, no mirror, no network)."""
    from slmlab import SlmlabError, datasets

    folders = {}

    def get(name: str):
        if name not in folders:
            try:
                folders[name] = datasets.fetch(name)
            except SlmlabError as exc:
                folders[name] = exc
        if isinstance(folders[name], SlmlabError):
            pytest.skip(f"dataset {name} is not available: {folders[name]}")
        return folders[name]

    return get


@pytest.fixture
def set_dir(tmp_path, paper_set):
    """The same set written to a folder."""
    import slmlab

    return slmlab.write_set(tmp_path / "set", paper_set)


def pytest_configure(config):
    """On a pytest-xdist worker (make test: one per core), OpenCV and OpenBLAS on one thread, as calibrate
    already runs: their thread pools would only compete with the other workers (5-7 % of the CPU time of the
    in-process tests on two cores). Subprocesses (the command line, the notebooks' kernels) keep the defaults."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        from slmlab.models.base import one_thread

        one_thread().__enter__()  # for the worker's whole life


def pytest_collection_modifyitems(config, items):
    """The slow tests first, each group in its own order: on several workers (make test) the long ones (the
    notebooks, the property tests) start early and the short ones fill in at the end, so that no worker is left
    running a long test while the others idle."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


# property-based tests (hypothesis). Profiles, chosen by SLMLAB_HYPOTHESIS_PROFILE:
#   quick     the default (make test, CI or not): 40 examples per test, derandomised, the same ones every run
#   thorough  make test-thorough: 300 examples per test, new ones each run (failures are replayed from .hypothesis/)
#   debug     60 examples, prints the blob that reproduces a failure
# SLMLAB_HYPOTHESIS_EXAMPLES=N overrides the number of examples of any profile.
from hypothesis import HealthCheck, Phase, settings  # noqa: E402

_examples = int(os.environ.get("SLMLAB_HYPOTHESIS_EXAMPLES", "0")) or None
_lenient = {"deadline": None, "suppress_health_check": [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]}
settings.register_profile("quick", max_examples=_examples or 40, derandomize=True, **_lenient)
settings.register_profile("thorough", max_examples=_examples or 300, **_lenient)
settings.register_profile("debug", max_examples=_examples or 60, print_blob=True,
                          phases=[Phase.explicit, Phase.reuse, Phase.generate], **_lenient)
settings.load_profile(os.environ.get("SLMLAB_HYPOTHESIS_PROFILE") or "quick")
