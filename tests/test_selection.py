"""Model selection per frequency on data with a known truth, and on measured data.

The truth is a Hammerstein actuator — a 4-operator play-PI hysteresis followed by a
second-order resonance at 250 Hz (damping 0.2, first-order hold) — observed with white
sensor noise of 0.1 % of the stroke, at 1 Hz (quasi-static: the resonance is invisible)
and 80 Hz (the resonance amplifies the loop by ~10 % and delays it by ~7 degrees). Candidates: the
generating hysteresis family alone (static PI), another static family (Bouc-Wen), the
generating Hammerstein (rate-dependent) and the Gaussian process.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bayeshyst.models as M
from bayeshyst.data import Dataset, Record
from bayeshyst.inference.posterior import cycle_units
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.base import DataScales
from bayeshyst.selection import compare_models

STATIC = "pi_play(n_operators=4)"
HAMMERSTEIN = "pi_play(n_operators=4)+second_order"
OTHER = "bouc_wen"


def _hammerstein_data(freqs=(1.0, 80.0), sigma=0.04, per_cycle=100, cycles=4, seed=0):
    model = M.get(HAMMERSTEIN)
    space = model.param_space(DataScales(0.0, 150.0, 0.0, 40.0))
    r = space.fixed["static.r"]
    theta = {"static.p0": 0.17, "static.w": np.array([0.06, 0.04, 0.03, 0.02]),
             "static.r": r, "second_order.f_n": 250.0, "second_order.zeta": 0.2}
    recs = []
    for i, f in enumerate(freqs):
        t = np.arange(cycles * per_cycle) / (per_cycle * f)
        u = 75 - 75 * np.cos(2 * np.pi * f * t)
        y = model.simulate(u, t, theta)
        y = y + np.random.default_rng([seed, i]).normal(0.0, sigma, t.size)
        recs.append(Record(t=t, u=u, y=y, name=f"h{f:g}", warmup=per_cycle,
                           metadata={"frequency_hz": f}))
    return Dataset(tuple(recs), name="hammerstein")


@pytest.fixture(scope="module")
def comparison():
    data = _hammerstein_data()
    # the default budget: a ranking of posteriors that did not converge is not a result
    # (with 1 500 steps and 24 walkers, Bouc-Wen's per-frequency fits did not)
    return compare_models(data, [STATIC, OTHER, HAMMERSTEIN, "gp"],
                          sampler=SamplerSettings(seed=1), lofo=False, max_refits=0,
                          draws_per_chain=40, gp_n_train=300, n_jobs=2)


def test_every_fit_ranked_converged(comparison):
    assert [t.spec.key for t in comparison.tasks if not t.converged] == []


def test_generating_family_first_at_low_frequency(comparison):
    low = comparison.per_frequency[0]
    assert low.frequency_hz == 1.0
    # the quasi-static loop: the generating PI family ranks first; its static form is
    # as good (within two standard errors: the resonance is invisible at 1 Hz), the
    # other static family is significantly worse
    assert low.best in (STATIC, HAMMERSTEIN), str(low)
    static = low.score(STATIC)
    assert -static.delta_elpd <= 2 * static.delta_se or static.delta_elpd == 0.0, str(low)
    other = low.score(OTHER)
    assert -other.delta_elpd > 2 * other.delta_se, str(low)


def test_rate_dependent_model_overtakes_static_ones_at_high_frequency(comparison):
    high = comparison.per_frequency[-1]
    assert high.frequency_hz == 80.0
    # a rate-dependent model ranks first (the Hammerstein or the GP on (u, du/dt))
    assert high.best in (HAMMERSTEIN, "gp"), str(high)
    hammer = high.score(HAMMERSTEIN)
    for static in (STATIC, OTHER):
        s = high.score(static)
        # the Hammerstein is significantly ahead of every static model: more than two
        # standard errors of the paired difference
        d, se = comparison.difference(HAMMERSTEIN, static, 80.0)
        assert d == pytest.approx(hammer.elpd_loo - s.elpd_loo)
        assert d > 2 * se, (static, d, se, str(high))
        assert s.nrmse_percent > hammer.nrmse_percent
    # over all frequencies jointly one parameter set must serve both: dynamics win
    assert comparison.overall.best == HAMMERSTEIN
    d, se = comparison.difference(HAMMERSTEIN, STATIC, joint=True)
    assert d > 2 * se


def test_gp_and_parametric_models_share_the_table(comparison):
    for fc in (*comparison.per_frequency, comparison.overall):
        gp = fc.score("gp")
        assert gp.error is None and math.isfinite(gp.elpd_loo)
        assert gp.n_cycles == fc.score(STATIC).n_cycles
        assert sum(s.weight for s in fc.scores) == pytest.approx(1.0, abs=1e-9)
        assert math.isnan(gp.bic) and math.isfinite(fc.score(STATIC).bic)
    text = str(comparison)
    assert "gp" in text and HAMMERSTEIN in text


def test_same_seed_same_numbers_whatever_the_workers():
    data = _hammerstein_data(freqs=(2.0, 20.0), cycles=3, per_cycle=60)
    kw = dict(sampler=SamplerSettings(max_steps=200, first_chunk=100, n_walkers=16, seed=7),
              max_refits=0, draws_per_chain=10, n_lofo_draws=50)
    a = compare_models(data, [STATIC], n_jobs=1, **kw)
    b = compare_models(data, [STATIC], n_jobs=2, **kw)
    for fa, fb in zip((*a.per_frequency, a.overall), (*b.per_frequency, b.overall),
                      strict=True):
        assert fa.scores[0].elpd_loo == fb.scores[0].elpd_loo
        assert fa.scores[0].elpd_lofo == fb.scores[0].elpd_lofo or (
            math.isnan(fa.scores[0].elpd_lofo) and math.isnan(fb.scores[0].elpd_lofo))


def _timed_task(data, spec, settings, seed, out_dir):
    """Stands in for run_task in the pool's workers: notes when it ran."""
    import time

    from bayeshyst.selection.tasks import TaskResult

    t0 = time.time()
    time.sleep(0.3)
    (out_dir / f"{spec.key}.t").write_text(f"{t0} {time.time()}")
    return TaskResult(spec, np.zeros(0), np.zeros(0), ())


def test_tasks_fitting_one_posterior_do_not_run_at_once(monkeypatch, tmp_path):
    # with two frequencies, leaving one out fits the other's records: the same posterior,
    # the same checkpoint file, which two workers must not write at the same time
    import bayeshyst.selection.compare as sel
    from bayeshyst.selection.tasks import CompareSettings

    monkeypatch.setattr(sel, "run_task", _timed_task)
    data = _hammerstein_data(freqs=(2.0, 20.0), cycles=3, per_cycle=60)
    tasks = sel._tasks((STATIC, OTHER), [2.0, 20.0], True)
    settings = CompareSettings(sampler=SamplerSettings(max_steps=100))
    # a worker per task: without the scheduling every task would start at once
    done = sel._run_all(data, tasks, settings, 0, tmp_path, len(tasks), None)
    assert set(done) == set(tasks)
    identity = sel._shared_fits(data, tasks, settings)
    assert len(set(identity.values())) == 2 * 3  # per model: joint and one per frequency
    when = {t: tuple(map(float, (tmp_path / f"{t.key}.t").read_text().split())) for t in tasks}
    for a in tasks:
        for b in tasks:
            if a != b and identity[a] == identity[b]:
                assert when[a][1] <= when[b][0] or when[b][1] <= when[a][0], (a.key, b.key)


# ----------------------------------------------------------------- measured MR damper
def _decimated(rec, per_cycle=80, cycles=3.5):
    f = rec.frequency_hz
    step = max(1, round(rec.fs / (per_cycle * f)))
    n = min(rec.n, int(cycles * rec.fs / f) + 1)
    idx = np.arange(0, n, step)
    return Record(t=rec.t[idx], u=rec.u[idx], y=rec.y[idx], name=rec.name,
                  warmup=round(rec.warmup / step), metadata=dict(rec.metadata),
                  units=dict(rec.units))


# slow (an end-to-end comparison on measured data, 2.5 min)
@pytest.mark.slow
def test_mr_damper_comparison_runs_end_to_end(shared_data_dir, tmp_path):
    from bayeshyst.data.measured import load_mr_damper
    from bayeshyst.outputs.assemble import comparison_figures
    from bayeshyst.outputs.compare_outputs import write_comparison_outputs

    mr = load_mr_damper(shared_data_dir, current_a=0.5, frequency_hz=[0.1, 1.0, 5.0])
    data = Dataset(tuple(_decimated(r) for r in mr), name="mr_damper_0.5A")
    res = compare_models(data, ["bouc_wen", "pi_play(n_operators=6)", "gp_memory"],
                         sampler=SamplerSettings(max_steps=400, first_chunk=200,
                                                 n_walkers=20),
                         lofo=False, max_refits=0, draws_per_chain=10, gp_n_train=200,
                         n_jobs=2)
    summary = write_comparison_outputs(res, tmp_path, data_path="mr_damper",
                                       figures=comparison_figures(res))
    assert [e["frequency_hz"] for e in summary["per_frequency"]] == [0.1, 1.0, 5.0]
    for entry in summary["per_frequency"]:
        assert entry["best"] in {"bouc_wen", "pi_play(n_operators=6)", "gp_memory"}
        assert entry["statement"].startswith(f"{entry['frequency_hz']:g} Hz: "
                                             f"{entry['best']} ranks first")
        assert all(r["elpd_loo"] is not None for r in entry["ranking"])
    assert (tmp_path / "compare.png").exists()
    print("\n".join(summary["statements"]))


def test_single_frequency_and_unknown_frequency_groups():
    data = _hammerstein_data(freqs=(2.0, 30.0), cycles=3, per_cycle=60)
    kw = dict(sampler=SamplerSettings(max_steps=100, first_chunk=100, n_walkers=16),
              max_refits=0, draws_per_chain=5, n_lofo_draws=20, n_jobs=1)
    one = compare_models(data[0], [STATIC], **kw)
    # one frequency: the joint fit is the per-frequency fit, and nothing is held out
    assert [fc.frequency_hz for fc in one.per_frequency] == [2.0]
    assert len(one.tasks) == 1 and one.settings["lofo"] is False
    s = one.per_frequency[0].score(STATIC)
    assert s.elpd_loo == one.overall.score(STATIC).elpd_loo
    assert math.isnan(s.elpd_lofo) and s.weight == 1.0
    assert s.n_cycles == len(cycle_units(data[0]))
    # a record without a frequency forms its own group, listed last
    bare = data[1].with_(metadata={})
    mixed = compare_models(Dataset((data[0], bare)), [STATIC], **kw)
    assert [fc.frequency_hz for fc in mixed.per_frequency] == [2.0, None]
    assert [fc.label for fc in mixed.per_frequency] == ["2 Hz", "unknown"]
    assert math.isfinite(mixed.per_frequency[1].score(STATIC).elpd_lofo)
    assert mixed.overall.score(STATIC).n_cycles == sum(len(cycle_units(r)) for r in data)


def test_a_failing_fit_is_recorded_and_ranked_last(monkeypatch):
    import bayeshyst.selection.tasks as tasks
    from bayeshyst.errors import SimulationError

    real = tasks._run_parametric

    def flaky(data, spec, settings, seed, out_dir):
        if spec.model == OTHER and spec.scope == "frequency" and spec.frequency_hz == 20.0:
            raise SimulationError("integrator blew up (simulated failure)")
        return real(data, spec, settings, seed, out_dir)

    monkeypatch.setattr(tasks, "_run_parametric", flaky)
    data = _hammerstein_data(freqs=(2.0, 20.0), cycles=3, per_cycle=60)
    res = compare_models(data, [STATIC, OTHER],
                         sampler=SamplerSettings(max_steps=100, first_chunk=100, n_walkers=16),
                         max_refits=0, draws_per_chain=5, n_lofo_draws=20, n_jobs=1,
                         lofo=False)
    assert len(res.failed) == 1 and "integrator blew up" in res.failed[0].error
    at20 = res.per_frequency[1]
    assert [s.model for s in at20.scores] == [STATIC, OTHER]
    bad = at20.score(OTHER)
    assert "integrator blew up" in bad.error and bad.weight == 0.0
    assert math.isnan(bad.elpd_loo) and at20.score(STATIC).weight == 1.0
    # the other frequency and the joint row are untouched
    assert res.per_frequency[0].score(OTHER).error is None
    assert res.to_dict()["failed_fits"] == [res.failed[0].error]


# ------------------------------------------------------------------ virtual actuator
PREISACH = "preisach_density(n_grid=32)"
PREISACH_DYN = "preisach_density(n_grid=32)+second_order"


@pytest.fixture(scope="module")
def virtual_comparison():
    """The virtual actuator (independent simulator): asymmetric Preisach hysteresis, a
    250 Hz resonance (damping 0.2), white sensor noise 0.04 um; creep, drift and delay
    off. Its hysteresis belongs to the Preisach family; PI and Bouc-Wen loops are
    point-symmetric and cannot follow its asymmetry."""
    from bayeshyst.data.excitation import sine
    from bayeshyst.data.virtual import AR1Noise, SecondOrder, VirtualActuator

    act = VirtualActuator(creep=None, drift=None, delay=None,
                          noise=AR1Noise(rms_um=0.04, phi=0.0),
                          dynamics=SecondOrder(resonance_hz=250.0, damping=0.2))
    recs = []
    for i, f in enumerate((1.0, 80.0)):
        t, u = sine(f, 100 * f, cycles=4)
        recs.append(act.record(t, u, rng=i, name=f"v{f:g}", warmup=100, frequency_hz=f))
    return compare_models(Dataset(tuple(recs), name="virtual"),
                          [PREISACH, OTHER, "pi_play(n_operators=6)", PREISACH_DYN, "gp"],
                          sampler=SamplerSettings(max_steps=1500, first_chunk=500,
                                                  n_walkers=24, seed=1),
                          lofo=False, max_refits=0, draws_per_chain=40, gp_n_train=300,
                          n_jobs=2)


# slow (its comparison fixture alone took 10 min); the generating family's win stays in
# the default run through test_generating_family_first_at_low_frequency
@pytest.mark.slow
def test_virtual_actuator_generating_family_first_at_low_frequency(virtual_comparison):
    low = virtual_comparison.per_frequency[0]
    assert low.best in (PREISACH, PREISACH_DYN), str(low)
    static = low.score(PREISACH)
    assert -static.delta_elpd <= 2 * static.delta_se or static.delta_elpd == 0.0, str(low)
    for other in (OTHER, "pi_play(n_operators=6)"):
        d, se = virtual_comparison.difference(low.best, other, 1.0)
        assert d > 2 * se, (other, d, se, str(low))


# slow (shares the 10-min comparison above)
@pytest.mark.slow
def test_virtual_actuator_dynamics_win_at_high_frequency(virtual_comparison):
    high = virtual_comparison.per_frequency[-1]
    assert high.best in (PREISACH_DYN, "gp"), str(high)
    for static in (PREISACH, OTHER, "pi_play(n_operators=6)"):
        d, se = virtual_comparison.difference(PREISACH_DYN, static, 80.0)
        assert d > 2 * se, (static, d, se, str(high))
    assert virtual_comparison.overall.best == PREISACH_DYN
