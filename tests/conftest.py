"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import numba
import pytest
from threadpoolctl import threadpool_limits

from bayeshyst.errors import DataError

if os.environ.get("PYTEST_XDIST_WORKER"):
    # each xdist worker has a core of its own: numba's thread team on top of that puts
    # four threads on two cores, and a parallel kernel then waits for descheduled
    # threads (a second-order block measured 20x slower than its serial loop that way)
    numba.set_num_threads(1)
    # the same for OpenBLAS: its team of two per worker spins on a core the other worker
    # holds (a discrepancy's Gram measured 2-3x slower with the second core busy)
    threadpool_limits(1, user_api="blas")
    # and for bayeshyst's own process pools (the comparison's fits, the diagnosis'
    # fits ahead of its loop, the feedforward's references): the workers already hold
    # every core, and speculative fits on top of them only take CPU from the other
    # worker's tests. Tests that exercise a pool ask for n_jobs=2 explicitly.
    os.environ.setdefault("BAYESHYST_JOBS", "1")

#: Files that take far longer than the rest, run first: with ``--dist loadfile`` a file
#: runs whole on one worker, and the simulation-based calibration (20 replicates of each
#: model, alphabetically near the end) otherwise ran alone on one worker for the last
#: half of the run while the other worker was idle (measured: 10 of 20 minutes on a slow
#: day); its two models are two files, so the two workers start one each.
LONG_FILES = ("test_sbc_bouc_wen.py", "test_sbc.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Put the long files first (a stable sort: the order within a file is kept)."""
    rank = {name: i for i, name in enumerate(LONG_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


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
