"""Undeclared effect: what does a hysteresis model miss on measured data, and what does
adding it buy?

Reproduces the close-the-loop result on measured data: a base model (Bouc–Wen by
default, in the form that can draw the data set's loop: see :data:`BASE_MODELS`) is
fitted to a measured record; its residual is tested for each catalogue effect
(creep, rate dependence, asymmetry, drift, delay, coloured noise, an auxiliary column, a
change point) with score tests, scanned for anything else it depends on (loop position,
rate, time since a reversal, time, every extra column of the file -- a held-out,
randomisation-calibrated scan) and for non-harmonic spectral lines; the effect that fires
is added to the model, the model is refitted, and the effect is kept only when the
cycle-wise held-out predictive density (PSIS-LOO elpd) improves by more than
``--threshold`` standard errors and its reading is physically plausible for the device
(:data:`PLAUSIBLE_FOR`; :func:`bayeshyst.diagnosis.diagnose`). The answer per data set:
which effect was added (or none), the verdict in words (what is left, what is tied with
what and which experiment would separate them), the RMSE and max error of the
posterior-mean prediction before and after -- overall and per excitation frequency -- and
Δelpd ± se of every augmentation tried.

Data sets (``--datasets``; read from ``../shared/data`` or ``$BAYESHYST_SHARED_DATA`` --
without that folder the script exits with status 2 and one line saying so):

* ``piezo_150v`` -- piezo actuator, ±150 V / 1 Hz, 5 kHz
  (:func:`~bayeshyst.data.measured.load_piezo_actuator_150v`); the full run decimates
  it to 1 kHz (every 5th sample) and uses the whole record, 0 V lead-in and virgin
  branch as (unscored) warm-up;
* ``micromanipulator`` -- piezo micromanipulator, 1 Hz, 200 Hz, used whole
  (:func:`~bayeshyst.data.measured.load_piezo_micromanipulator`, ``which="model"``);
* ``mr_damper`` -- MR damper, one diagnosis per coil current (``--mr-currents``, default
  all five: 0, 0.25, 0.5, 0.75, 1 A), all six frequencies each, decimated to about 200
  samples per cycle (:func:`~bayeshyst.data.measured.load_mr_damper`).

The full run does all three; quick mode only the 150 V set, cut to a short record
(about 100 samples per cycle, 0 V lead-in trimmed to 0.2 s, warm-up plus 3 cycles).
Every record's cut is recorded in ``summary.json`` (see :mod:`analyses._common`).

Outputs in ``--out``: one folder per data set with what ``bayeshyst diagnose`` writes
(:func:`bayeshyst.outputs.diagnose_outputs.write_diagnosis_outputs`: ``summary.json``,
``diagnosis.txt``, ``steps.csv``, posteriors, figures), ``undeclared_effect.txt`` and the
combined ``summary.json`` (written last).

Run (from the repository root)::

    python -m analyses.undeclared_effect                  # full: 3 data sets, <= 6 rounds,
                                                          # <= 20 000 steps per fit (40 000
                                                          # for one that has not converged
                                                          # by then), <= 5 exact LOO
                                                          # refits each (hours)
    python -m analyses.undeclared_effect --quick          # seconds: 150 V set, 1 round
    python -m analyses.undeclared_effect --datasets piezo_150v --max-rounds 1 --steps 3000 \\
        --max-refits 0                                    # the first round only (minutes)
    python -m analyses.undeclared_effect --datasets piezo_150v --model "pi_play(n_operators=8)"

Quick mode (``--quick``): one round, one candidate effect refitted, 200 sampler steps,
no exact LOO refits, 50 prediction draws, no second run of an unconverged fit; its fits
are NOT converged and its outputs say so.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from analyses._common import (
    EXIT_OK,
    MEASURED,
    MR_CURRENTS,
    Cut,
    Progress,
    base_parser,
    budget,
    describe_cut,
    load_measured,
    name_list,
    non_negative_float,
    non_negative_int,
    positive_int,
    run,
    slug,
    write_text,
)
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.files import write_json

PROG = "undeclared_effect"

#: Base model per data set (``--model`` sets one for all). The piezo stages take the
#: review's piezo form ``y = k u - h``. An MR damper's force loop runs the other way
#: round (the force leads the displacement: steep after each reversal, then a plateau),
#: which the piezo form cannot draw for any parameters (fitted anyway it is a linear
#: spring: RMSE 146 N at 0 A, force span ~400 N); it takes Spencer's form ``F = k x + h``
#: (``sign=1``), in the saturation coordinates, whose stable region is a product of
#: intervals (its loop needs beta + gamma a thousand times below beta, against the
#: classical coordinates' boundary).
BASE_MODELS = {"piezo_150v": "bouc_wen", "micromanipulator": "bouc_wen",
               "mr_damper": "bouc_wen(sign=1, parametrisation='saturation')"}
#: Plausible readings per data set (:data:`bayeshyst.diagnosis.verdict.PLAUSIBLE`, a piezo
#: stage's, unless given here). The MR damper sits in a servo-hydraulic press whose
#: displacement and force channels are sampled by one acquisition and smoothed by the same
#: moving average (SOURCE.md), so neither a sensor chain's delay nor the filter's lag
#: separates them; set before the damper was diagnosed.
MR_DAMPER_PLAUSIBLE = {
    "delay.d": (0.0, 5e-3, "the press's displacement and force are sampled together and "
                           "filtered alike: a relative delay beyond ~5 ms is not the rig's"),
    "second_order.f_n": (10.0, 1e6, "a load frame carrying a damper resonates above 10 Hz"),
    "creep.c": (-0.5, 0.5, "creep moves the force by less than half its static value"),
}
PLAUSIBLE_FOR = {"mr_damper": MR_DAMPER_PLAUSIBLE}

# to the end: every candidate of a round is tried before the loop concludes (a round's
# first two candidates -- score tests that fired on structure a column explains -- had
# used up the MR damper's budget while the scan still saw 86 % of the residual)
FULL = {"datasets": MEASURED, "sampler": SamplerSettings(max_steps=20_000), "max_rounds": 6,
        "max_candidates": 12, "max_refits": 5, "n_draws": 200, "budget_doublings": 1,
        "cuts": {"piezo_150v": Cut(samples_per_cycle=1000),  # 5 kHz -> 1 kHz
                 "micromanipulator": Cut(),
                 "mr_damper": Cut(samples_per_cycle=200)}}
QUICK = {"datasets": ("piezo_150v",), "sampler": SamplerSettings(max_steps=200, first_chunk=200),
         "max_rounds": 1,
         "max_candidates": 1, "max_refits": 0, "n_draws": 50, "budget_doublings": 0,
         "cuts": {key: Cut(samples_per_cycle=100, cycles=3, trim_rest_s=0.2)
                  for key in MEASURED}}


def build_parser() -> argparse.ArgumentParser:
    """Options of the undeclared-effect analysis."""
    p = base_parser(PROG, __doc__)
    p.add_argument("--datasets", type=name_list, default=None, metavar="A,B,...",
                   help=f"measured data sets (default {','.join(FULL['datasets'])}; "
                        f"--quick {','.join(QUICK['datasets'])})")
    p.add_argument("--model", default=None,
                   help="base model name or spec string for every data set (default: "
                        "bouc_wen for the piezo sets, "
                        f"{BASE_MODELS['mr_damper']} for the MR damper)")
    p.add_argument("--likelihood", default="gaussian",
                   help="base likelihood: gaussian (default), student_t or ar1")
    p.add_argument("--effects", type=name_list, default=None, metavar="A,B,...",
                   help="candidate effects (default all: creep, rate_dependence, asymmetry, "
                        "drift, delay, colored_noise)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="family-wise level of the residual tests (default 0.01)")
    p.add_argument("--threshold", type=non_negative_float, default=2.0, metavar="T",
                   help="keep an effect when the held-out elpd improves by more than T "
                        "standard errors (default 2)")
    p.add_argument("--max-rounds", type=positive_int, default=None, metavar="N",
                   help="most effects added (default 6; --quick 1)")
    p.add_argument("--max-candidates", type=positive_int, default=None, metavar="N",
                   help="candidates refitted per round before it gives up (default 12: "
                        "every one; --quick 1)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="step budget per ensemble of every fit (default 20000; --quick 200)")
    p.add_argument("--budget-doublings", type=non_negative_int, default=None, metavar="N",
                   help="times an unconverged fit is sampled again with twice the steps "
                        "before it is reported as not converged (default 1; --quick 0)")
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="walkers per ensemble (default: from the number of parameters)")
    p.add_argument("--max-refits", type=non_negative_int, default=None, metavar="N",
                   help="exact LOO refits per fit for cycles with Pareto k > 0.7 (each costs a "
                        "fit; default 5; --quick 0)")
    p.add_argument("--samples-per-cycle", type=positive_int, default=None, metavar="N",
                   help="decimate every record to about N samples per excitation cycle "
                        "(default: 1000 for the 150 V set, 200 for the MR damper, the "
                        "micromanipulator whole; --quick 100)")
    p.add_argument("--mr-currents", type=_currents, default=MR_CURRENTS, metavar="A,B,...",
                   help="coil currents of the MR-damper tests [A], one diagnosis each "
                        "(default all: 0,0.25,0.5,0.75,1)")
    p.add_argument("--no-checkpoint", action="store_true",
                   help="do not checkpoint the fits (OUT/<dataset>/checkpoints/)")
    return p


def _currents(text: str) -> tuple[float, ...]:
    """``"0,0.5"`` -> ``(0.0, 0.5)``: coil currents of the MR-damper tests."""
    try:
        values = tuple(float(v) for v in name_list(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected coil currents like 0,0.5,1 [A], got "
                                         f"{text!r}") from None
    bad = [v for v in values if v not in MR_CURRENTS]
    if bad:  # (name_list already refused an empty list)
        raise argparse.ArgumentTypeError(f"coil currents must be among "
                                         f"{', '.join(f'{c:g}' for c in MR_CURRENTS)} A, "
                                         f"got {text!r}")
    return values


# ------------------------------------------------------------------------- results
def dataset_summary(key: str, data: Any, result: Any, folder: str) -> dict[str, Any]:
    """What the combined summary says about one data set."""
    before, after = result.base.overall, result.final.overall
    steps = [{"round": s.index, "effect": s.effect, "accepted": bool(s.accepted),
              "outcome": s.outcome,
              "model_after": s.model_after, "delta_elpd": s.delta_elpd,
              "delta_elpd_se": s.delta_elpd_se, "p_adjusted": s.test.p_adjusted,
              "rmse_before": s.before.rmse, "rmse_after": s.after.rmse,
              "converged": bool(s.converged), "reason": s.reason,
              "tied_with": list(s.tied_with), "experiment": s.experiment,
              "per_frequency": [{"frequency_hz": b.frequency_hz, "rmse_before": b.rmse,
                                 "rmse_after": a.rmse} for b, a in s.per_frequency]}
             for s in result.steps]
    accepted = [s for s in steps if s["accepted"]]
    converged = bool(result.base.sampling.converged and result.final.sampling.converged)
    # the candidates whose gate decided nothing: the result stands, they are left open
    undecided = [f"round {s.index}: {s.effect}" for s in result.undecided]
    return {
        "dataset": key, "name": data.name, "folder": folder,
        "records": describe_cut(data), "output_unit": data[0].units.get("y", ""),
        "base_model": result.base_model, "final_model": result.final_model,
        "effects_found": list(result.effects_found),
        "rmse_before": before.rmse, "rmse_after": after.rmse,
        "max_error_before": before.max_error, "max_error_after": after.max_error,
        "nrmse_percent_before": before.nrmse_percent,
        "nrmse_percent_after": after.nrmse_percent,
        "rmse_reduction_percent": (100 * (1 - after.rmse / before.rmse)
                                   if before.rmse > 0 else math.nan),
        "delta_elpd": sum(s["delta_elpd"] for s in accepted) if accepted else 0.0,
        "per_frequency": [{"frequency_hz": b.frequency_hz, "rmse_before": b.rmse,
                           "rmse_after": a.rmse}
                          for b, a in zip(result.base.per_frequency,
                                          result.final.per_frequency, strict=True)],
        "verdict": result.verdict, "ties": list(result.ties),
        "steps": steps, "converged": converged,
        "status": ("NOT converged" if not converged else
                   f"converged; not decided: {', '.join(undecided)}" if undecided else
                   "converged"),
        "undecided": undecided,
        "warnings": list(result.warnings),
    }


def _f(x: Any, spec: str = ".4g") -> str:
    return format(x, spec) if isinstance(x, int | float) and math.isfinite(x) else "n/a"


def report_text(entries: list[dict[str, Any]], quick: bool) -> str:
    """The combined plain-text report (``undeclared_effect.txt``)."""
    lines = ["UNDECLARED EFFECT: residual -> missing effect -> refit, on measured data"]
    bad = [e["dataset"] for e in entries if not e["converged"]]
    if bad:
        lines += ["", "*" * 78, f"*** NOT converged: fits on {', '.join(bad)} did not converge; "
                  "the tests, Δelpd and errors are provisional"
                  + (" (quick run)." if quick else " (raise --steps)."), "*" * 78]
    for e in entries:
        unit = e["output_unit"]
        found = ", ".join(e["effects_found"]) or "none"
        lines += ["", f"== {e['dataset']} ({e['name']}; {e['status']})"]
        lines += [f"   {r['record']}: {r['n']} samples at {r['fs_hz']:.6g} Hz, warm-up "
                  f"{r['warmup']}; {r['cut']}" for r in e["records"]]
        lines.append(f"   {e['base_model']} -> {e['final_model']}; effect(s) added: {found}")
        lines.append(f"   RMSE {_f(e['rmse_before'])} -> {_f(e['rmse_after'])} {unit} "
                     f"({_f(e['nrmse_percent_before'], '.3f')} % -> "
                     f"{_f(e['nrmse_percent_after'], '.3f')} % of stroke; "
                     f"{_f(e['rmse_reduction_percent'], '.1f')} % lower); max error "
                     f"{_f(e['max_error_before'])} -> {_f(e['max_error_after'])} {unit}")
        if len(e["per_frequency"]) > 1:
            lines.append("   per frequency: " + "; ".join(
                f"{f['frequency_hz']:.4g} Hz {_f(f['rmse_before'])} -> {_f(f['rmse_after'])}"
                for f in e["per_frequency"]))
        lines.append(f"   verdict: {e['verdict']}")
        if not e["steps"]:
            lines.append("   no candidate effect fired on the base model's residual")
        for s in e["steps"]:
            verdict = "ACCEPTED" if s["accepted"] else s["outcome"]
            lines.append(f"   round {s['round']}: +{s['effect']}: {verdict}; Δelpd "
                         f"{_f(s['delta_elpd'], '.1f')} ± {_f(s['delta_elpd_se'], '.1f')} "
                         f"(p_adj {_f(s['p_adjusted'], '.2g')}); RMSE "
                         f"{_f(s['rmse_before'])} -> {_f(s['rmse_after'])} {unit}"
                         f"{'' if s['converged'] else '; NOT converged'}"
                         + (f"; cannot tell from {', '.join(s['tied_with'])}"
                            if s["tied_with"] else ""))
        lines += [f"   warning: {w}" for w in e["warnings"]]
    return "\n".join(lines)


# ---------------------------------------------------------------------------- main
def _analyse(args: argparse.Namespace) -> int:
    from bayeshyst.data.measured import shared_data_root
    from bayeshyst.diagnosis import EFFECTS, diagnose, get_effect
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs.assemble import diagnosis_figures
    from bayeshyst.outputs.diagnose_outputs import write_diagnosis_outputs

    log = Progress(PROG, args.quiet)
    cfg = budget(args, QUICK, FULL, {"max_rounds": args.max_rounds,
                                     "max_candidates": args.max_candidates,
                                     "max_refits": args.max_refits,
                                     "budget_doublings": args.budget_doublings})
    keys = tuple(args.datasets or cfg["datasets"])
    # validate everything cheap before anything is written
    unknown = [k for k in keys if k not in MEASURED]
    if unknown:
        raise ParameterError(f"--datasets: unknown {unknown}; known: {', '.join(MEASURED)}")
    if not 0.0 < args.alpha < 1.0:
        raise ParameterError(f"--alpha must be in (0, 1), got {args.alpha:g}")
    models = {k: args.model or BASE_MODELS[k] for k in keys}
    for spec in set(models.values()):
        get_model(spec)
    get_likelihood(args.likelihood)
    effects = tuple(EFFECTS) if args.effects is None else args.effects
    for name in effects:
        get_effect(name)  # raises, naming the valid effects
    try:
        shared_data_root()
    except DataError as exc:  # exit status 2 with this one line: nothing to analyse
        raise DataError(f"the measured data sets are not available: {exc}") from None
    cuts = {k: (cfg["cuts"][k] if args.samples_per_cycle is None
                else dataclasses.replace(cfg["cuts"][k],
                                         samples_per_cycle=args.samples_per_cycle))
            for k in keys}
    datasets = []
    for k in keys:  # the MR damper: one diagnosis per coil current
        for current in (args.mr_currents if k == "mr_damper" else (None,)):
            label = k if current is None else f"{k}_{current:g}A"
            datasets.append((label, models[k], PLAUSIBLE_FOR.get(k),
                             load_measured(k, cuts[k], mr_current=current or 0.0)))
    out = Path(args.out)
    entries = []
    for key, model, plausible, data in datasets:
        folder = out / slug(key)
        n_fits = 0

        def on_fit(fit: Any, key: str = key) -> None:
            nonlocal n_fits
            n_fits += 1
            fired = [t.effect for t in fit.analysis.fired()]
            log(f"{key}: fit {n_fits}: {fit.label} "
                f"({'converged' if fit.sampling.converged else 'NOT converged'}); RMSE "
                f"{fit.overall.rmse:.4g}, elpd {fit.elpd:.1f}; firing: "
                f"{', '.join(fired) or 'none'}")

        log(f"{key}: diagnosing {model} on {data.name} ({len(data)} record(s), "
            f"{data.n_samples} samples; {'; '.join(r['cut'] for r in describe_cut(data))})")
        # the gate's decisions as they are made: a round of a measured set can take hours
        with log.follow("bayeshyst.diagnosis.loop"):
            result = diagnose(data, model, args.likelihood, effects=effects,
                              alpha=args.alpha, threshold=args.threshold,
                              max_rounds=cfg["max_rounds"],
                              max_candidates=cfg["max_candidates"],
                              sampler=cfg["sampler"], n_draws=cfg["n_draws"],
                              max_refits=cfg["max_refits"], plausible=plausible,
                              budget_doublings=cfg["budget_doublings"],
                              checkpoint_dir=(None if args.no_checkpoint
                                              else folder / "checkpoints"),
                              on_fit=on_fit)
        write_diagnosis_outputs(result, folder, data_name=data.name,
                                figures=None if args.no_figures or args.quick
                                else diagnosis_figures(result))
        entry = dataset_summary(key, data, result, slug(key))
        log(f"{key}: effects found: {', '.join(entry['effects_found']) or 'none'}; RMSE "
            f"{_f(entry['rmse_before'])} -> {_f(entry['rmse_after'])} {entry['output_unit']}")
        entries.append(entry)
    text = report_text(entries, args.quick)
    write_text(out / "undeclared_effect.txt", text)
    converged = all(e["converged"] for e in entries)
    summary = {
        "command": PROG, "quick": bool(args.quick), "base_models": models,
        "likelihood": args.likelihood, "effects": list(effects),
        "converged": converged, "status": "converged" if converged else "NOT converged",
        "datasets": entries,
        "settings": {k: v for k, v in cfg.items() if k not in ("cuts", "datasets")}
        | {"sampler": cfg["sampler"].to_dict(), "alpha": args.alpha,
           "threshold": args.threshold, "seed": cfg["sampler"].seed,
           "mr_currents_a": list(args.mr_currents)},
        "files": {"text": "undeclared_effect.txt",
                  "per_dataset": [e["folder"] for e in entries]},
        "runtime_s": round(log.elapsed, 2),
    }
    write_json(out / "summary.json", summary)
    print(text)
    print(f"outputs in {out}/: summary.json, undeclared_effect.txt"
          + "".join(f", {e['folder']}/" for e in entries))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the undeclared-effect analysis; return the exit status (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    return run(PROG, _analyse, args)


if __name__ == "__main__":
    sys.exit(main())
