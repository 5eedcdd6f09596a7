"""Model selection per excitation frequency: :func:`compare_models`.

The question a user asks is not only "which model fits my loops best" but "which model
will hold at a frequency I did not fit". For every model and every excitation
frequency ``f`` in the data the comparison therefore fits

- the records at ``f`` alone → PSIS-LOO with cycles as the left-out unit (Pareto k
  reported, exact refits for k > 0.7), WAIC, BIC at the MAP, tracking error;
- every record but those at ``f`` → the **leave-one-frequency-out** (LOFO) log
  predictive density of the cycles at ``f``: extrapolation in frequency, the test a
  rate-independent model fails when the dynamics matter;

and, once, all records together → the joint row (PSIS-LOO over all cycles, also
reported per frequency as ``elpd_joint``: one set of parameters for every frequency).
Models are ranked at each frequency by ``elpd_loo``; ``Δelpd`` and its standard error
are paired over the same cycles (Vehtari, Gelman & Gabry 2017, §5.2); stacking weights
(Yao et al. 2018) combine the models' pointwise predictive densities.

Independent (model, scope) fits run in parallel worker processes; each task derives
its seed from the user's seed and its own identity, so the numbers do not depend on
the number of workers or the order in which tasks finish.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, wait
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.groups import Band, band_of, frequency_of, group_label
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ModelError, ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.likelihoods import get_likelihood
from bayeshyst.selection.ranking import rank_by_elpd, total_and_se
from bayeshyst.selection.results import (
    ComparisonResult,
    FrequencyComparison,
    ModelScore,
    cycles_at,
)
from bayeshyst.selection.tasks import (
    CompareSettings,
    TaskResult,
    TaskSpec,
    build_spec,
    fit_identity,
    is_parametric,
    run_task,
    split_data,
)
from bayeshyst.workers import process_pool, resolve_jobs

__all__ = [
    "check_models",
    "compare_models",
    "split_top_level",
]


# ---------------------------------------------------------------------- orchestration
def split_top_level(text: str) -> list[str]:
    """Split at commas outside parentheses (specs carry settings: ``pi_play(n_operators=4)``)."""
    parts, depth, cur = [], 0, []
    for ch in text:
        depth += (ch == "(") - (ch == ")")
        if ch == "," and depth == 0:
            parts.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur).strip())
    return parts


def check_models(models: Sequence[str] | str) -> tuple[str, ...]:
    """Validated model specs, from a list or one comma-separated string.

    Every spec must build (:func:`~bayeshyst.selection.tasks.build_spec`: a parametric
    model, or a GP for ``gp`` and ``gp_memory``; ``ModelError`` names the bad one), and
    no spec may appear twice.
    """
    if isinstance(models, str):
        models = split_top_level(models)
    names = tuple(str(m).strip() for m in models)
    if not names or any(not m for m in names):
        raise ModelError(f"models: expected a non-empty list of model specs, got {models!r}")
    dup = sorted({m for m in names if names.count(m) > 1})
    if dup:
        raise ModelError(f"models: {dup} listed more than once")
    for m in names:
        build_spec(m)  # raises ModelError naming the unknown part of the spec
    return names


def _tasks(models: tuple[str, ...], keys: list[Any], lofo: bool) -> list[TaskSpec]:
    out = []
    for m in models:
        out.append(TaskSpec(m, "joint"))
        if len(keys) > 1:
            out += [TaskSpec.at(m, "frequency", f) for f in keys]
            if lofo:
                out += [TaskSpec.at(m, "lofo", f) for f in keys]
    return out


def _shared_fits(data: Dataset, tasks: list[TaskSpec],
                 settings: CompareSettings) -> dict[TaskSpec, str]:
    """The fit identity of every parametric task.

    Tasks whose data or model cannot be set up here are left out: they fail in their
    worker, with their own message.

    Tasks with one identity sample one posterior into one checkpoint (with two
    frequencies, leaving one out fits the other's records), so they must not run at the
    same time: the second one reads the first one's finished run instead.
    """
    from bayeshyst.inference.posterior import Posterior

    out = {}
    for spec in tasks:
        try:
            model = build_spec(spec.model)
            if not is_parametric(model):  # a GP samples no posterior of records
                continue
            train, _ = split_data(data, spec)
            post = Posterior(train, model, settings.likelihood)
        except (DataError, ModelError, ParameterError, ValueError):
            continue
        out[spec] = fit_identity(post, settings.sampler)
    return out


def _run_all(data: Dataset, tasks: list[TaskSpec], settings: CompareSettings, seed: int,
             out_dir: Path | None, n_jobs: int,
             report: Callable[[int, int, TaskResult], None] | None) -> dict[TaskSpec, TaskResult]:
    done: dict[TaskSpec, TaskResult] = {}
    # the costliest fits first, so that the pool does not end waiting on one of them
    order = sorted(tasks, key=lambda s: {"joint": 0, "lofo": 1, "frequency": 2}[s.scope])
    if n_jobs <= 1 or len(tasks) == 1:
        for spec in order:
            done[spec] = run_task(data, spec, settings, seed, out_dir)
            if report:
                report(len(done), len(tasks), done[spec])
        return done
    # a task whose fit another task makes (same identity, same checkpoint) waits for it
    identity = _shared_fits(data, order, settings) if out_dir is not None else {}
    waiting: dict[str, list[TaskSpec]] = {}
    first = []
    for spec in order:
        key = identity.get(spec)
        if key is not None and key in waiting:
            waiting[key].append(spec)
        else:
            first.append(spec)
            if key is not None:
                waiting[key] = []
    with process_pool(n_jobs) as pool:
        pending = {pool.submit(run_task, data, spec, settings, seed, out_dir): spec
                   for spec in first}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                spec = pending.pop(fut)
                done[spec] = fut.result()
                # one at a time: even reading a finished run reopens its file to write
                queue = waiting.get(identity.get(spec, ""))
                if queue:
                    other = queue.pop(0)
                    pending[pool.submit(run_task, data, other, settings, seed,
                                        out_dir)] = other
                if report:
                    report(len(done), len(tasks), done[spec])
    return done


def _nrmse(task: TaskResult | None, freq: Any, joint: bool) -> tuple[float, float]:
    if task is None or not task.ok or task.overall is None:
        return math.nan, math.nan
    if joint:
        return task.overall.nrmse_percent, task.overall.max_error_percent
    # the tracking errors are per frequency: a band group's fit scores its own records
    # only (or all of them, when it is the only group), whose error is the overall one
    if not isinstance(freq, Band):
        for e in task.per_frequency:
            if e.frequency_hz == freq:
                return e.nrmse_percent, e.max_error_percent
    return task.overall.nrmse_percent, task.overall.max_error_percent


def _assemble(models: tuple[str, ...], freq: Any, joint: bool,
              fit: dict[str, TaskResult | None], lofo: dict[str, list[TaskResult]],
              jointfit: dict[str, TaskResult]) -> FrequencyComparison:
    """Rank the models in one group (``freq`` its key: a frequency, a Band, None) or jointly."""
    pre: list[dict[str, Any]] = []
    for m in models:
        t = fit.get(m)
        row: dict[str, Any] = {"model": m}
        if t is None or not t.ok:
            row["error"] = t.error if t is not None else "not run"
            row["pw"] = None
        else:
            sel = cycles_at(t, freq, joint)
            row["pw"] = t.pointwise[sel]
            row["task"], row["sel"] = t, sel
        lt = [x for x in lofo.get(m, []) if x.ok]
        lofo_failed = [x.error for x in lofo.get(m, []) if not x.ok]
        if lt and not lofo_failed:
            lpw = np.concatenate([x.pointwise for x in lt])
            row["lofo"] = total_and_se(lpw)
            if len(lt) == 1:
                row["lofo_nrmse"] = _nrmse(lt[0], freq, True)[0]
        jt = jointfit.get(m)
        if jt is not None and jt.ok:
            row["elpd_joint"] = float(np.sum(jt.pointwise[cycles_at(jt, freq, joint)]))
        row["lofo_errors"] = lofo_failed
        pre.append(row)
    ok = [r for r in pre if r["pw"] is not None and np.all(np.isfinite(r["pw"]))
          and r["pw"].size]
    for r in pre:
        if r["pw"] is not None and not any(r is o for o in ok):
            r["error"] = "non-finite predictive density (failed simulations)"
    try:
        ranked = {x.model: x for x in rank_by_elpd({r["model"]: r["pw"] for r in ok},
                                                   stacking=True)}
    except ModelError as exc:
        raise ModelError(f"at {'all' if joint else group_label(freq)}: {exc}") from None
    scores = []
    for r in pre:
        m = r["model"]
        t: TaskResult | None = r.get("task")
        lofo_elpd, lofo_se = r.get("lofo", (math.nan, math.nan))
        warns = list(t.warnings) if t is not None else []
        warns += [f"leave-one-frequency-out fit failed: {e}" for e in r["lofo_errors"]]
        if t is None or r.get("error"):
            nan = math.nan
            scores.append(ModelScore(
                model=m, elpd_loo=nan, se=nan, p_loo=nan, delta_elpd=nan, delta_se=nan,
                weight=0.0, elpd_waic=nan, waic_se=nan, elpd_lofo=lofo_elpd, lofo_se=lofo_se,
                lofo_nrmse_percent=r.get("lofo_nrmse", nan),
                elpd_joint=r.get("elpd_joint", nan), bic=nan, nrmse_percent=nan,
                max_error_percent=nan, n_params=0, converged=False, max_pareto_k=nan,
                n_refits=0, n_cycles=0, warnings=tuple(warns),
                error=r.get("error") or "failed"))
            continue
        sel = r["sel"]
        rk = ranked[m]
        wa = (total_and_se(t.waic_pointwise[sel]) if t.waic_pointwise is not None
              else (math.nan, math.nan))
        k = t.pareto_k[sel] if t.pareto_k is not None else np.zeros(0)
        kmax = float(np.nanmax(k)) if k.size and np.any(np.isfinite(k)) else math.nan
        nrmse, mx = _nrmse(t, freq, joint)
        conv = t.converged and all(x.converged for x in lofo.get(m, []) if x.ok)
        scores.append(ModelScore(
            model=m, elpd_loo=rk.elpd, se=rk.se, p_loo=t.p_loo, delta_elpd=rk.delta_elpd,
            delta_se=rk.delta_se, weight=rk.weight, elpd_waic=wa[0], waic_se=wa[1],
            elpd_lofo=lofo_elpd, lofo_se=lofo_se, lofo_nrmse_percent=r.get("lofo_nrmse", math.nan),
            elpd_joint=r.get("elpd_joint", math.nan), bic=t.bic, nrmse_percent=nrmse,
            max_error_percent=mx, n_params=t.n_params, converged=conv, max_pareto_k=kmax,
            n_refits=t.n_refits, n_cycles=int(sel.sum()), warnings=tuple(warns)))

    # the ranking's order; failed fits last, in the user's order
    place = {name: i for i, name in enumerate(ranked)}
    scores.sort(key=lambda s: place.get(s.model, len(place)))
    best = scores[0].model if scores and not scores[0].error else None
    lofo_ok = [s for s in scores if math.isfinite(s.elpd_lofo)]
    best_lofo = max(lofo_ok, key=lambda s: s.elpd_lofo).model if lofo_ok else None
    return FrequencyComparison(frequency_of(freq), tuple(scores), best, best_lofo, joint,
                               band_of(freq))


def compare_models(
    data: Dataset | Record,
    models: Sequence[str] | str,
    *,
    likelihood: str = "gaussian",
    sampler: SamplerSettings | None = None,
    draws_per_chain: int = 30,
    n_lofo_draws: int = 400,
    lofo: bool = True,
    max_refits: int = 5,
    gp_n_train: int = 1000,
    gp_sampling: bool = False,
    n_jobs: int | None = None,
    out_dir: str | os.PathLike[str] | None = None,
    progress: bool = False,
) -> ComparisonResult:
    """Compare models per excitation frequency and over all frequencies.

    Parameters
    ----------
    data : Dataset or Record
        Measured records; records are grouped by ``frequency_hz``, records without one
        by their band (``metadata["band_hz"]`` of a multisine or broadband record: one
        group per band label, :meth:`~bayeshyst.data.dataset.Dataset.by_group`); records
        with neither form an "unknown" group. Frequencies come first, ascending, then
        bands by lower edge, then "unknown".
    models : sequence of str, or a comma-separated str
        Model spec strings (``"pi_play"``, ``"bouc_wen+second_order"``), and ``"gp"``
        (Gaussian process on (u, du/dt), ref. [64]) or ``"gp_memory"`` (with reversal
        memory features).
    likelihood : str
        ``"gaussian"``, ``"student_t"`` or ``"ar1"`` for the parametric models.
    sampler : SamplerSettings, optional
        How every fit is sampled (default :class:`SamplerSettings`; see
        :func:`~bayeshyst.inference.sampling.sample_posterior`). ``sampler.seed`` is the
        comparison's seed: each fit derives its own from it and what the fit is, so the
        same seed gives the same numbers whatever ``n_jobs``. Its checkpoint is ignored
        (each fit checkpoints under ``out_dir``), and so is its progress bar (parallel
        fits would garble it; ``progress`` prints a line per finished fit instead).
    draws_per_chain : int
        Draws per walker kept for PSIS-LOO and WAIC.
    n_lofo_draws : int
        Posterior draws averaged for the held-out predictive density.
    lofo : bool
        Run the leave-one-frequency-out fits (one per model and frequency).
    max_refits : int
        Exact leave-one-cycle-out refits per fit for cycles with Pareto k > 0.7.
    gp_n_train : int
        Training subset of the GP models.
    gp_sampling : bool
        Sample the GP models' hyperparameters with ``sampler`` (the same sampler and
        convergence criteria as every model) and score them mixed over 16 posterior
        draws (ref. [64]); off, at the marginal-likelihood optimum. Minutes per GP fit
        at ``gp_n_train=1000`` instead of seconds.
    n_jobs : int, optional
        Worker processes; default the machine's cores (``os.cpu_count()``).
    out_dir : path, optional
        Posteriors (netCDF, ``posteriors/``) and resumable sampler checkpoints
        (``checkpoints/<identity>.h5``) go here; another command fitting the same
        posterior with the same settings and checkpoint folder (the diagnosis of a
        report) reuses a finished fit.
    progress : bool
        One line per finished fit on stderr.

    Returns
    -------
    ComparisonResult
    """
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    if not isinstance(data, Dataset):
        raise DataError(f"data must be a Dataset or Record, got {type(data).__name__}")
    names = check_models(models)
    get_likelihood(likelihood)
    sampler = SamplerSettings() if sampler is None else sampler
    if not isinstance(sampler, SamplerSettings):
        raise ParameterError(f"sampler must be a SamplerSettings, got {type(sampler).__name__}")
    seed = sampler.seed
    for value, what, low in ((draws_per_chain, "draws_per_chain", 1),
                             (n_lofo_draws, "n_lofo_draws", 1), (max_refits, "max_refits", 0),
                             (gp_n_train, "gp_n_train", 10)):
        if int(value) != value or value < low:
            raise ParameterError(f"{what} must be an integer >= {low}, got {value!r}")
    n_jobs = resolve_jobs(n_jobs)
    settings = CompareSettings(likelihood, sampler.replace(checkpoint=None, progress=False),
                               int(draws_per_chain), int(n_lofo_draws), int(max_refits),
                               int(gp_n_train), gp_sampling=gp_sampling)
    keys = list(data.by_group())
    tasks = _tasks(names, keys, lofo)
    out = None if out_dir is None else Path(out_dir)
    t0 = time.perf_counter()

    def report(i: int, n: int, r: TaskResult) -> None:
        state = ("FAILED: " + (r.error or "")) if not r.ok else (
            "converged" if r.converged else "NOT converged")
        print(f"[{i}/{n}] {r.spec.key}: {state} ({r.runtime_s:.1f} s)", file=sys.stderr,
              flush=True)

    done = _run_all(data, tasks, settings, seed, out, min(n_jobs, len(tasks)),
                    report if progress else None)
    joint = {s.model: r for s, r in done.items() if s.scope == "joint"}
    per = []
    for f in keys:
        fit = ({s.model: r for s, r in done.items() if s.scope == "frequency"
                and s.group_key == f} if len(keys) > 1 else dict(joint))
        lofo_f = {m: [r for s, r in done.items() if s.scope == "lofo" and s.model == m
                      and s.group_key == f] for m in names}
        per.append(_assemble(names, f, False, fit, lofo_f, joint))
    lofo_all = {m: [r for s, r in done.items() if s.scope == "lofo" and s.model == m]
                for m in names}
    overall = _assemble(names, None, True, joint, lofo_all, joint)
    settings_d = {**settings.__dict__, "sampler": settings.sampler.to_dict(), "seed": seed,
                  "lofo": bool(lofo) and len(keys) > 1, "n_jobs": n_jobs}
    return ComparisonResult(names, tuple(per), overall,
                            tuple(done[s] for s in tasks), settings_d,
                            time.perf_counter() - t0)
