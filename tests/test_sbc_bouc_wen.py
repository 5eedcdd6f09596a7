"""Simulation-based calibration of the structured sampler on Bouc–Wen.

The same check as tests/test_sbc.py (whose docstring states the statistics), in a file of
its own so that pytest-xdist runs it beside the play-PI replicates instead of after them.
"""

from __future__ import annotations

import pytest

from tests.test_sbc import _run


# slow (19 min of the default run on 2 loaded cores); Bouc-Wen's calibration stays in
# the default run through tests/test_recovery.py
@pytest.mark.slow
def test_sbc_ranks_are_uniform():
    _run("bouc_wen", replicates=20, bins=4)


@pytest.mark.slow
def test_sbc_ranks_are_uniform_100_replicates():
    _run("bouc_wen", replicates=100, bins=10)
