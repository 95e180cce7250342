import os

import pytest

from polarref.data import data_root


@pytest.fixture(scope="session")
def shared_data():
    """The reference data folder; tests needing it skip with the reason when absent."""
    root = data_root()
    if root is None:
        where = os.environ.get("POLARREF_DATA") or "../shared/data beside the repo root"
        pytest.skip(f"reference data not found ({where}); set $POLARREF_DATA")
    return root
