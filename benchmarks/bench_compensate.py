"""Speed of the feedforward stage (``compensate``) on the demo's final model.

The demo ends with ``pi_play(n_operators=8)+asym_output(order=2)+delay(
max_delay_samples=10)+creep`` with an HSGP discrepancy on ``data/virtual_multifreq.csv``
(5 frequencies, 1-200 Hz). This benchmark fits that model with a small sampler budget
(a posterior of the right structure, quickly; convergence is not the point), then
measures in the same run:

* ``compensate`` serially (``n_jobs=1``) and on two workers (``n_jobs=2``), and checks
  that both give the same rows;
* the cost of the numerical inverse per sample and per draw -- the posterior-mean and
  the robust command of one reference on the design draws -- against a bare forward
  simulation of the same draws along the same command (``run_batch``): how many forward
  evaluations one inverted sample costs.

Measured at HEAD before the prepared one-step path and the pool (same machine, 2 cores,
same fit): 119.3 s for ``compensate``, 20.3-26.3 s per reference (the demo's cProfile
run: 188 s, ~37 s per reference, with the profiler's overhead).

Usage::

    python benchmarks/bench_compensate.py [--steps 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SPEC = ("pi_play(n_operators=8)+asym_output(order=2)+delay(max_delay_samples=10)"
        "+creep")
#: Measured at HEAD (commit before this benchmark), no profiler: whole stage and the
#: slowest reference (s).
HEAD_TOTAL_S, HEAD_PER_REF_S = 119.3, (20.3, 26.3)


def fit(steps: int, seed: int):
    """The bundled data and a posterior of :data:`SPEC` with an HSGP discrepancy."""
    from bayeshyst.data.io import load
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.settings import SamplerSettings

    data = load(ROOT / "data" / "virtual_multifreq.csv")
    sampler = SamplerSettings(max_steps=steps, seed=seed)
    return data, sampler, fit_model(data, SPEC, "gaussian", sampler=sampler,
                                    discrepancy="hsgp")


def time_compensate(data, sampler, fitted, n_jobs: int):
    """Wall time (s) of ``compensate`` with ``n_jobs`` workers, and its result."""
    from bayeshyst.inverse.compensate import compensate

    t0 = time.perf_counter()
    res = compensate(data, fitted.posterior.model, fit=fitted, sampler=sampler,
                     n_jobs=n_jobs)
    return time.perf_counter() - t0, res


def same_rows(a, b) -> bool:
    """Whether two compensation results agree in every number and curve."""
    if a.to_dict() != b.to_dict():
        return False
    return all(np.array_equal(ra.curves[k], rb.curves[k], equal_nan=True)
               for ra, rb in zip(a.rows, b.rows, strict=True) for k in ra.curves)


def per_sample_costs(data, sampler, fitted, repeats: int = 3) -> dict[str, float]:
    """µs per sample per draw: the two designed commands against a forward simulation."""
    from bayeshyst.inverse.feedforward import Draws
    from bayeshyst.inverse.numerical import invert
    from bayeshyst.inverse.references import command_limits, design_references
    from benchmarks._results import median_time

    post, model = fitted.posterior, fitted.posterior.model
    design = Draws.of(post, fitted.sampling.draws(24, seed=sampler.seed))
    ref, _ = design_references(data, "sine", cycles=2, warmup_cycles=1)[-1]
    limits = command_limits(data, 0.05)
    n, s = ref.t.size, design.size
    out = {}
    for objective in ("mean", "quantile"):
        secs, inv = median_time(lambda objective=objective: invert(
            model, ref.y_d, ref.t, design.theta, objective=objective, offset=design.offset,
            u_limits=limits, periodic=ref.periodic, scored=ref.scored), repeats)
        out[f"invert_{objective}_us"] = 1e6 * secs / (n * s)
        out[f"invert_{objective}_evals_per_sample"] = inv.n_evaluations / n
        u = inv.u
    fwd, _ = median_time(lambda: model.run_batch(u, ref.t, design.theta), repeats)
    out["forward_us"] = 1e6 * fwd / (n * s)
    out["samples"], out["draws"] = n, s
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="sampler budget of the fit")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{platform.processor() or platform.machine()}, Python {platform.python_version()}")
    t0 = time.perf_counter()
    data, sampler, fitted = fit(args.steps, args.seed)
    print(f"fit of {SPEC} + hsgp ({args.steps} steps): {time.perf_counter() - t0:.1f} s")
    # a first, untimed reference warms numba's caches in this process
    per_sample_costs(data, sampler, fitted, repeats=1)
    serial, res1 = time_compensate(data, sampler, fitted, 1)
    parallel, res2 = time_compensate(data, sampler, fitted, 2)
    n_refs = len(res1.rows)
    print(f"compensate, {n_refs} references: serial {serial:.1f} s "
          f"({serial / n_refs:.1f} s per reference), 2 workers {parallel:.1f} s; "
          f"serial / parallel = {serial / parallel:.2f}; identical rows: "
          f"{same_rows(res1, res2)}")
    print(f"HEAD before this change: {HEAD_TOTAL_S:.1f} s serial, "
          f"{HEAD_PER_REF_S[0]:.1f}-{HEAD_PER_REF_S[1]:.1f} s per reference; "
          f"HEAD / serial = {HEAD_TOTAL_S / serial:.2f}, "
          f"HEAD / 2 workers = {HEAD_TOTAL_S / parallel:.2f}")
    c = per_sample_costs(data, sampler, fitted)
    print(f"one reference, {c['samples']} samples x {c['draws']} design draws:")
    print(f"  forward simulation        {c['forward_us']:8.3f} µs per sample per draw")
    for objective in ("mean", "quantile"):
        us = c[f"invert_{objective}_us"]
        print(f"  inverse ({objective:>8})       {us:8.3f} µs per sample per draw "
              f"({c[f'invert_{objective}_evals_per_sample']:.1f} one-step evaluations "
              f"per sample; {us / c['forward_us']:.0f}x the forward simulation)")


if __name__ == "__main__":
    main()
