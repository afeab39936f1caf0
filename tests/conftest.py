"""Shared fixtures: the shared/ folder beside the checkout (real data), skipping cleanly."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REALDATA = SHARED / "realdata"


@pytest.fixture
def realdata_dir() -> Path:
    """../shared/realdata, or skip the test when it is absent."""
    if not REALDATA.is_dir():
        pytest.skip("../shared/realdata is absent (real-receiver logs are not in the repo)")
    return REALDATA
