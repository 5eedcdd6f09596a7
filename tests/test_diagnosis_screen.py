"""The diagnosis' screen: a candidate's held-out score from its MAP, and what it may decide.

Oracles: an exact leave-one-cycle-out refit (the posterior without the cycle, sampled)
for a cycle that moves a creep posterior far; the error bounds the rule states; and the
gate's own arithmetic for the decision.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from bayeshyst.diagnosis.screen import ERROR_BOUNDS, _margin, screen_candidate
from bayeshyst.diagnosis.verdict import MIN_GATE_UNITS
from bayeshyst.diagnostics.laplace_loo import laplace_loo
from bayeshyst.inference.held_out import held_out_start
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get
from bayeshyst.selection.tasks import _refit_log_predictive
from tests.test_diagnosis_parallel import BASE, _wander


def test_the_margin_adds_each_cycles_bound_and_refuses_an_unreliable_one():
    assert ERROR_BOUNDS == ((0.5, 0.1), (0.7, 1.0))
    assert _margin(np.array([0.1, -0.3, 0.5])) == pytest.approx(0.3)
    assert _margin(np.array([0.2, 0.6, 0.7])) == pytest.approx(2.1)
    assert _margin(np.array([0.2, 0.71])) == math.inf
    assert _margin(np.array([0.2, np.nan])) == math.inf


def test_a_cycle_that_moves_a_creep_posterior_is_scored_like_its_exact_refit():
    # a play PI whose offset wanders over the record, fitted with creep: left out, the
    # first cycle's offset is the creep's extrapolation, and the fit predicts it badly.
    # PSIS on the full posterior's draws cannot see that (k ~ 2.5, +77 nats); the
    # screen scores it from the held-out posterior's own Laplace approximation, which
    # must land near the exact refit (measured: -302 against -386; PSIS is 460 off)
    data = _wander()
    post = Posterior(data, get(f"{BASE}+creep"))
    start = find_map(post, seed=0)
    res = laplace_loo(post, start, n_draws=1000, seed=0)
    assert 0 in res.refitted and res.reliable
    held = post.holding_out([0])
    refit = sample_posterior(held, SamplerSettings(seed=2, max_steps=4000),
                             start=held_out_start(held, start, 0))
    assert refit.converged
    full = SimpleNamespace(start=start)
    exact = _refit_log_predictive(post, full, refit.draws(400, seed=0), 0)
    assert exact < -200  # the case: the cycle is predicted very badly when left out
    assert abs(res.pointwise[0] - exact) < 0.3 * abs(exact), (res.pointwise[0], exact)
    # the other cycles move the posterior little: the screen agrees with plain PSIS
    plain = laplace_loo(post, start, n_draws=1000, seed=0, refit_above=None)
    others = [i for i in range(post.n_units) if i not in res.refitted]
    np.testing.assert_allclose(res.pointwise[others], plain.pointwise[others])


@pytest.fixture(scope="module")
def creep_args():
    """``diagnosis_fit``'s arguments for creep on the wandering record, and its settings."""
    from bayeshyst.diagnosis.records import DiagnosisSettings

    st = DiagnosisSettings(sampler=SamplerSettings(seed=0, max_steps=200, n_walkers=16))
    return (_wander(), get(f"{BASE}+creep"), "gaussian", "creep", st, None)


def _current(pointwise):
    return SimpleNamespace(pointwise_elpd=np.asarray(pointwise, dtype=float))


def test_the_screen_rejects_only_past_the_gate_with_its_error_given(creep_args):
    scr, prep = screen_candidate(creep_args, _current(np.zeros(10)), 2.0)
    assert prep.start is not None and prep.post.n_units == 10
    d, se, m = scr.delta_elpd, scr.delta_se, scr.margin
    assert scr.loo.reliable and math.isfinite(m)
    # the gate's arithmetic against a current fit made to sit just either side of it:
    # every cycle shifted by c changes d by -10 c and leaves se as it is
    for shift, rejects in ((-(2 * se - d - m) / 10 - 1.0, False),
                           ((d + m - 2 * se) / 10 + 1.0, True)):
        cur = _current(np.full(10, shift))
        again, _ = screen_candidate(creep_args, cur, 2.0)
        assert again.delta_se == pytest.approx(se)
        assert again.rejects is rejects, (again, shift)
    assert "screen of creep" in str(scr) and scr.to_dict()["reliable"] is True


def test_the_screen_does_not_judge_fewer_cycles_than_the_gate_needs(creep_args):
    data, model, *rest = creep_args
    short = data.__class__((data.records[0].slice(0, 700),), name="short")
    n = Posterior(short, model).n_units
    assert n < MIN_GATE_UNITS
    scr, _ = screen_candidate((short, model, *rest), _current(np.full(n, 1e6)), 2.0)
    assert scr.delta_elpd < 0 and not scr.rejects  # would lose, but the gate cannot tell


def test_the_loop_rejects_from_the_screen_and_samples_the_rest(tmp_path):
    # the wandering record: creep fires first. Its screen rejects it (left out, the first
    # cycle is predicted hundreds of nats worse: see above), so it is not sampled and
    # does not use the round's one candidate; the smooth term in time is sampled and
    # kept, as the full loop keeps it after creep's challenge
    from bayeshyst.diagnosis import diagnose

    fits = []
    result = diagnose(_wander(), BASE, sampler=SamplerSettings(n_walkers=16, max_steps=200,
                                                               first_chunk=100, seed=0),
                      n_draws=50, max_refits=0, max_candidates=1, max_rounds=1,
                      on_fit=fits.append, n_jobs=1, screen=True)
    creep, smooth = result.steps
    assert (creep.effect, creep.decided_by, creep.accepted) == ("creep", "screen", False)
    assert "screened out at its MAP" in creep.reason and creep.added_parameters == ()
    assert creep.delta_elpd < 0 and creep.model_after.endswith("+creep")
    assert smooth.effect == "unexplained" and smooth.accepted and smooth.decided_by == "elpd"
    # the base and the smooth term were sampled, creep never
    assert [f.label for f in fits] == [result.base.label, smooth.model_after]
    assert result.effects_found == ("unexplained",)
    row = result.to_dict()["steps"][0]
    assert row["decided_by"] == "screen"
