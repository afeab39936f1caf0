"""Shared fixtures: the shared/ folder beside the checkout (real data), skipping cleanly;
the test process's thread settings."""

import os
from pathlib import Path

import pytest
from hypothesis import settings

# One BLAS / OpenMP thread, as experiments.sweep.run sets for its workers: the tests' linear
# algebra is on tiny matrices (3x3 expm, 6x6 inverses), where worker threads only contend
# for the cores; on this 2-core machine under load they made the identification tests 4x
# slower (19.6 s -> 4.8 s for tests/test_identification.py). Set before numpy is imported
# (pytest loads this file first); a value in the environment wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# Property tests (hypothesis) draw the same examples on every run, so a test run (and CI)
# is reproducible: a failure is a change of the code, not of the draw. To look for new
# failing examples, run with HYPOTHESIS_PROFILE=explore (fresh random examples on each run;
# run it a few times) and pin what it finds with @example.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REALDATA = SHARED / "realdata"


@pytest.fixture
def realdata_dir() -> Path:
    """../shared/realdata, or skip the test when it is absent."""
    if not REALDATA.is_dir():
        pytest.skip("../shared/realdata is absent (real-receiver logs are not in the repo)")
    return REALDATA
