"""``compensate`` in a process pool gives exactly the serial result, rows in order.

Oracle: the serial, in-process evaluation (``n_jobs=1``) of the same references with
the same seed; every reference draws from its own random streams, so the pool may not
change a single bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.errors import ParameterError
from bayeshyst.inference.fit import fit_model
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.compensate import compensate
from bayeshyst.workers import process_pool, resolve_jobs
from tests.test_compensate import HYSTERESIS_ONLY, loops

SAMPLER = SamplerSettings(max_steps=150, n_walkers=16, seed=3)
SMALL = {"cycles": 1, "n_design_draws": 4, "n_predict_draws": 12, "n_plants": 6}


@pytest.fixture(scope="module")
def fitted():
    data = loops(HYSTERESIS_ONLY, [1.0, 4.0, 9.0], samples_per_cycle=60, cycles=3)
    return data, fit_model(data, "pi_play(n_operators=3)+creep(n_terms=2)", sampler=SAMPLER)


def assert_identical(a, b):
    assert a.to_dict() == b.to_dict()
    assert [r.label for r in a.rows] == [r.label for r in b.rows]
    for ra, rb in zip(a.rows, b.rows, strict=True):
        assert ra.curves.keys() == rb.curves.keys()
        for key in ra.curves:
            np.testing.assert_array_equal(ra.curves[key], rb.curves[key], err_msg=key)


@pytest.mark.parametrize("plant", [None, "posterior"], ids=["virtual", "posterior"])
def test_two_workers_give_the_serial_result_bit_for_bit(fitted, plant):
    data, fit = fitted
    serial = compensate(data, fit.posterior.model, fit=fit, sampler=SAMPLER, plant=plant,
                        n_jobs=1, **SMALL)
    pooled = compensate(data, fit.posterior.model, fit=fit, sampler=SAMPLER, plant=plant,
                        n_jobs=2, **SMALL)
    assert [r.frequency_hz for r in pooled.rows] == [1.0, 4.0, 9.0]  # reference order
    assert_identical(serial, pooled)


def test_job_counts_are_checked():
    assert resolve_jobs(1) == 1
    assert resolve_jobs(8, n_tasks=3) == 3
    assert resolve_jobs(None) >= 1
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ParameterError, match="n_jobs"):
            resolve_jobs(bad)
    with pytest.raises(ParameterError, match="n_jobs"):
        with process_pool(0):
            pass


def test_a_pool_returns_results_in_input_order():
    with process_pool(2) as pool:
        assert list(pool.map(abs, [-3, 1, -2, 5])) == [3, 1, 2, 5]


def test_the_environment_caps_the_default_number_of_processes(monkeypatch):
    from bayeshyst.workers import JOBS_ENV, default_jobs

    monkeypatch.delenv(JOBS_ENV, raising=False)
    cores = default_jobs()
    monkeypatch.setenv(JOBS_ENV, "1")
    assert default_jobs() == 1 and resolve_jobs(None) == 1
    assert resolve_jobs(2) == 2          # an explicit request is the caller's
    monkeypatch.setenv(JOBS_ENV, str(cores + 5))
    assert default_jobs() == cores       # a cap, never more than the cores
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(JOBS_ENV, bad)
        with pytest.raises(ParameterError, match=JOBS_ENV):
            default_jobs()
