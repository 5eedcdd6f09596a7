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

#: The files that take longest (summed test durations measured 2026-12-07, slowest
#: first; benchmarks/RESULTS.md), run first. With ``--dist loadfile`` a file runs whole
#: on one worker; started last, a long one runs alone while the other worker idles (the
#: simulation-based calibration once did so for 10 of 20 minutes). Scheduling only: a
#: file missing here runs after these, in collection order. ``--no-loadscope-reorder``
#: (pyproject) keeps xdist from re-sorting the files by their number of tests.
LONG_FILES = ("test_diagnosis.py", "test_sampling.py", "test_selection.py",
              "test_analyses.py", "test_report.py", "test_analyses_predict_unseen.py",
              "test_compensate.py", "test_fit_cli.py", "test_diagnosis_verdict.py",
              "test_diagnosis_parallel.py", "test_discrepancy.py", "test_bouc_wen.py",
              "test_inverse.py", "test_recovery.py", "test_compare_cli.py")


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
