"""Screening a diagnosis candidate from its MAP, against the sampled candidate's own score.

Runs the demo's diagnosis (the bundled virtual actuator, the chosen model, the demo's
settings) and, for every fit it makes, scores that fit's posterior a second time without
its chains: :func:`bayeshyst.diagnostics.laplace_loo.laplace_loo` at the MAP the sampler
started from. For every step of the loop it prints the gate both ways -- the held-out
elpd change of the candidate against the current fit and its standard error, from the
candidate's MCMC LOO (what decides today) and from its Laplace-PSIS LOO (the screen) --,
the screen's worst Pareto k, whether the two gates agree, and the wall time of the
candidate's fit against its screen's.

Usage::

    python benchmarks/bench_screening.py [--write] [--rounds N] [--draws S]
"""

from __future__ import annotations

import argparse
import os
import pickle
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="record in benchmarks/RESULTS.md")
    ap.add_argument("--rounds", type=int, default=3, help="diagnosis rounds (demo: 3)")
    ap.add_argument("--draws", type=int, default=2000, help="proposal draws of the screen")
    ap.add_argument("--jobs", type=int, default=2, help="the diagnosis' workers")
    ap.add_argument("--cache", type=Path, default=None,
                    help="pickle of the diagnosis and its fits: read if it exists, else "
                         "written (to compare screens without sampling again)")
    args = ap.parse_args(argv)
    from bayeshyst.data import load
    from bayeshyst.demo import DEMO_DEFAULT, bundled_data
    from bayeshyst.diagnosis import diagnose
    from bayeshyst.diagnostics.laplace_loo import laplace_loo
    from bayeshyst.selection.ranking import paired_difference

    data = load(bundled_data())
    s = DEMO_DEFAULT.settings
    fits: dict[str, tuple[object, float]] = {}
    last = [time.perf_counter()]

    def on_fit(fit: object) -> None:
        now = time.perf_counter()
        fits[fit.label] = (fit, now - last[0])
        last[0] = now

    if args.cache is not None and args.cache.exists():
        with args.cache.open("rb") as fh:
            result, fits, t_diag = pickle.load(fh)
    else:
        t0 = time.perf_counter()
        result = diagnose(data, "pi_play(n_operators=8)", s.likelihood, effects=s.effects,
                          max_rounds=args.rounds, max_candidates=s.max_candidates,
                          sampler=s.sampler, max_refits=s.max_refits,
                          budget_doublings=s.budget_doublings, n_jobs=args.jobs,
                          on_fit=on_fit)
        t_diag = time.perf_counter() - t0
        if args.cache is not None:
            with args.cache.open("wb") as fh:
                pickle.dump((result, fits, t_diag), fh)
    screens = {}
    for label, (fit, _) in fits.items():
        t1 = time.perf_counter()
        screens[label] = (laplace_loo(fit.posterior, fit.sampling.start, n_draws=args.draws,
                                      seed=0), time.perf_counter() - t1)
    lines = [f"diagnosis: {t_diag:.0f} s, {len(fits)} fits; effects {result.effects_found}",
             "", "| step | gate (MCMC) | gate (screen) | worst k | agree | fit s | screen s |",
             "|---|---|---|---|---|---|---|"]
    agree = n = 0
    for st in result.steps:
        if st.model_after not in fits or st.model_before not in fits:
            continue
        cur = fits[st.model_before][0]
        cand, t_fit = fits[st.model_after]
        scr, t_scr = screens[st.model_after]
        d_m, se_m = paired_difference(cand.pointwise_elpd, cur.pointwise_elpd)
        d_s, se_s = paired_difference(scr.pointwise, cur.pointwise_elpd)
        thr = result.settings.threshold
        ok_m, ok_s = d_m > thr * se_m, d_s > thr * se_s
        n += 1
        agree += ok_m == ok_s
        lines.append(f"| {st.index}: {st.effect} | {d_m:+.1f} (se {se_m:.1f}) "
                     f"{'pass' if ok_m else 'fail'} | {d_s:+.1f} (se {se_s:.1f}) "
                     f"{'pass' if ok_s else 'fail'} | {scr.worst_k:.2f} | "
                     f"{'yes' if ok_m == ok_s else 'NO'} | {t_fit:.0f} | {t_scr:.1f} |")
    lines.append("")
    lines.append(f"{agree} of {n} gates agree")
    for label, (scr, t_scr) in screens.items():
        fit = fits[label][0]
        err = scr.pointwise - fit.pointwise_elpd
        lines.append(f"{label}: screen - MCMC per cycle: median {np.median(err):+.2f}, "
                     f"max |.| {np.max(np.abs(err)):.2f} nat; k worst {scr.worst_k:.2f} "
                     f"(posterior {scr.posterior_k:.2f}); ESS {scr.ess:.0f}; "
                     f"{len(scr.refitted)} cycles from their own Laplace; {t_scr:.1f} s")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        load_avg = os.getloadavg()
        write_section("screening", "Screening diagnosis candidates from the MAP",
                      f"{platform.machine()}, {os.cpu_count()} cores, load "
                      f"{load_avg[0]:.1f} at the end\n\n{text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
