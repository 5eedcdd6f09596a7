"""Posterior evaluation speed and sampling efficiency for Bouc–Wen (6 000 samples, sigma free).

Measured in one run:

1. log-likelihood evaluations per second
   * the vectorised ensemble path (``Posterior.log_prob_batch`` on W = 64 walkers),
   * one walker at a time (``Posterior.log_prob`` in a Python loop),
   * a naive likelihood: Bouc–Wen integrated in time with ``scipy.integrate.solve_ivp``
     and a NumPy Gaussian log-density, per parameter vector;
2. time to a converged posterior and effective samples per second (minimum bulk ESS
   over parameters divided by the wall time of MAP + sampling to convergence: R-hat <
   1.01, ESS >= 1000 for Bouc-Wen, >= 400 for the PI model, 50 tau), for the structured
   moves (the default) and the differential-evolution moves of the previous engine
   (``moves="de"``), measured in the same run on Bouc-Wen (6 000 samples) and on
   ``pi_play(n_operators=8)`` fitted jointly to the bundled five-frequency record.

Usage::

    python benchmarks/bench_inference.py [--quick] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3}
SIGMA = 0.05


def make_data(n: int = 6000, seed: int = 0):
    """A 0-150 V sine, 3 periods of 2 000 samples, through the true Bouc-Wen, plus noise."""
    from bayeshyst import models
    from bayeshyst.data import Record

    t = np.arange(n) * 5e-4
    u = 75.0 - 75.0 * np.cos(2 * np.pi * t / (2000 * 5e-4))
    y = models.get("bouc_wen").simulate(u, t, TRUTH)
    y = y + np.random.default_rng(seed).normal(0.0, SIGMA, n)
    return Record(t=t, u=u, y=y, name="bouc_wen_6000", warmup=500,
                  metadata={"frequency_hz": 1.0 / (2000 * 5e-4)})


def naive_loglik(theta: dict, rec) -> float:
    """Bouc-Wen in time with solve_ivp (u linear between samples) + Gaussian density."""
    t, u = rec.t, rec.u

    def rhs(tt, h):
        i = min(int(np.searchsorted(t, tt, side="right")) - 1, t.size - 2)
        du = (u[i + 1] - u[i]) / (t[i + 1] - t[i])
        hh = h[0]
        return [theta["alpha"] * du - theta["beta"] * abs(du) * abs(hh) ** (theta["n"] - 1) * hh
                - theta["gamma"] * du * abs(hh) ** theta["n"]]

    sol = solve_ivp(rhs, (t[0], t[-1]), [0.0], t_eval=t, rtol=1e-6, atol=1e-9, max_step=5e-4)
    yhat = theta["k"] * u - sol.y[0] + theta["offset"]
    r = (rec.y - yhat)[rec.scored]
    s = theta["sigma"]
    return float(np.sum(-0.5 * (r / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi)))


def _rate(fn, calls: int, per_call: int) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return calls * per_call / (time.perf_counter() - t0)


def _engine(post, moves: str, min_ess: float, max_steps: int):
    """MAP + sampling to convergence with ``moves``; (result, wall s, MAP s)."""
    from bayeshyst.inference.optimize import find_map
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings

    post.reset_counts()
    t0 = time.perf_counter()
    st = find_map(post, seed=0)
    t_map = time.perf_counter() - t0
    res = sample_posterior(post, SamplerSettings(seed=0, moves=moves, min_ess=min_ess,
                                                 max_steps=max_steps), start=st)
    return res, time.perf_counter() - t0, t_map


def _row(label: str, moves: str, res, wall: float, t_map: float) -> tuple:
    c = res.convergence
    acc = ", ".join(f"{k} {v:.2f}" for k, v in sorted(res.move_acceptance.items())) or "-"
    print(f"{label:>14} {moves:>10}: ESS min {c.ess_bulk_min:.0f}, R-hat {c.rhat_max:.4f}, "
          f"{c.n_steps} steps, tau {c.tau_max:.1f}, MAP {t_map:.2f} s, total {wall:.2f} s -> "
          f"{c.ess_bulk_min / wall:.0f} ESS/s ({'converged' if c.converged else 'NOT converged'}"
          f"; acceptance {acc})", flush=True)
    return (label, moves, c.ess_bulk_min, c.rhat_max, c.n_steps, c.tau_max, t_map, wall,
            c.ess_bulk_min / wall, c.converged, acc)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats; shorter budget")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from bayeshyst.data.io import load
    from bayeshyst.inference.optimize import find_map
    from bayeshyst.inference.posterior import Posterior
    from benchmarks._results import write_section

    load0 = os.getloadavg()[0]
    rec = make_data()
    post = Posterior(rec, "bouc_wen")
    rng = np.random.default_rng(1)
    start = find_map(post, seed=0)  # also compiles every kernel
    z = start.z + 0.01 * rng.standard_normal((64, post.ndim))
    batch = _rate(lambda: post.log_prob_batch(z), 5 if args.quick else 30, 64)
    single = _rate(lambda: [post.log_prob(zi) for zi in z[:16]], 2 if args.quick else 10, 16)
    th = dict(start.theta)
    th["offset"], th["sigma"] = th.pop("obs.offset"), th.pop("noise.sigma")
    naive = _rate(lambda: naive_loglik(th, rec), 1 if args.quick else 3, 1)
    print(f"log-likelihood evaluations/s: ensemble {batch:,.0f}, one walker at a time "
          f"{single:,.0f}, naive solve_ivp {naive:,.1f}  (ratios {batch / naive:,.0f}x, "
          f"{single / naive:,.0f}x)", flush=True)

    rows = []
    # Bouc-Wen, 6 000 samples: time to a converged posterior with ESS >= 1000
    budget = 6000 if args.quick else 40_000
    for moves in ("structured", "de"):
        res, wall, t_map = _engine(post, moves, 1000.0, budget)
        rows.append(_row("bouc_wen", moves, res, wall, t_map))
        summ = {s.label: (s.mean, s.hdi_lo, s.hdi_hi) for s in res.summary()}
        cover = {k: summ[k][1] <= v <= summ[k][2] for k, v in TRUTH.items()}
        print(f"          90 % HDI covers the truth: {cover}", flush=True)
    # pi_play(8) jointly on the bundled five-frequency record (default criteria)
    data = load(ROOT / "data" / "virtual_multifreq.csv")
    pi = Posterior(data, "pi_play(n_operators=8)")
    find_map(pi, seed=0)
    for moves in ("structured", "de"):
        res, wall, t_map = _engine(pi, moves, 400.0, budget)
        rows.append(_row("pi_play(8)", moves, res, wall, t_map))
    load1 = os.getloadavg()[0]
    by = {(r[0], r[1]): r for r in rows}
    ratios = {m: by[(m, "de")][7] / by[(m, "structured")][7] for m in ("bouc_wen", "pi_play(8)")}
    print("time to a converged posterior, de / structured: "
          + ", ".join(f"{m} {r:.1f}x" for m, r in ratios.items()), flush=True)

    if args.write:
        import numba

        lines = [
            f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, {os.cpu_count()} "
            f"cores, numba {numba.__version__}, emcee; load average {load0:.1f} at the start, "
            f"{load1:.1f} at the end. Bouc-Wen: 6 000 samples (500 warm-up), sigma and "
            f"offset sampled (7 parameters), run to convergence with ESS >= 1000; "
            f"pi_play(n_operators=8): jointly on data/virtual_multifreq.csv (5 records, "
            f"4 005 samples), default criteria (ESS >= 400). Both engines start from the "
            f"same MAP search (its time is in the total).",
            "",
            "| log-likelihood evaluations/s | value |",
            "|---|---|",
            f"| vectorised ensemble (W = 64) | {batch:,.0f} |",
            f"| one walker at a time | {single:,.0f} |",
            f"| naive solve_ivp + NumPy | {naive:,.1f} |",
            "",
            "| posterior | moves | min bulk ESS | R-hat max | steps | tau | MAP s | total s | "
            "ESS/s | converged | acceptance per move |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for lab, m, ess, rh, steps, tau, tm, wall, rate, conv, acc in rows:
            lines.append(f"| {lab} | {m} | {ess:.0f} | {rh:.4f} | {steps} | {tau:.1f} | "
                         f"{tm:.2f} | {wall:.2f} | {rate:.0f} | {conv} | {acc} |")
        lines += ["", "Time to a converged posterior, `de` / `structured`: "
                  + ", ".join(f"{m} {r:.1f}x" for m, r in ratios.items()) + "."]
        write_section("inference", "Posterior sampling (Bouc-Wen)", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
