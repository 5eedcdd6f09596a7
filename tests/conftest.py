"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from bayeshyst.errors import DataError

SHARED_DATA_SKIP = (
    "../shared/data not found: measured-data tests need the shared folder beside the checkout"
)


@pytest.fixture(scope="session")
def shared_data_dir() -> Path:
    """The shared measured-data folder, or skip the test when it is absent."""
    from bayeshyst.data.measured import shared_data_root

    try:
        return shared_data_root()
    except DataError:
        pytest.skip(SHARED_DATA_SKIP)
