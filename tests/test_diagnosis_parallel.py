"""Fits prefetched in worker processes give the serial loop's result, bit for bit.

The oracle is the serial run (``n_jobs=1``: every fit in this process, one at a time).
Two cases, each with two candidates in round 1:

* a play PI whose offset wanders slowly over the record: creep fires and the driver
  scan keeps time, so the candidates are creep and a smooth term in time. Creep passes
  its gate and is challenged by the smooth term, which a worker has fitted meanwhile:
  the prefetched fit is used;
* a play PI whose gain follows a temperature column: the column's candidate (aux)
  comes first and is kept, so the next candidate, which a worker fitted meanwhile, is
  never reached and must leave no trace.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data import excitation
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.diagnosis import _workers, diagnose
from bayeshyst.errors import ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get as get_model

BASE = "pi_play(n_operators=3)"


def _wander() -> Dataset:
    """12 cycles at 2 Hz, 100 samples each; the offset wanders 1.5 times up and down."""
    model = get_model(BASE)
    rng = np.random.default_rng(0)
    t, u = excitation.sine(2.0, 200.0, cycles=12)
    theta = {**model.param_space(Record(t=t, u=u, y=u.copy())).fixed, "p0": 0.12,
             "w": np.array([0.05, 0.03, 0.02])}
    y = model.simulate(u, t, theta)
    y = y + 0.15 * np.sin(3 * np.pi * (t - t[0]) / np.ptp(t) + 0.2) \
        + 0.002 * np.ptp(y) * rng.standard_normal(t.size)
    rec = Record(t=t, u=u, y=y, warmup=100, metadata={"frequency_hz": 2.0}, name="wander")
    return Dataset((rec,), name="wander")


def _temperature() -> Dataset:
    """12 cycles at 2 Hz, 100 samples each; the gain follows a temperature column."""
    model = get_model(BASE)
    rng = np.random.default_rng(0)
    t, u = excitation.sine(2.0, 200.0, cycles=12)
    temp = 20.0 + 9.0 * np.sin(np.pi * (t - t[0]) / np.ptp(t))
    theta = {**model.param_space(Record(t=t, u=u, y=u.copy())).fixed, "p0": 0.12,
             "w": np.array([0.05, 0.03, 0.02])}
    y = model.simulate(u, t, theta) * (1.0 + 0.006 * (temp - temp.mean()))
    y = y + 0.002 * np.ptp(y) * rng.standard_normal(y.size)
    rec = Record(t=t, u=u, y=y, warmup=100, metadata={"frequency_hz": 2.0}, name="temp",
                 covariates={"temperature_c": temp})
    return Dataset((rec,), name="temp")


def _run(data, ckdir, n_jobs, on_fit, screen=True):
    return diagnose(data, BASE, sampler=SamplerSettings(n_walkers=16, max_steps=200,
                                                        first_chunk=100, seed=0),
                    n_draws=50, max_refits=0, max_candidates=2, max_rounds=1,
                    checkpoint_dir=ckdir, on_fit=on_fit, n_jobs=n_jobs, screen=screen)


@pytest.fixture
def workers_started(monkeypatch):
    """How many worker processes the loop started."""
    started = []
    real = _workers._Worker.__init__

    def init(self, ctx):
        started.append(ctx.get_start_method())
        real(self, ctx)

    monkeypatch.setattr(_workers._Worker, "__init__", init)
    return started


def _same(a, b):
    assert a.effects_found == b.effects_found
    assert [(s.effect, s.accepted, s.reason) for s in a.steps] == \
        [(s.effect, s.accepted, s.reason) for s in b.steps]
    assert a.warnings == b.warnings and a.final_model == b.final_model


def _check(one, result, fits, one_fits):
    _same(result, one)
    # the same fits reported, in the same order: none the loop did not reach
    assert [f.label for f in fits] == [f.label for f in one_fits]
    for a, b in zip(fits, one_fits, strict=True):
        assert np.array_equal(a.sampling.chains, b.sampling.chains), a.label
        assert np.array_equal(a.pointwise_elpd, b.pointwise_elpd), a.label
    assert np.array_equal(result.final.sampling.chains, one.final.sampling.chains)


def test_a_prefetched_challenger_gives_the_serial_result_and_its_exceptions(
        tmp_path, workers_started):
    data = _wander()
    made = []  # (fit, checkpoint files new after it), in the loop's order

    def watch(fit):
        old = {p for _, files in made for p in files}
        made.append((fit, sorted(set((tmp_path / "serial").iterdir()) - old)))

    # without the screen: creep is sampled, passes its gate on PSIS-LOO whose Pareto k
    # reaches 2.5 (no refits) and is challenged. The screen rejects it from its MAP --
    # rightly: left out, the first cycle's exact refit scores -386 nats, the screen's
    # own held-out Laplace -302, the PSIS value +77 (tests/test_diagnosis_screen.py)
    one = _run(data, tmp_path / "serial", 1, watch, screen=False)
    # the case: creep first, then the smooth term in time that challenges it and wins
    assert [s.effect for s in one.steps] == ["creep", "unexplained"], str(one)
    assert one.steps[0].reason.endswith("is not credited") and one.steps[1].accepted
    assert [t.effect for t in one.rounds[0].fired()] == ["creep"]
    assert one.rounds[0].drivers.selected[0].driver == "time"
    assert workers_started == []
    fits = []
    result = _run(data, tmp_path / "jobs2", 2, fits.append, screen=False)
    assert len(workers_started) == 1  # the challenger was fitted ahead
    _check(one, result, fits, [f for f, _ in made])

    # the challenger's checkpoint is not HDF5: its fit, made in a worker, raises in the
    # caller where the serial loop would, after the fits before it were reported
    fit, files = made[-1]
    assert fit.label.endswith("+unexplained(feature=time)") and files
    ckdir = tmp_path / "broken"
    ckdir.mkdir()
    for f in files:
        (ckdir / f.name).write_bytes(b"not a checkpoint")
    fits.clear()
    with pytest.raises(ParameterError, match="cannot be read as HDF5") as info:
        _run(data, ckdir, 2, fits.append, screen=False)
    assert len(workers_started) == 2
    assert isinstance(info.value.__cause__, _workers.WorkerTraceback)  # from a worker
    assert "Traceback" in str(info.value.__cause__)
    assert [f.label for f in fits] == [f.label for f, _ in made[:-1]]


def test_a_prefetched_fit_the_loop_does_not_reach_leaves_no_trace(tmp_path, workers_started):
    data = _temperature()
    serial_fits, fits = [], []
    one = _run(data, tmp_path / "serial", 1, serial_fits.append)
    # the case: the column's candidate is kept first, a second candidate is left
    assert [s.effect for s in one.steps] == ["aux"] and one.steps[0].accepted, str(one)
    assert len(serial_fits) == 2
    result = _run(data, tmp_path / "jobs2", 2, fits.append)
    assert len(workers_started) == 1  # the second candidate was fitted ahead
    _check(one, result, fits, serial_fits)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_n_jobs_must_be_a_positive_count(bad):
    with pytest.raises(ParameterError, match="n_jobs must be an integer >= 1"):
        diagnose(_wander(), BASE, n_jobs=bad)


def test_the_caller_takes_the_second_core_back_as_soon_as_the_worker_is_done():
    # sharing() asks at every kernel batch, not once per fit: serial while the worker
    # sleeps, parallel once it has sent its result (read or not)
    import time

    from bayeshyst.models import _kernels as kernels

    with _workers.Prefetcher(1, time.sleep) as pool, pool.sharing():
        pool.submit("nap", 1.0)
        assert pool.running() and not kernels.use_parallel(8, 10**9)
        deadline = time.monotonic() + 30.0
        while pool.running() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not pool.running() and kernels.use_parallel(8, 10**9)
        assert pool.take("nap") is None
