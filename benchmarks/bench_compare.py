"""Wall time of a model comparison with 1 and with all cores (the same fits, the same numbers).

``compare_models`` cuts a comparison into independent fits — per model: one joint fit,
one per frequency and one leave-one-frequency-out fit per frequency — and runs them in
worker processes. This measures the speed-up of ``n_jobs = os.cpu_count()`` over
``n_jobs = 1`` on one comparison (3 frequencies, 2 parametric models and the GP, 7 fits
each: 21 fits), and checks that both runs give identical elpd values.

Usage::

    python benchmarks/bench_compare.py [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MODELS = ["pi_play(n_operators=4)", "pi_play(n_operators=4)+second_order", "gp"]
SAMPLER = dict(max_steps=1000, first_chunk=500, n_walkers=24, seed=3)
SCORING = dict(max_refits=0, draws_per_chain=20, n_lofo_draws=200, gp_n_train=300)


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


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; with ``--write`` record it in RESULTS.md."""
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.selection import compare_models

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    data = make_data()
    cores = os.cpu_count() or 1
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
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("compare", "Model comparison: parallel fits", text)
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
