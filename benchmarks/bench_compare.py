"""Model comparison at a real stage's scale, and its parallel speed-up.

Two measurements, each selectable with ``--only``:

``stage``
    ``compare_models`` of ``pi_play``, ``pi_play+second_order`` and ``gp`` on a virtual
    actuator sampled at 10 kHz at five frequencies (5, 10, 25, 50, 100 Hz; 8 000 samples
    each, 40 000 in all), per frequency and jointly, with the leave-one-frequency-out
    fits, default sampler settings (the structured moves) and all cores, checkpoints on
    disk: wall time, fits converged, the largest checkpoint. In the same run the
    baseline: the joint ``pi_play+second_order`` fit sampled with ``moves="de"`` (the
    previous engine) at the same settings, stopped after as many seconds as the whole
    comparison took (at most 5 minutes), against the structured moves on that fit.
``parallel``
    One small comparison (3 frequencies x 3 models, 21 fits) with 1 worker and with all
    cores: the speed-up, and that both give identical elpd values.

Usage::

    python benchmarks/bench_compare.py [--only stage|parallel] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MODELS = ["pi_play(n_operators=4)", "pi_play(n_operators=4)+second_order", "gp"]
SAMPLER = dict(max_steps=1000, first_chunk=500, n_walkers=24, seed=3)
SCORING = dict(max_refits=0, draws_per_chain=20, n_lofo_draws=200, gp_n_train=300)

STAGE_MODELS = ["pi_play", "pi_play+second_order", "gp"]
STAGE_FREQS = (5.0, 10.0, 25.0, 50.0, 100.0)
STAGE_FS = 10_000.0
STAGE_N = 8000
#: the de baseline's time limit: the comparison's wall time, at most the 5 minutes the
#: whole comparison is meant to take
DE_SECONDS = 300.0


def make_data():
    """A Hammerstein actuator (4-operator PI + 250 Hz resonance) at 1, 20 and 80 Hz."""
    from bayeshyst import models
    from bayeshyst.data import Dataset, Record
    from bayeshyst.models.base import DataScales

    model = models.get("pi_play(n_operators=4)+second_order")
    r = model.param_space(DataScales(0.0, 150.0, 0.0, 40.0)).fixed["static.r"]
    theta = {"static.p0": 0.17, "static.w": np.array([0.06, 0.04, 0.03, 0.02]),
             "static.r": r, "second_order.f_n": 250.0, "second_order.zeta": 0.2}
    recs = []
    for i, f in enumerate((1.0, 20.0, 80.0)):
        t = np.arange(400) / (100 * f)
        u = 75 - 75 * np.cos(2 * np.pi * f * t)
        y = model.simulate(u, t, theta) + np.random.default_rng(i).normal(0, 0.04, t.size)
        recs.append(Record(t=t, u=u, y=y, name=f"h{f:g}", warmup=100,
                           metadata={"frequency_hz": f}))
    return Dataset(tuple(recs), name="hammerstein")


def make_stage_data():
    """The virtual actuator (every effect on) driven by 0-150 V sines at 10 kHz.

    One record per frequency, 8 000 samples each; its first cycle is simulated but not
    scored (the virgin branch from the demagnetised state).
    """
    from bayeshyst.data import Dataset, VirtualActuator, excitation

    plant = VirtualActuator()
    recs = []
    for i, f in enumerate(STAGE_FREQS):
        t, u = excitation.sine(f, STAGE_FS, duration_s=STAGE_N / STAGE_FS)
        recs.append(plant.record(t[:STAGE_N], u[:STAGE_N], rng=i, name=f"stage{f:g}",
                                 frequency_hz=f, warmup=round(STAGE_FS / f)))
    return Dataset(tuple(recs), name="stage_10khz")


def stage(cores: int) -> tuple[str, bool]:
    """The stage-scale comparison and the DE baseline on its hardest parametric fit."""
    from bayeshyst.data import Dataset
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.selection import compare_models

    data = make_stage_data()
    n = sum(r.n for r in data)
    settings = SamplerSettings(seed=11)
    # numba's cache: compile the kernels on a tiny fit first (not timed)
    compare_models(Dataset(data.records[:1], name="warm"), STAGE_MODELS[1:2],
                   n_jobs=1, lofo=False, max_refits=0,
                   sampler=settings.replace(max_steps=40, first_chunk=20))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = compare_models(data, STAGE_MODELS, n_jobs=cores, sampler=settings, out_dir=tmp)
        wall = time.perf_counter() - t0
        sizes = sorted(p.stat().st_size for p in (Path(tmp) / "checkpoints").glob("*.h5"))
    fits = [t for t in res.tasks if t.error is None]
    conv = [t for t in fits if t.converged]
    slow = sorted(fits, key=lambda t: -t.runtime_s)[:3]
    # the baseline: the joint Hammerstein fit with the previous engine, for as long as
    # the whole comparison took, against the structured moves on the same posterior
    post = Posterior(data, STAGE_MODELS[1])
    rows = []
    for moves, budget in (("structured", settings.max_steps), ("de", settings.max_steps)):
        s = settings.replace(moves=moves, max_steps=budget, progress=False)
        if moves == "de":
            s = s.replace(n_walkers=max(32, 4 * post.ndim))
        t1 = time.perf_counter()
        r = _sample_until(post, s, min(wall, DE_SECONDS) if moves == "de" else None,
                          sample_posterior)
        rows.append((moves, time.perf_counter() - t1, r))
    base_struct, base_de = rows[0], rows[1]
    lines = [
        f"Machine: {platform.processor() or platform.machine()}, {cores} cores, Python "
        f"{platform.python_version()}; numba cache warm; measured alone.",
        "",
        f"Virtual actuator (every effect on), 10 kHz, {len(STAGE_FREQS)} frequencies "
        f"({', '.join(f'{f:g}' for f in STAGE_FREQS)} Hz), {n} samples; models "
        f"{', '.join(STAGE_MODELS)}; per frequency, jointly and leave-one-frequency-out; "
        f"default sampler settings ({settings.moves} moves, up to {settings.max_steps} "
        f"steps), {cores} workers, checkpoints on disk.",
        "",
        "| fits | converged | wall time | largest checkpoint | slowest fits |",
        "|---|---|---|---|---|",
        f"| {len(fits)} (+{len(res.tasks) - len(fits)} failed) | {len(conv)} of {len(fits)} "
        f"| {wall:.1f} s | {sizes[-1] / 1e6:.2f} MB | "
        + "; ".join(f"{t.spec.key} {t.runtime_s:.1f} s" for t in slow) + " |",
        "",
        f"Baseline in the same run: the joint `{STAGE_MODELS[1]}` fit ({post.ndim} "
        f"parameters, {n} samples) sampled alone, structured moves against `de`:",
        "",
        "| moves | wall time | converged | R-hat max | ESS bulk min | steps |",
        "|---|---|---|---|---|---|",
    ]
    for moves, secs, r in (base_struct, base_de):
        c = r.convergence
        lines.append(f"| {moves} | {secs:.1f} s | {'yes' if c.converged else 'no'} | "
                     f"{c.rhat_max:.3f} | {c.ess_bulk_min:.0f} | {c.n_steps} |")
    if not base_de[2].converged:
        lines += ["", f"`de` was given the steps that fit in {min(wall, DE_SECONDS):.0f} s "
                      "(the comparison's wall time, at most 5 minutes, at the rate of a "
                      "200-step probe) and did not converge in them; the structured moves "
                      f"converged the same fit in {base_struct[1]:.1f} s."]
    text = "\n".join(lines)
    ok = len(conv) == len(fits) and len(fits) == len(res.tasks)
    return text, ok


def _sample_until(post, settings, seconds, sample_posterior):
    """Sample; with ``seconds``, cap the budget at the steps that fit in that time (the
    rate measured on a first short run, so the cap is a step count and reproducible)."""
    if seconds is None:
        return sample_posterior(post, settings)
    probe = settings.replace(max_steps=200, first_chunk=200)
    t0 = time.perf_counter()
    sample_posterior(post, probe)
    per_step = (time.perf_counter() - t0) / 200
    steps = max(200, int((seconds - (time.perf_counter() - t0)) / per_step))
    return sample_posterior(post, settings.replace(max_steps=min(steps, settings.max_steps)))


def parallel(cores: int) -> tuple[str, bool]:
    """1 worker vs all cores on one small comparison: speed-up and identical numbers."""
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.selection import compare_models

    data = make_data()
    sampler = SamplerSettings(**SAMPLER)
    compare_models(data, MODELS[:1], n_jobs=1, lofo=False, **SCORING,
                   sampler=sampler.replace(max_steps=50, first_chunk=50))  # warm caches
    times, results = {}, {}
    for jobs in (1, cores):
        t0 = time.perf_counter()
        results[jobs] = compare_models(data, MODELS, n_jobs=jobs, sampler=sampler, **SCORING)
        times[jobs] = time.perf_counter() - t0
    same = all(a.elpd_loo == b.elpd_loo or (np.isnan(a.elpd_loo) and np.isnan(b.elpd_loo))
               for fa, fb in zip(results[1].per_frequency, results[cores].per_frequency,
                                 strict=True)
               for a, b in zip(fa.scores, fb.scores, strict=True))
    n_fits = len(results[1].tasks)
    lines = [
        f"Machine: {platform.processor() or platform.machine()}, {cores} cores, "
        f"Python {platform.python_version()}; measured alone.",
        "",
        f"One comparison: 3 frequencies x {len(MODELS)} models = {n_fits} fits "
        f"({sampler.max_steps} steps, {sampler.n_walkers} walkers per ensemble, "
        f"{sampler.moves} moves).",
        "",
        "| workers | wall time | speed-up |",
        "|---|---|---|",
        f"| 1 | {times[1]:.1f} s | 1.00 |",
        f"| {cores} | {times[cores]:.1f} s | {times[1] / times[cores]:.2f} |",
        "",
        f"Identical elpd values with 1 and {cores} workers: {'yes' if same else 'NO'}.",
    ]
    return "\n".join(lines), same


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; with ``--write`` record it in RESULTS.md."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=("stage", "parallel"), default=None)
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    cores = os.cpu_count() or 1
    ok = True
    for name, key, heading, fn in (
            ("stage", "compare_stage", "Model comparison at a stage's scale", stage),
            ("parallel", "compare", "Model comparison: parallel fits", parallel)):
        if args.only not in (None, name):
            continue
        text, good = fn(cores)
        ok = ok and good
        print(text, flush=True)
        if args.write:
            from benchmarks._results import write_section

            write_section(key, heading, text)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
