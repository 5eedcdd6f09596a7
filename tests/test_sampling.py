"""MCMC: convergence diagnostics, prior recovery, conjugate oracle, determinism, resume."""

from __future__ import annotations

import itertools
import math
import os
import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import arviz as az
import emcee
import numpy as np
import pytest
from scipy import stats

from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.convergence import (
    _sorted_median,
    _sorted_quantile,
    assess,
    ess_bulk,
    ess_tail,
    hdi,
    integrated_time,
    rhat,
)
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import chunk_boundaries, sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from tests.synthetic import pi_data

ROOT = Path(__file__).resolve().parents[1]


def _ar_chains(phi, m=6, n=800, seed=0, shift=0.0):
    rng = np.random.default_rng(seed)
    x = np.zeros((m, n))
    e = rng.normal(size=(m, n))
    for k in range(1, n):
        x[:, k] = phi * x[:, k - 1] + e[:, k]
    x[0] += shift
    return x


@pytest.mark.parametrize(("phi", "shift"), [(0.0, 0.0), (0.6, 0.0), (0.95, 0.0), (0.5, 1.0)])
def test_rhat_and_ess_agree_with_arviz(phi, shift):
    x = _ar_chains(phi, shift=shift)
    assert rhat(x) == pytest.approx(float(az.rhat(x)), rel=1e-10)
    assert ess_bulk(x) == pytest.approx(float(az.ess(x, method="bulk")), rel=1e-8)
    assert ess_tail(x) == pytest.approx(float(az.ess(x, method="tail")), rel=1e-8)


def test_rhat_and_ess_agree_with_arviz_when_draws_tie():
    # rejected proposals repeat a value: ties must get their average rank
    x = np.round(_ar_chains(0.7, seed=5), 1)
    assert len(np.unique(x)) < x.size // 10
    assert rhat(x) == pytest.approx(float(az.rhat(x)), rel=1e-10)
    assert ess_bulk(x) == pytest.approx(float(az.ess(x, method="bulk")), rel=1e-8)
    assert ess_tail(x) == pytest.approx(float(az.ess(x, method="tail")), rel=1e-8)


def test_quantiles_and_medians_of_sorted_rows_are_numpys():
    # the tail ESS's indicators compare draws with these: the same arithmetic, bit for bit
    rng = np.random.default_rng(2)
    for n in (7, 8, 4512, 4513):
        x = np.round(rng.normal(size=(5, n)), 2)
        ordered = np.sort(x, axis=1)
        for q in (0.05, 0.5, 0.95):
            assert np.array_equal(_sorted_quantile(ordered, q), np.quantile(x, q, axis=1))
        assert np.array_equal(_sorted_median(ordered), np.median(x, axis=1))


@pytest.mark.parametrize("steps", [601, 600])
def test_assess_agrees_with_the_per_parameter_diagnostics(steps):
    # assess ranks each parameter once for both chain arrangements (walkers, ensembles)
    # and the bulk ESS; the oracle is the public per-parameter functions (checked against
    # arviz above) on the same kept draws, including a parameter with ties and one whose
    # ensembles disagree
    rng = np.random.default_rng(7)
    chains = []
    for e in range(2):
        c = rng.normal(size=(steps, 6, 3))
        c[:, :, 0] += 0.5 * np.cumsum(c[:, :, 0], axis=0) / np.arange(1, steps + 1)[:, None]
        c[:, :, 1] = np.round(c[:, :, 1])
        c[:, :, 2] += 1.0 * e
        chains.append(c)
    report = assess(chains)
    assert (steps - report.burn) % 2 == 0
    kept = [c[report.burn:] for c in chains]
    walkers = np.concatenate([c.transpose(1, 0, 2) for c in kept], axis=0)
    ensembles = np.stack([c.reshape(-1, 3) for c in kept])
    rh = [(rhat(walkers[:, :, d]), rhat(ensembles[:, :, d])) for d in range(3)]
    # the ensembles' disagreement shows most with each ensemble as one chain
    assert max(rh[2]) == rh[2][1] == max(max(r) for r in rh)
    assert report.rhat_max == pytest.approx(rh[2][1], rel=1e-12)
    assert report.ess_bulk_min == pytest.approx(
        min(ess_bulk(walkers[:, :, d]) for d in range(3)), rel=1e-10)
    assert report.ess_tail_min == pytest.approx(
        min(ess_tail(walkers[:, :, d]) for d in range(3)), rel=1e-10)


@pytest.mark.parametrize("where", [0, 2])
def test_a_parameter_that_never_moves_is_not_converged_wherever_it_is(where):
    # two well-mixed parameters and one the sampler never moved, first or last: the run
    # is not converged either way and the reason says why in words, with no NaN
    rng = np.random.default_rng(4)
    chain = rng.normal(size=(4000, 8, 3))
    chain[:, :, where] = 1.0
    report = assess([chain])
    assert not report.converged
    assert "R-hat undefined" in str(report) and "nan" not in str(report)
    chain[:, :, where] = rng.normal(size=(4000, 8))
    assert assess([chain]).converged


@pytest.mark.parametrize("values", ["whole", "thirds"])
@pytest.mark.parametrize("frozen", [0, 1])
def test_an_ensemble_that_never_moves_is_not_converged_in_either_order(frozen, values):
    # two ensembles of i.i.d. draws, one of them frozen at its start for the whole run:
    # its autocorrelation time is at least the chain (like a stuck walker's), so the
    # report is the same whichever ensemble comes first, it fails the length criterion,
    # and it is computed without a NaN time (which crashed the burn-in when the frozen
    # ensemble came first, and was dropped when it came second)
    rng = np.random.default_rng(11)
    steps = 400
    chains = [rng.normal(size=(steps, 8, 2)) for _ in range(2)]
    # frozen at whole numbers (their mean over steps is exact, the variance exactly 0)
    # or at thirds (the mean rounds, the variance is ~1e-30, not 0)
    start = np.arange(8.0)[None, :, None] + np.zeros((1, 1, 2))
    if values == "thirds":
        start = 0.1 + start / 3.0
    chains[frozen] = np.broadcast_to(start, chains[frozen].shape).copy()
    assert np.all(chains[frozen].mean(axis=0) == start[0]) == (values == "whole")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report = assess(chains)
        swapped = assess(chains[::-1])
    assert not report.converged
    assert report.tau_max == swapped.tau_max == steps // 2  # the kept half, frozen
    assert report.burn == steps // 2
    assert f"< 50 tau = {50 * (steps // 2)}" in str(report)
    # both frozen: nothing moved; undefined in words, no exception
    chains[1 - frozen] = chains[frozen].copy()
    report = assess(chains)
    assert not report.converged and "nan" not in str(report)


def test_integrated_time_agrees_with_emcee_and_hdi_with_arviz():
    rng = np.random.default_rng(3)
    walk = np.cumsum(rng.normal(size=(3000, 16, 2)), axis=0)
    chain = 0.02 * walk + rng.normal(size=(3000, 16, 2))
    np.testing.assert_allclose(integrated_time(chain),
                               emcee.autocorr.integrated_time(chain, tol=0), rtol=1e-10)
    x = rng.gamma(2.0, size=5000)
    np.testing.assert_allclose(hdi(x, 0.9), az.hdi(x, hdi_prob=0.9), rtol=1e-12)


def test_chunk_boundaries_are_fixed_and_cover_the_budget():
    assert chunk_boundaries(100, 1000) == [100, 150, 200, 250, 312, 390, 487, 608, 760, 950,
                                           1000]
    assert chunk_boundaries(500, 300) == [300]
    b = chunk_boundaries(100, 20_000)  # a quarter apart, at least first // 2
    assert b[-1] == 20_000 and all(
        max(50, a // 4) == c - a for a, c in itertools.pairwise(b[:-1]))


def test_prior_only_sampling_reproduces_the_prior():
    # beta = 0: the sampler must return the prior; this checks every transform and
    # log-Jacobian on the way (K-S per parameter against the prior's cdf)
    model, rec, _ = pi_data()
    post = Posterior(rec, model, beta=0.0)
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    # start from the prior itself: the Laplace ball of a flat-ish prior is the prior
    res = sample_posterior(post, SamplerSettings(seed=1, max_steps=3000, first_chunk=500),
                           start=start)
    theta = res.theta()
    thin = max(1, int(res.convergence.tau_max))
    for p in post.space.params:
        x = np.asarray(theta[p.name]).reshape(theta[p.name].shape[0], -1)[::thin * 8, 0]
        assert stats.kstest(x, p.prior.cdf).pvalue > 1e-3, p.name


def test_emcee_agrees_with_the_conjugate_posterior_of_pi_weights():
    model, rec, theta = pi_data(n_ops=3, sigma=0.05)
    fixed = Posterior(rec, model).fix("noise.sigma", 0.05)  # known sigma, as the closed form
    exact = conjugate_posterior(fixed)
    res = sample_posterior(fixed, SamplerSettings(seed=2, max_steps=8000, first_chunk=1000))
    assert res.converged, res.convergence
    draws = res.flat_z  # Normal priors -> identity transforms: z is the value
    ess = res.convergence.ess_bulk_min
    se = exact.sd / np.sqrt(ess)
    np.testing.assert_array_less(np.abs(draws.mean(axis=0) - exact.mean), 5 * se)
    # covariance: standard deviations within 10 %, correlations within 0.05
    sd = draws.std(axis=0, ddof=1)
    np.testing.assert_allclose(sd, exact.sd, rtol=0.1)
    corr = np.corrcoef(draws.T)
    ref = exact.cov / np.outer(exact.sd, exact.sd)
    np.testing.assert_allclose(corr, ref, atol=0.05)
    # and the truth is inside the 99.9 % ellipsoid of the exact posterior
    truth = np.concatenate([[theta["p0"]], theta["w"], [0.4]])
    d = truth - exact.mean
    assert d @ np.linalg.solve(exact.cov, d) < stats.chi2.ppf(0.999, truth.size)


def _small_run(checkpoint=None, seed=5, moves="structured", model=None, flush_seconds=2.0):
    model_, rec, _ = pi_data(n_ops=2, n=600, warmup=100)
    post = Posterior(rec, model or model_)
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    return sample_posterior(post, SamplerSettings(seed=seed, max_steps=400, first_chunk=100,
                                                  checkpoint=checkpoint, min_ess=1e9,
                                                  moves=moves, flush_seconds=flush_seconds),
                             start=start)


def test_same_seed_same_chains_other_seed_other_chains():
    a, b, c = _small_run(seed=5), _small_run(seed=5), _small_run(seed=6)
    np.testing.assert_array_equal(a.chains, b.chains)
    assert not np.array_equal(a.chains, c.chains)
    assert not a.converged and "ESS" in str(a.convergence)  # min_ess=1e9 cannot be met


@pytest.mark.parametrize("moves", ["structured", "de"])
def test_resume_after_sigkill_gives_the_uninterrupted_draws(tmp_path, moves):
    ck = tmp_path / "run.h5"
    child = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(ROOT)!r})
        import tests.test_sampling as T
        from bayeshyst.inference.checkpoint import CheckpointBackend
        calls = {{"n": 0}}
        orig = CheckpointBackend.save_step
        def killing(self, state, accepted):
            calls["n"] += 1
            if calls["n"] == 530:  # mid-run (second ensemble, second chunk), with
                # unflushed steps in memory
                os.kill(os.getpid(), signal.SIGKILL)
            return orig(self, state, accepted)
        CheckpointBackend.save_step = killing
        T._small_run(checkpoint={str(ck)!r}, moves={moves!r})
    """)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", child], env=env, capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    import h5py

    with h5py.File(ck, "r") as f:
        done = [int(f[f"ensemble_{e}"].attrs["iteration"]) for e in range(2)]
    assert 0 < min(done) and max(done) < 400  # it really stopped part-way
    resumed = _small_run(checkpoint=ck, moves=moves)
    whole = _small_run(moves=moves)
    assert resumed.convergence.n_steps == whole.convergence.n_steps
    np.testing.assert_array_equal(resumed.chains, whole.chains)
    np.testing.assert_array_equal(resumed.log_prob, whole.log_prob)
    assert resumed.move_acceptance == whole.move_acceptance


def test_a_checkpoint_locked_by_a_reader_delays_the_flush_and_loses_nothing(tmp_path,
                                                                           monkeypatch):
    # a user opening the checkpoint while the run goes on holds its HDF5 lock: a write
    # that meets the lock (BlockingIOError) waits it out -- the run neither dies nor
    # loses or reorders a step
    orig, calls = emcee.backends.HDFBackend.open, {"a": 0, "refused": 0}

    def locked(self, mode="r"):
        if mode == "a":
            calls["a"] += 1
            if calls["a"] % 40 in (3, 4):  # two of every 40 appends meet the lock
                calls["refused"] += 1
                raise BlockingIOError(11, "Resource temporarily unavailable")
        return orig(self, mode)

    monkeypatch.setattr(emcee.backends.HDFBackend, "open", locked)
    ck = tmp_path / "run.h5"
    whole = _small_run()
    res = _small_run(checkpoint=ck, flush_seconds=1e-9)  # flush at every step
    monkeypatch.undo()
    assert calls["refused"] >= 10
    np.testing.assert_array_equal(res.chains, whole.chains)
    resumed = _small_run(checkpoint=ck)  # everything was written: nothing is resampled
    np.testing.assert_array_equal(resumed.chains, whole.chains)


def test_checkpoint_of_another_run_is_refused(tmp_path):
    from bayeshyst.errors import ParameterError

    ck = tmp_path / "run.h5"
    _small_run(checkpoint=ck, seed=5)
    with pytest.raises(ParameterError, match="different run"):
        _small_run(checkpoint=ck, seed=6)


def test_a_checkpoint_sampled_in_another_coordinate_is_refused(tmp_path, monkeypatch):
    # the same model, priors and data, but the exponent sampled in the logit coordinate it
    # had before: its z are other numbers, so resuming would reinterpret every draw
    import bayeshyst.models.bouc_wen as bw
    from bayeshyst.errors import ParameterError
    from bayeshyst.params import LogitTransform
    from bayeshyst.selection.tasks import fit_identity

    _, rec, _ = pi_data(n_ops=2, n=400, warmup=50)
    settings = SamplerSettings(seed=1, max_steps=60, first_chunk=60, min_ess=1e9,
                               checkpoint=tmp_path / "run.h5")
    probit = Posterior(rec, "bouc_wen")
    assert probit.space.declared_transforms.startswith("n: ProbitTransform")
    with monkeypatch.context() as m:
        m.setattr(bw, "_N_TRANSFORM", LogitTransform(1.0, bw.N_MAX))
        logit = Posterior(rec, "bouc_wen")
        assert logit.space.declared_transforms == ""  # the prior's default coordinate
        assert str(logit.space) == str(probit.space)  # the table cannot tell them apart
        assert fit_identity(logit, settings) != fit_identity(probit, settings)
        sample_posterior(logit, settings, start=find_map(logit, seed=0, n_starts=1))
    with pytest.raises(ParameterError, match=r"different run.*transforms"):
        sample_posterior(probit, settings, start=find_map(probit, seed=0, n_starts=1))


class _Payload:
    """Unpickling this creates a file: the proof that a loader ran the file's code."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


@pytest.mark.parametrize("where", ["file", "group"])
def test_a_checkpoint_with_a_pickled_attribute_is_refused_unopened(tmp_path, where):
    import pickle

    import h5py

    from bayeshyst.errors import ParameterError

    ck, sentinel = tmp_path / "run.h5", tmp_path / "code_ran"
    _small_run(checkpoint=ck, seed=5)
    blob = np.void(pickle.dumps(_Payload(sentinel)))
    with h5py.File(ck, "a") as f:
        # the pickled format's names: the file's metadata, or an ensemble's last step
        (f.attrs if where == "file" else f["ensemble_0"].attrs)[
            "bayeshyst_meta" if where == "file" else "checkpoint"] = blob
    with pytest.raises(ParameterError, match="pickled"):
        _small_run(checkpoint=ck, seed=5)
    assert not sentinel.exists()


def test_a_checkpoint_holds_no_pickle_and_its_metadata_round_trips(tmp_path):
    import h5py

    from bayeshyst.inference.checkpoint import read_meta, write_meta

    ck = tmp_path / "run.h5"
    _small_run(checkpoint=ck, seed=5)
    found = []
    with h5py.File(ck, "r") as f:
        def visit(name, obj):
            found.extend(f"{name}/{k}" for k, v in obj.attrs.items()
                         if isinstance(v, np.void) or np.asarray(v).dtype.kind == "O")
        visit("", f)
        f.visititems(visit)
    assert found == []  # every attribute is a number, an array of numbers or text
    meta = {"a": np.arange(6.0).reshape(2, 3), "b": (1, "x", None), "c": -math.inf,
            "d": {"e": np.array(True), "f": np.float64(0.1)}}
    write_meta(tmp_path / "m.h5", meta)
    back = read_meta(tmp_path / "m.h5")
    np.testing.assert_array_equal(back["a"], meta["a"])
    assert back["a"].dtype == float and back["b"] == [1, "x", None] and back["c"] == -math.inf
    assert back["d"]["e"].dtype == bool and back["d"]["f"] == 0.1


def test_fit_sampler_names_a_fit_by_what_it_is_and_its_seed(tmp_path):
    from bayeshyst.selection.tasks import fit_identity, fit_sampler

    model, rec, _ = pi_data(n_ops=2, n=600, warmup=100)
    base = SamplerSettings(max_steps=200)
    a = fit_sampler(Posterior(rec, model), base, 1, tmp_path)
    again = fit_sampler(Posterior(rec, "pi_play(n_operators=2)"), base, 1, tmp_path)
    other_seed = fit_sampler(Posterior(rec, model), base, 2, tmp_path)
    assert a.checkpoint == again.checkpoint and a.seed == again.seed  # same posterior
    assert other_seed.checkpoint != a.checkpoint and other_seed.seed != a.seed
    assert fit_identity(Posterior(rec, model, "ar1"), base) != fit_identity(
        Posterior(rec, model), base)
    # a second seed into the same folder is another run, not a clash with the first
    for s in (a, other_seed):
        post = Posterior(rec, model)
        sample_posterior(post, s, start=find_map(post, seed=0, n_starts=1))
    assert len(list(tmp_path.glob("*.h5"))) == 2
    # the de engine's walker floor applies to every command fitting that posterior
    de = fit_sampler(Posterior(rec, model), base.replace(moves="de", n_walkers=4), 1, tmp_path)
    assert de.n_walkers == 2 * Posterior(rec, model).ndim + 2


@pytest.mark.parametrize("moves", ["structured", "de", "stretch"])
def test_a_coordinate_every_starting_walker_shares_still_reaches_its_posterior(moves):
    # oracle: the conjugate posterior of the PI weights at known sigma. Every walker
    # starts at the same, deliberately wrong value of p0 (3 sd off its mean, as a
    # candidate's new parameter set at a score test's estimate); ensemble moves move
    # along walker differences, so without drawing it apart p0 would never move (emcee
    # refuses such a start for its own moves; the structured ones skip that check, and
    # stalled silently). The likelihood is tempered (beta = 1/2) so that the structured
    # moves have no exact linear block and p0 is theirs to move; at known sigma that is
    # the Gaussian posterior with sigma / sqrt(beta)
    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    fixed = Posterior(rec, model, beta=0.5).fix("noise.sigma", 0.05)
    exact = conjugate_posterior(Posterior(rec, model).fix("noise.sigma", 0.05 / math.sqrt(0.5)))
    start = find_map(fixed, seed=0, global_search=False, n_screen=64, n_starts=1)
    rng = np.random.default_rng(3)
    walkers = exact.mean + rng.standard_normal((64, exact.mean.size)) * exact.sd
    walkers[:, 0] = exact.mean[0] + 3 * exact.sd[0]
    res = sample_posterior(fixed, SamplerSettings(seed=4, max_steps=8000, first_chunk=1000,
                                                  moves=moves),
                           start=start, initial=walkers)
    assert res.converged, res.convergence
    p0 = res.flat_z[:, 0]
    se = exact.sd[0] / np.sqrt(res.convergence.ess_bulk_min)
    assert abs(p0.mean() - exact.mean[0]) < 5 * se
    np.testing.assert_allclose(p0.std(ddof=1), exact.sd[0], rtol=0.1)


def test_walkers_without_a_shared_coordinate_are_returned_as_given():
    # the repair must not touch an ensemble that needs none (a checkpoint started from
    # it keeps its identity); with one shared coordinate only that coordinate changes,
    # and its new spread is the Laplace conditional's (oracle: a Gaussian posterior's
    # conditional sd, 1 / sqrt(P_00))
    from bayeshyst.inference.optimize import spread_shared_coordinates

    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    fixed = Posterior(rec, model).fix("noise.sigma", 0.05)
    start = find_map(fixed, seed=0, global_search=False, n_screen=64, n_starts=1)
    rng = np.random.default_rng(0)
    chol = np.linalg.cholesky(start.covariance)
    walkers = start.z + rng.standard_normal((4000, start.z.size)) @ chol.T
    same, shared = spread_shared_coordinates(fixed, start, walkers,
                                             np.arange(fixed.ndim), rng)
    assert same is walkers and shared.size == 0
    walkers[:, 1] = start.z[1]
    out, shared = spread_shared_coordinates(fixed, start, walkers,
                                            np.arange(fixed.ndim), rng)
    assert shared.tolist() == [1] and out.shape == walkers.shape
    np.testing.assert_array_equal(np.delete(out, 1, axis=1), np.delete(walkers, 1, axis=1))
    cond_sd = 1 / np.sqrt(np.linalg.inv(start.covariance)[1, 1])
    # 4000 draws: the sd's relative se is 1.1 %; 5 % is over 4 se
    np.testing.assert_allclose(out[:, 1].std(ddof=1), cond_sd, rtol=0.05)
    # and a coordinate left to an exact Gibbs draw is not touched
    walkers[:, 2] = start.z[2]
    out, shared = spread_shared_coordinates(fixed, start, walkers, np.array([0, 2]), rng)
    assert shared.tolist() == [2] and np.all(out[:, 1] == start.z[1])
