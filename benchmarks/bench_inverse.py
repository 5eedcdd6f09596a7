"""Speed of numerical inversion against references measured in the same run.

* **Root finding**: the bracketed Illinois solver against plain bisection on the same
  one-step map (the textbook safe choice), for a 10-operator play-PI and Bouc–Wen:
  one-step evaluations per sample and wall time, and their agreement.
* **Against the closed form**: numerical inversion of the play-PI against Kuhnen's
  analytic inverse (one simulation of a play-PI), time per sample.
* **Posterior draws**: cost per sample of the posterior-mean command for S = 1 ... 128
  draws carried together (one batched one-step call evaluates every draw).

Usage::

    python benchmarks/bench_inverse.py [--write]
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

FS, F = 2000.0, 10.0


def reference_and_theta(spec: str):
    from bayeshyst.models import get
    from bayeshyst.models.base import DataScales

    model = get(spec)
    space = model.param_space(DataScales(0.0, 150.0, 0.0, 40.0))
    theta = space.unpack(space.sample_prior(np.random.default_rng(0), 1))
    if "w" in theta:  # positive weights: an invertible play-PI
        theta["w"] = np.abs(theta["w"])
        theta["p0"] = np.abs(theta["p0"])
    t = np.arange(int(4 * FS / F)) / FS
    u = 75.0 - 60.0 * np.cos(2 * np.pi * F * t) + 8.0 * np.sin(6 * np.pi * F * t)
    return model, theta, t, model.run_batch(u, t, theta).y[0]


def bisection_inverse(model, theta, y_d, t, lo=-100.0, hi=250.0, xtol=1e-13 * 350):
    """Reference: plain bisection on the same one-step map (no interpolation)."""
    tb, _ = model._batch_theta(theta, batched=True)
    u, states, n_eval = np.empty(t.size), None, 0
    for k in range(t.size):
        a, b = lo, hi
        while b - a > xtol:
            m = 0.5 * (a + b)
            s0 = model._initial_state(tb, m) if states is None else states
            y, _, _ = model._run(np.array([m]), t[k:k + 1], tb, s0)
            n_eval += 1
            a, b = (m, b) if y[0, 0] < y_d[k] else (a, m)
        u[k] = 0.5 * (a + b)
        s0 = model._initial_state(tb, u[k]) if states is None else states
        _, states, _ = model._run(u[k:k + 1], t[k:k + 1], tb, s0)
    return u, n_eval


def timed(fun, repeat=3):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fun()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; with ``--write`` record it in RESULTS.md."""
    from bayeshyst.inverse.numerical import invert

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    limits = (-100.0, 250.0)
    lines = [f"Machine: {platform.processor() or platform.machine()}, Python "
             f"{platform.python_version()}, numpy {np.__version__}; measured alone. "
             f"Reference: {int(4 * FS / F)} samples (4 periods of a {F:g} Hz sine with "
             "minor loops at 2 kHz); best of 3.", "",
             "| model | solver | evaluations/sample | time/sample | ratio | max deviation |",
             "|---|---|---|---|---|---|"]
    for spec in ("pi_play", "bouc_wen"):
        model, theta, t, y_d = reference_and_theta(spec)
        invert(model, y_d[:20], t[:20], theta, u_limits=limits)  # compile
        t_ours, inv = timed(lambda m=model, th=theta, y=y_d, tt=t:
                            invert(m, y, tt, th, u_limits=limits))
        t_bis, (u_bis, n_bis) = timed(lambda m=model, th=theta, y=y_d, tt=t:
                                      bisection_inverse(m, th, y, tt), repeat=1)
        dev = np.max(np.abs(inv.u - u_bis))
        lines.append(f"| {spec} | bisection (reference) | {n_bis / t.size:.1f} | "
                     f"{1e6 * t_bis / t.size:.0f} us | 1.00 | |")
        lines.append(f"| {spec} | bracketed Illinois | {inv.n_evaluations / t.size:.1f} | "
                     f"{1e6 * t_ours / t.size:.0f} us | {t_bis / t_ours:.1f}x faster | "
                     f"{dev:.1e} V |")
        if spec == "pi_play":
            one = {k: np.asarray(v)[0] for k, v in theta.items()}
            t_an, u_an = timed(lambda m=model, o=one, y=y_d, tt=t: m.inverse(y, tt, o))
            lines.append(f"| {spec} | Kuhnen closed form | - | {1e6 * t_an / t.size:.2f} us | "
                         f"{t_bis / t_an:.0f}x faster | {np.max(np.abs(inv.u - u_an)):.1e} V |")
    lines += ["", "Posterior-mean command, S draws carried together (bouc_wen):", "",
              "| S | time/sample | per draw |", "|---|---|---|"]
    model, theta, t, y_d = reference_and_theta("bouc_wen")
    rng = np.random.default_rng(1)
    for s in (1, 8, 32, 128):
        draws = {k: np.asarray(v) * (1 + 0.02 * rng.standard_normal((s, *np.shape(v)[1:])))
                 for k, v in theta.items()}
        elapsed, _ = timed(lambda d=draws: invert(model, y_d, t, d, u_limits=limits),
                           repeat=1)
        lines.append(f"| {s} | {1e3 * elapsed / t.size:.2f} ms | "
                     f"{1e6 * elapsed / t.size / s:.0f} us |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("inverse", "Numerical inversion", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
