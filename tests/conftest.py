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


# property-based tests: at least 300 examples locally; in CI fewer, and the same ones every run
from hypothesis import HealthCheck, settings  # noqa: E402

_examples = int(os.environ.get("SLMLAB_HYPOTHESIS_EXAMPLES", "0")) or None
settings.register_profile("ci", max_examples=_examples or 40, derandomize=True, deadline=None,
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
settings.register_profile("dev", max_examples=_examples or 300, deadline=None,
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
from hypothesis import Phase  # noqa: E402

settings.register_profile("debug", max_examples=_examples or 60, deadline=None, print_blob=True,
                          phases=[Phase.explicit, Phase.reuse, Phase.generate],
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
settings.load_profile(os.environ.get("SLMLAB_HYPOTHESIS_PROFILE") or ("ci" if os.environ.get("CI") else "dev"))
