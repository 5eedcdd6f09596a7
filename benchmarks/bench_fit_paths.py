"""Two costs inside every structured fit, each against its former path in the same run.

1. **The adaptive proposal's mixture fit** (:func:`bayeshyst.inference.moves._fit_mixture`):
   EM with the inverse Cholesky factor and a row log-sum-exp, against the former EM
   (a general solve per component and scipy's ``logsumexp``, kept below as the
   baseline), per call on draws shaped as the demo's fits give them, and over one whole
   fit with either one in place.
2. **The design of a block's own linear coefficients** (the ``unexplained`` smooth term):
   the block's closed form (``EffectBlock._linear_columns``) against the composite's
   generic path (the block applied to one unit coefficient vector per column), on the
   demo's diagnosis candidate with that term; the sampled chains must be identical.

Usage::

    python benchmarks/bench_fit_paths.py [--write] [--repeats N]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np
from scipy import special

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._results import median_time, write_section  # noqa: E402

#: The diagnosis candidate of the demo whose fit the smooth term's design dominated.
CANDIDATE = ("pi_play(n_operators=8)+asym_output(order=2)+delay(max_delay_samples=10)"
             "+unexplained(feature='time')")
#: A fit the mixture fit weighs on without the smooth term (the quick demo's candidate).
PLAIN = "pi_play(n_operators=5)+asym_output(order=2)+second_order"


def former_fit_mixture(x: np.ndarray, k: int, iterations: int = 60):
    """The EM as it was: a general solve against the (d, M) block, scipy's logsumexp."""
    m, d = x.shape
    centres = [x[int(np.argmax(np.sum((x - x.mean(axis=0)) ** 2, axis=1)))]]
    while len(centres) < k:
        dist = np.min([np.sum((x - c) ** 2, axis=1) for c in centres], axis=0)
        centres.append(x[int(np.argmax(dist))])
    mu = np.array(centres)
    base = np.cov(x.T).reshape(d, d)
    ridge = 1e-6 * np.diag(np.diag(base)) + 1e-300 * np.eye(d)
    cov = np.repeat(base[None], k, axis=0)
    w = np.full(k, 1.0 / k)
    prev = ll = -np.inf
    for _ in range(iterations):
        logp = np.empty((m, k))
        for j in range(k):
            try:
                c = np.linalg.cholesky(cov[j] + ridge)
            except np.linalg.LinAlgError:
                return None
            r = np.linalg.solve(c, (x - mu[j]).T)
            logp[:, j] = (math.log(w[j]) - 0.5 * np.sum(r * r, axis=0)
                          - np.sum(np.log(np.diag(c))) - 0.5 * d * math.log(2 * math.pi))
        ll = float(np.sum(special.logsumexp(logp, axis=1)))
        resp = np.exp(logp - special.logsumexp(logp, axis=1, keepdims=True))
        nk = resp.sum(axis=0)
        if np.any(nk < d + 2):
            return None
        w = nk / m
        mu = (resp.T @ x) / nk[:, None]
        for j in range(k):
            dx = x - mu[j]
            cov[j] = (resp[:, j, None] * dx).T @ dx / nk[j] + ridge
        if ll - prev < 1e-6 * abs(ll):
            break
        prev = ll
    return w, mu, cov, ll


def _draws(m: int, d: int, seed: int) -> np.ndarray:
    """A two-lobed cloud of ``m`` points in ``d`` dimensions (a curved posterior's draws)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((m, d))
    x[: m // 3, 0] += 3.0
    x[:, 1] += 0.3 * x[:, 0] ** 2
    return x


def _fit(spec: str, data, seed: int = 0):
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.settings import SamplerSettings

    t0 = time.perf_counter()
    f = fit_model(data, spec, sampler=SamplerSettings(max_steps=5000, seed=seed))
    return time.perf_counter() - t0, f


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="record in benchmarks/RESULTS.md")
    ap.add_argument("--repeats", type=int, default=3, help="timings per EM case (median)")
    args = ap.parse_args(argv)
    from bayeshyst.data import load
    from bayeshyst.demo import bundled_data
    from bayeshyst.inference import moves
    from bayeshyst.models.blocks.smooth import Unexplained

    lines = [f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, "
             f"{os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the start.",
             "", "**Mixture EM per call** (median of "
             f"{args.repeats}; the shapes the demo's fits give: draws x coordinates, "
             "components):", "",
             "| draws | d | k | former | now | speed-up | same fit |",
             "|---|---|---|---|---|---|---|"]
    for m, d, k in ((624, 3, 5), (4400, 10, 3), (13728, 10, 5)):
        x = _draws(m, d, m + d + k)
        t_old, old = median_time(lambda x=x, k=k: former_fit_mixture(x, k), args.repeats)
        t_new, new = median_time(lambda x=x, k=k: moves._fit_mixture(x, k), args.repeats)
        same = (old is None and new is None) or (
            old is not None and new is not None
            and all(np.allclose(a, b, rtol=1e-6, atol=1e-9) for a, b in zip(old, new, strict=True)))
        lines.append(f"| {m} | {d} | {k} | {1e3 * t_old:.1f} ms | {1e3 * t_new:.1f} ms | "
                     f"{t_old / t_new:.2f}x | {'yes' if same else 'NO'} |")
        print(lines[-1], flush=True)

    data = load(bundled_data())
    lines += ["", "**Whole fits** on the bundled five-frequency record (default sampler, "
              "seed 0, up to 5 000 steps):", "",
              "| posterior | path | wall time | steps | converged | ratio |",
              "|---|---|---|---|---|---|"]
    with mock.patch.object(moves, "_fit_mixture", former_fit_mixture):
        t_old, f_old = _fit(PLAIN, data)
    t_new, f_new = _fit(PLAIN, data)
    for label, t, f in (("former EM", t_old, f_old), ("EM now", t_new, f_new)):
        c = f.sampling.convergence
        lines.append(f"| {PLAIN} | {label} | {t:.1f} s | {c.n_steps} | "
                     f"{f.sampling.converged} | {t_old / t:.2f}x |")
        print(lines[-1], flush=True)
    with mock.patch.object(Unexplained, "_linear_columns", lambda *a, **k: None):
        t_gen, f_gen = _fit(CANDIDATE, data)
    t_cf, f_cf = _fit(CANDIDATE, data)
    # the two designs agree to rounding (1e-14 of the output), not bit for bit: the
    # chains part where an acceptance sits at that rounding, so their posteriors are
    # compared (mean difference in posterior sd, the sd ratio)
    a, b = f_gen.sampling.draws(2000, seed=0), f_cf.sampling.draws(2000, seed=0)
    sd = a.std(axis=0)
    shift = float(np.max(np.abs(a.mean(axis=0) - b.mean(axis=0)) / sd))
    ratio = b.std(axis=0) / sd
    for label, t, f in (("generic design", t_gen, f_gen), ("closed form", t_cf, f_cf)):
        c = f.sampling.convergence
        lines.append(f"| {CANDIDATE} | {label} | {t:.1f} s | {c.n_steps} | "
                     f"{f.sampling.converged} | {t_gen / t:.2f}x |")
        print(lines[-1], flush=True)
    lines += ["", f"The two design paths agree to rounding, so their chains part: the "
              f"posterior means differ by at most {shift:.2f} posterior sd and the sds by "
              f"a factor {ratio.min():.2f}-{ratio.max():.2f} (2 000 draws each). The "
              "former EM's proposals differ from today's in the last bits too."]
    text = "\n".join(lines)
    print(text)
    if args.write:
        write_section("fit_paths", "Issue 59: the mixture EM and the smooth term's design",
                      text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
