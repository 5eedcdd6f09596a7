"""An unconverged fit of the diagnosis is sampled again with twice the steps, on from its end.

The oracle is a convergence rule imposed on the real sampler: its runs are recorded and
their ``converged`` flag is set by the step budget alone (converged from ``need`` steps
on), so the test knows which runs the loop must make, with which budgets and
checkpoints, and which steps it may decide.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bayeshyst.data import excitation
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.diagnosis import _fitting, diagnose
from bayeshyst.errors import ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get as get_model

BASE = "pi_play(n_operators=2)"
STEPS = 100
TINY = SamplerSettings(max_steps=STEPS, first_chunk=STEPS, n_walkers=16, progress=False)


def _drifting() -> Dataset:
    """Two sines from the base model with a gain drift of 8 % (drift fires on the base)."""
    model = get_model(BASE)
    recs = []
    for i, f in enumerate((1.0, 2.0)):
        t, u = excitation.sine(f, 100.0 * f, cycles=6)
        proto = Record(t=t, u=u, y=u.copy(), warmup=100)
        theta = dict(model.param_space(proto).fixed)
        theta.update({"p0": 0.5, "w": np.array([0.08, 0.05])})
        y = model.simulate(u, t, theta) * (1.0 + 0.08 * t / t[-1])
        y = y + 0.002 * np.random.default_rng(i).standard_normal(y.size)
        recs.append(Record(t=t, u=u, y=y, warmup=100, name=f"sine_{f:g}Hz",
                           metadata={"frequency_hz": f}))
    return Dataset(tuple(recs), name="drifting")


@pytest.fixture(scope="module")
def data() -> Dataset:
    return _drifting()


def _converging_from(monkeypatch, need: int, calls: list | None = None
                     ) -> list[SamplerSettings]:
    """Record every run of the sampler; a run converges iff its budget is >= ``need``.

    ``calls``, when given, gets each run's keyword arguments and result.
    """
    runs: list[SamplerSettings] = []
    real = _fitting.sample_posterior

    def sample(post, settings, **kw):
        runs.append(settings)
        res = real(post, settings, **kw)
        conv = dataclasses.replace(res.convergence, converged=settings.max_steps >= need)
        res = dataclasses.replace(res, convergence=conv)
        if calls is not None:
            calls.append((kw, res))
        return res

    monkeypatch.setattr(_fitting, "sample_posterior", sample)
    return runs


def _run(data, tmp_path, **kw):
    # screen=False: what is tested is how a sampled candidate's budget grows (the screen
    # would reject this drift from its MAP, and nothing would be sampled)
    return diagnose(data, BASE, effects=("drift",), max_rounds=1, max_candidates=1,
                    sampler=TINY, n_draws=20, max_refits=0, n_permutations=0,
                    checkpoint_dir=tmp_path, screen=False, **kw)


def test_an_unconverged_fit_is_sampled_again_with_twice_the_steps(data, tmp_path,
                                                                   monkeypatch):
    calls: list = []
    runs = _converging_from(monkeypatch, 2 * STEPS, calls)
    result = _run(data, tmp_path)
    (step,) = result.steps  # drift fired on the base and was refitted
    # every fit: once at the budget, once at twice it, each with its own seed and file
    assert [r.max_steps for r in runs] == [STEPS, 2 * STEPS] * 2
    for first, second in (runs[0:2], runs[2:4]):
        assert first.checkpoint != second.checkpoint and first.seed != second.seed
        assert first.checkpoint.exists() and second.checkpoint.exists()
    # the longer run goes on from the short one's last walkers, each ensemble from its
    # own, and from the start the short one ended with
    for (_, short), (kw, _) in (calls[0:2], calls[2:4]):
        np.testing.assert_array_equal(kw["walkers"], short.chains[:, -1])
        assert kw["start"] is short.start and "initial" not in kw
    assert result.base.converged and step.converged, step.reason
    assert step.outcome in ("accepted", "rejected"), step.reason
    assert any(f"did not converge within {STEPS} steps; sampled again with {2 * STEPS}"
               in w for w in result.base.warnings), result.base.warnings
    assert not any("within its budget" in w for w in result.warnings)
    # a rerun into the same folder resumes both runs of both fits: the same decision
    again = _run(data, tmp_path)
    assert [r.max_steps for r in runs[4:]] == [STEPS, 2 * STEPS] * 2
    assert str(again.steps[0]) == str(step)


def test_a_fit_that_needs_more_than_the_doublings_is_not_decided(data, tmp_path,
                                                                  monkeypatch):
    runs = _converging_from(monkeypatch, 4 * STEPS + 1)
    result = _run(data, tmp_path, budget_doublings=2)
    assert [r.max_steps for r in runs] == [STEPS, 2 * STEPS, 4 * STEPS] * 2
    (step,) = result.steps
    assert not result.base.converged and not step.converged, step.reason
    assert step.outcome == "not decided", step.reason
    assert any(f"did not converge within its budget ({4 * STEPS} steps)" in w
               for w in result.base.warnings), result.base.warnings


@pytest.mark.parametrize("kw", [{"budget_doublings": 0}, {"decide_unconverged": True}])
def test_no_second_run_without_doublings_or_when_unconverged_fits_decide(data, tmp_path,
                                                                         monkeypatch, kw):
    runs = _converging_from(monkeypatch, 2 * STEPS)
    result = _run(data, tmp_path, **kw)
    assert [r.max_steps for r in runs] == [STEPS, STEPS]
    (step,) = result.steps
    assert (step.outcome == "not decided") is not kw.get("decide_unconverged", False)


@pytest.mark.parametrize("bad", [-1, 1.5, True, "1"])
def test_budget_doublings_must_be_a_count(data, bad):
    with pytest.raises(ParameterError, match="budget_doublings must be an integer >= 0"):
        diagnose(data, BASE, sampler=TINY, budget_doublings=bad)


@pytest.mark.parametrize("bad", [-1, 1.5, True])
def test_the_reports_budget_doublings_must_be_a_count(bad):
    from bayeshyst.workflow import ReportSettings

    with pytest.raises(ParameterError, match="budget_doublings must be an integer >= 0"):
        ReportSettings(budget_doublings=bad)
