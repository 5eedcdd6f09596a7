"""A sharp force loop: the MR damper's Bouc–Wen posterior in two parametrisations.

An MR damper's force loop (Spencer's form ``F = k x + h``, ``bouc_wen(sign=1)``) is
steep after every reversal and flat on its plateau: in the classical coordinates its
posterior lies against the stable region's edge ``γ > -β`` (``β + γ`` a thousand times
below ``β``), where proposals fall outside and the ensemble does not mix. In the
``saturation`` coordinates (``h_sat``, ``kappa``: :class:`~bayeshyst.models.BoucWen`)
the stable region is the whole space. Measured in one run on the same data:

1. **baseline**: ``bouc_wen(sign=1)``, classical coordinates, step budget ``--cap``
   (default 3 000: it does not converge in 10 000);
2. ``bouc_wen(sign=1, parametrisation='saturation')``, default budget (20 000).

Data: the UTFSM MR damper at 0 A, six frequencies, decimated to 50 samples per cycle
(2 983 samples), from ``../shared/data`` (exits 2 with one line when it is absent).
Printed per fit: time, steps, convergence, R-hat, least bulk ESS, ESS per second,
failed simulations, and the ratio against the baseline.

Usage::

    python benchmarks/bench_force_loop.py [--seed 0] [--cap 3000] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLASSICAL = "bouc_wen(sign=1)"
SATURATION = "bouc_wen(sign=1, parametrisation='saturation')"


def _fit(data, spec: str, max_steps: int, seed: int) -> dict:
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings

    post = Posterior(data, spec)
    t0 = time.perf_counter()
    res = sample_posterior(post, SamplerSettings(max_steps=max_steps, seed=seed))
    wall = time.perf_counter() - t0
    rep = res.convergence
    return {"spec": spec, "time_s": wall, "steps": int(rep.n_steps),
            "converged": bool(res.converged), "rhat": float(rep.rhat_max),
            "ess": float(rep.ess_bulk_min), "ess_per_s": float(rep.ess_bulk_min) / wall,
            "failed": int(res.counts.failed), "evaluations": int(res.counts.evaluations)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    ap.add_argument("--cap", type=int, default=3000,
                    help="the baseline's step budget (default 3 000)")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from analyses._common import Cut, load_measured
    from bayeshyst.errors import DataError
    from benchmarks._results import write_section

    try:
        data = load_measured("mr_damper", Cut(samples_per_cycle=50), mr_current=0.0)
    except DataError as exc:
        print(f"bench_force_loop: the MR-damper data are not available: {exc}",
              file=sys.stderr)
        return 2
    load0 = os.getloadavg()[0]
    rows = [_fit(data, CLASSICAL, args.cap, args.seed),
            _fit(data, SATURATION, 20_000, args.seed)]
    base = rows[0]
    lines = [f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, "
             f"{os.cpu_count()} cores, Python {platform.python_version()}; load average "
             f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end. MR damper, 0 A, "
             f"{data.n_samples} samples, seed {args.seed}.", "",
             "| parametrisation | steps | time (s) | converged | R-hat max | bulk ESS min "
             "| ESS/s | failed / evaluations | ESS/s vs baseline |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        # a baseline with no effective draws has no finite ratio: say so, not "inf"
        ratio = (f"{r['ess_per_s'] / base['ess_per_s']:.0f}x" if base["ess_per_s"] > 0
                 else "n/a (baseline ESS 0)")
        lines.append(f"| `{r['spec']}` | {r['steps']} | {r['time_s']:.1f} | "
                     f"{'yes' if r['converged'] else 'no'} | {r['rhat']:.3f} | {r['ess']:.0f} | "
                     f"{r['ess_per_s']:.2f} | {r['failed']} / {r['evaluations']} | "
                     f"{'1 (baseline)' if r is base else ratio} |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        write_section("force_loop", "A sharp force loop: Bouc–Wen parametrisations", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
