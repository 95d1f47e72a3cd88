import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("SLMLAB_SHARED", REPO.parent / "shared"))


@pytest.fixture(scope="session")
def paper_set():
    """A Test 1 calibration set of the paper preset (seed 1), in memory."""
    import slmlab

    return slmlab.simulate_set(slmlab.preset("paper"), slmlab.paper_test(1), seed=1)


@pytest.fixture
def set_dir(tmp_path, paper_set):
    """The same set written to a folder."""
    import slmlab

    return slmlab.write_set(tmp_path / "set", paper_set)
