"""Command line: a thin argparse layer over the public API.

Exit status: 0 success, 2 bad input (one clear line on stderr, nothing written half-way),
1 internal error. A command that fails before its first result leaves its output
folder as it found it (:func:`bayeshyst.files.removed_on_failure`).

Each command runs the library, computes what its writer needs (a fit's InferenceData,
the figures of :mod:`bayeshyst.outputs.assemble`), hands both to its writer in
:mod:`bayeshyst.outputs` and prints the summary the writer returns; ``--json`` prints it
with the serialiser ``summary.json`` was written with, so the two are the same text.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst._version import __version__
from bayeshyst.errors import DataError, ModelError, ParameterError
from bayeshyst.files import RunOutputs, json_text, removed_on_failure
from bayeshyst.inference.settings import MOVES, SamplerSettings

__all__ = ["build_parser", "int_at_least", "main", "non_negative_float", "non_negative_int",
           "positive_int", "probability", "sampler_settings"]

EXIT_OK, EXIT_INTERNAL, EXIT_BAD_INPUT = 0, 1, 2


def _models_summary(names: Sequence[str]) -> list[dict[str, Any]]:
    from bayeshyst import models

    out = []
    for name in names:
        model = models.get(name)
        space = model.param_space()
        params = []
        for p in space.params:
            params.append({"name": p.name, "shape": list(p.shape), "unit": p.unit,
                           "prior": str(p.prior), "description": p.description})
        for p in space.fixed_params:
            params.append({"name": p.name, "shape": list(p.shape), "unit": p.unit,
                           "fixed": np.asarray(space.fixed[p.name]).tolist(),
                           "description": p.description})
        out.append({
            "name": name,
            "class": type(model).__name__,
            "equation": model.equation,
            "rate_dependent": bool(model.rate_dependent),
            "analytic_inverse": bool(model.has_inverse),
            "summary": (type(model).__doc__ or "").strip().splitlines()[0],
            "settings": {k: v for k, v in vars(model).items() if not k.startswith("_")},
            "parameters": params,
        })
    return out


def _cmd_models(args: argparse.Namespace) -> int:
    from bayeshyst import models

    names = models.names()
    if args.name:
        unknown = [n for n in args.name if n not in names]
        if unknown:
            raise ModelError(f"unknown model(s) {unknown}; available: {', '.join(names)}")
        names = args.name
    summary = _models_summary(names)
    if args.json:
        json.dump({"models": summary}, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
        return EXIT_OK
    for m in summary:
        flags = []
        if m["rate_dependent"]:
            flags.append("rate-dependent")
        if m["analytic_inverse"]:
            flags.append("analytic inverse")
        settings = ", ".join(f"{k}={v}" for k, v in m["settings"].items())
        print(f"{m['name']}  [{m['class']}({settings})]  {m['equation']}"
              + (f"  ({'; '.join(flags)})" if flags else ""))
        print(f"    {m['summary']}")
        for p in m["parameters"]:
            shape = "x".join(map(str, p["shape"])) or "scalar"
            what = p.get("prior") or f"fixed = {np.round(p['fixed'], 4).tolist()}"
            print(f"    {p['name']:<16} {shape:<7} {p['unit']:<8} {what}  - {p['description']}")
        print()
    return EXIT_OK


def int_at_least(minimum: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum`` (``what`` names it in the message)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value

    return parse


positive_int = int_at_least(1, "a positive integer")
non_negative_int = int_at_least(0, "an integer >= 0")

#: The options every sampling command maps onto its :class:`SamplerSettings`, and the
#: field each one sets (``--quiet`` sets ``progress`` to its negation).
_SAMPLER_FLAGS = {"seed": "seed", "walkers": "n_walkers", "steps": "max_steps",
                  "moves": "moves"}


def sampler_settings(args: argparse.Namespace, **overrides: Any) -> SamplerSettings:
    """The one :class:`SamplerSettings` of a command, from its command-line options.

    ``--seed``, ``--walkers`` (``n_walkers``), ``--steps`` (``max_steps``), ``--moves``
    and ``--quiet`` (``progress = not quiet``) are mapped here and nowhere else; an
    option the command does not have (``bayeshyst demo`` has no ``--steps``), or left
    at None, keeps the record's default. ``overrides`` (``checkpoint=...``, a demo's
    budget) replace what the options give. ``first_chunk`` stays at its default unless
    the step budget is below it.

    Raises
    ------
    ParameterError
        For values the record rejects (``--steps 5``: fewer steps than a convergence
        check needs).
    """
    values: dict[str, Any] = {}
    for flag, name in _SAMPLER_FLAGS.items():
        value = getattr(args, flag, None)
        if value is not None:
            values[name] = value
    if getattr(args, "quiet", None) is not None:
        values["progress"] = not args.quiet
    values.update(overrides)
    if "first_chunk" not in values and "max_steps" in values:
        values["first_chunk"] = min(SamplerSettings.first_chunk, values["max_steps"])
    return SamplerSettings(**values)


def _cmd_fit(args: argparse.Namespace) -> int:
    from bayeshyst import diagnostics
    from bayeshyst.data import load
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs import write_fit_outputs
    from bayeshyst.outputs.assemble import fit_figures

    # validate everything cheap before the long part starts
    data = load(args.data)
    model = get_model(args.model)
    likelihood = get_likelihood(args.likelihood)
    out = Path(args.out)
    checkpoint = None if args.no_checkpoint else out / "checkpoint.h5"
    if not args.quiet:
        print(f"bayeshyst fit: {model.name} / {likelihood.name} on {data.name} "
              f"({len(data)} record(s), {data.n_samples} samples)", file=sys.stderr)
    sampler = sampler_settings(args, checkpoint=checkpoint)
    with removed_on_failure(out) as outputs:
        fit = fit_model(data, model, likelihood, sampler=sampler)
        # the sampled chains are the result: should writing fail, their checkpoint stays
        # and the rerun resumes from it instead of sampling again
        outputs.keep()
        idata = diagnostics.to_inference_data(fit.posterior, fit.sampling, seed=sampler.seed)
        figures = None if args.no_figures else fit_figures(fit, seed=sampler.seed)
        summary = write_fit_outputs(fit, out, idata=idata, figures=figures,
                                    data_path=str(args.data))
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(fit)
        print(f"outputs in {out}/: summary.json, posterior.nc"
              + ("" if args.no_figures else ", " + ", ".join(summary["files"]["figures"])))
    return EXIT_OK


def _cmd_compare(args: argparse.Namespace) -> int:
    from bayeshyst.data import load
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.outputs.assemble import comparison_figures
    from bayeshyst.outputs.compare_outputs import write_comparison_outputs
    from bayeshyst.selection import check_models, compare_models

    # validate everything cheap before the long part starts
    data = load(args.data)
    models = check_models(args.models)
    get_likelihood(args.likelihood)
    out = Path(args.out)
    sampler = sampler_settings(args)
    if not args.quiet:
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        print(f"bayeshyst compare: {', '.join(models)} on {data.name} ({len(data)} record(s); "
              f"frequencies [Hz]: {freqs})", file=sys.stderr)
    # each finished fit stores its posterior: from the first one on, a failure keeps
    # what is there for the rerun to resume from
    with removed_on_failure(out, results=("posteriors/*.nc",)):
        result = compare_models(data, models, likelihood=args.likelihood, sampler=sampler,
                                lofo=not args.no_lofo, max_refits=args.max_refits,
                                gp_n_train=args.gp_train, n_jobs=args.jobs, out_dir=out,
                                progress=sampler.progress)
        figures = None if args.no_figures else comparison_figures(result)
        summary = write_comparison_outputs(result, out, figures=figures,
                                           data_path=str(args.data))
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        print()
        print("\n".join(summary["statements"]))
        for w in summary["warnings"]:
            print(f"warning: {w}")
        print(f"outputs in {out}/: summary.json, comparison.csv, comparison.txt"
              + "".join(f", {f}" for f in summary["files"]["figures"])
              + (", posteriors/" if summary["files"]["posteriors"] else ""))
    return EXIT_OK


def probability(text: str) -> float:
    """An argparse type: a number strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {value:g}")
    return value


def _cmd_compensate(args: argparse.Namespace) -> int:
    from bayeshyst import diagnostics
    from bayeshyst.data import load
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inverse.compensate import REFERENCE_KINDS, compensate, load_reference
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs.assemble import compensation_figures
    from bayeshyst.outputs.compensate_outputs import write_compensation_outputs, written_files

    # validate everything cheap before the long part starts
    data = load(args.data)
    model = get_model(args.model)
    likelihood = get_likelihood(args.likelihood)
    if args.reference in REFERENCE_KINDS:
        reference: Any = args.reference
        if not data.frequencies:
            raise DataError(f"{args.data}: no record has a frequency_hz, so there is no "
                            f"frequency to put a {args.reference} reference at; label the "
                            "records' frequencies or pass --reference FILE.csv")
    elif Path(args.reference).is_file():
        reference = load_reference(args.reference)
    else:
        raise DataError(f"{args.reference}: no such reference file (--reference takes "
                        f"{' or '.join(REFERENCE_KINDS)} or a CSV file with columns t,y)")
    out = Path(args.out)
    sampler = sampler_settings(
        args, checkpoint=None if args.no_checkpoint else out / "checkpoint.h5")
    if not args.quiet:
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        ref = args.reference if isinstance(reference, str) else f"file {args.reference}"
        print(f"bayeshyst compensate: {model.name} / {likelihood.name} on {data.name} "
              f"({len(data)} record(s); frequencies [Hz]: {freqs}); reference: {ref}",
              file=sys.stderr)
    with removed_on_failure(out) as outputs:
        fit = fit_model(data, model, likelihood, sampler=sampler)
        # the sampled chains are the first result: should the design fail, their
        # checkpoint stays and the rerun resumes from it instead of sampling again
        outputs.keep()
        result = compensate(data, model, fit=fit, reference=reference,
                            plant=None if args.plant == "auto" else args.plant,
                            n_design_draws=args.design_draws, robust_quantile=args.quantile,
                            sampler=sampler)
        idata = diagnostics.to_inference_data(fit.posterior, fit.sampling,
                                              seed=int(result.settings.get("seed", 0)))
        figures = None if args.no_figures else compensation_figures(result, fit=fit)
        summary = write_compensation_outputs(result, out, fit=fit, idata=idata,
                                             figures=figures, data_path=str(args.data))
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        for w in summary["warnings"]:
            print(f"warning: {w}")
        print(f"outputs in {out}/: " + ", ".join(written_files(summary)))
    return EXIT_OK


def _effect_list(text: str) -> tuple[str, ...]:
    """``creep,delay`` -> ``("creep", "delay")``; ModelError naming an unknown effect."""
    from bayeshyst.diagnosis import get_effect

    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ParameterError(f"--effects: no effect named in {text!r}")
    for n in names:
        get_effect(n)  # raises, listing the valid names
    return tuple(dict.fromkeys(names))


def non_negative_float(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from bayeshyst.data import load
    from bayeshyst.diagnosis import EFFECTS, diagnose
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs.assemble import diagnosis_figures
    from bayeshyst.outputs.diagnose_outputs import write_diagnosis_outputs

    # validate everything cheap before the long part starts
    data = load(args.data)
    model = get_model(args.model)
    likelihood = get_likelihood(args.likelihood)
    effects = tuple(EFFECTS) if args.effects is None else _effect_list(args.effects)
    out = Path(args.out)
    checkpoints = None if args.no_checkpoint else out / "checkpoints"
    sampler = sampler_settings(args)
    n_fits = 0

    def on_fit(fit: Any) -> None:
        nonlocal n_fits
        n_fits += 1
        outputs.keep()  # a finished fit is a result: its checkpoint makes a rerun quick
        if args.quiet:
            return
        fired = [t.effect for t in fit.analysis.fired()]
        conv = "converged" if fit.sampling.converged else "NOT converged"
        print(f"bayeshyst diagnose: fit {n_fits} done: {fit.label} ({conv}); RMSE "
              f"{fit.overall.rmse:.4g}, elpd {fit.elpd:.1f}; tests firing on its residual: "
              f"{', '.join(fired) or 'none'}", file=sys.stderr, flush=True)

    if not args.quiet:
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        print(f"bayeshyst diagnose: {model.name} / {likelihood.name} on {data.name} "
              f"({len(data)} record(s); frequencies [Hz]: {freqs}); candidate effects: "
              f"{', '.join(effects)}", file=sys.stderr)
    with removed_on_failure(out) as outputs:
        result = diagnose(data, args.model, likelihood.name, effects=effects,
                          alpha=args.alpha, threshold=args.threshold,
                          max_rounds=args.max_rounds, sampler=sampler,
                          checkpoint_dir=checkpoints, on_fit=on_fit)
        figures = None if args.no_figures else diagnosis_figures(result)
        summary = write_diagnosis_outputs(result, out, figures=figures,
                                          data_name=str(args.data))
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        print(f"outputs in {out}/: " + ", ".join(summary["outputs"])
              + ("" if checkpoints is None else ", checkpoints/"))
    return EXIT_OK


# a report's comparison stores each finished fit's posterior here; from the first one
# on, a failed report keeps what is there for the rerun to resume from
_REPORT_RESULTS = ("compare/posteriors/*.nc",)


def _report_run(data: Any, data_path: str, models: tuple[str, ...], settings: Any,
                args: argparse.Namespace, command: str,
                outputs: RunOutputs) -> tuple[Any, Any]:
    """The shared part of ``report`` and ``demo``: run every stage and write.

    ``outputs`` is the caller's :func:`removed_on_failure` of ``--out`` (a finished
    diagnosis fit marks the first result). Returns ``(result, summary)`` for
    :func:`_report_print`.
    """
    from bayeshyst.outputs.assemble import report_figures, report_posteriors
    from bayeshyst.outputs.report_outputs import write_report_outputs
    from bayeshyst.workflow import run_report

    out = Path(args.out)
    n_fits = 0

    def on_fit(fit: Any) -> None:
        nonlocal n_fits
        n_fits += 1
        outputs.keep()
        if not args.quiet:
            conv = "converged" if fit.sampling.converged else "NOT converged"
            print(f"bayeshyst {command}: diagnosis fit {n_fits} done: {fit.label} ({conv}); "
                  f"RMSE {fit.overall.rmse:.4g}", file=sys.stderr, flush=True)

    if not args.quiet:
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        print(f"bayeshyst {command}: {data.name} ({len(data)} record(s); frequencies [Hz]: "
              f"{freqs}); models: {', '.join(models)}", file=sys.stderr)
    result = run_report(data, models, settings=settings, out_dir=out,
                        progress=settings.sampler.progress, on_fit=on_fit)
    posteriors = report_posteriors(result)
    figures = None if args.no_figures else report_figures(result, posteriors)
    summary = write_report_outputs(result, out, posteriors=posteriors, figures=figures,
                                   data_path=data_path)
    return result, summary


def _report_print(args: argparse.Namespace, result: Any, summary: Any) -> int:
    """Print what ``report`` and ``demo`` did (after the outputs are written)."""
    out = Path(args.out)
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        for w in summary["warnings"]:
            print(f"warning: {w}")
        print(f"report: {out / 'report.html'}  (numbers: {out / 'summary.json'})")
    return EXIT_OK


def _report_settings(args: argparse.Namespace) -> Any:
    from bayeshyst.workflow import ReportSettings

    return ReportSettings(
        likelihood=args.likelihood, sampler=sampler_settings(args), lofo=not args.no_lofo,
        max_refits=args.max_refits, effects=None if args.effects is None
        else _effect_list(args.effects), max_rounds=args.max_rounds, n_jobs=args.jobs)


def _cmd_report(args: argparse.Namespace) -> int:
    from bayeshyst.data import load
    from bayeshyst.selection import check_models
    from bayeshyst.workflow import DEFAULT_MODELS

    # validate everything cheap before the long part starts
    data = load(args.data)
    models = check_models(args.models) if args.models else DEFAULT_MODELS
    settings = _report_settings(args)
    with removed_on_failure(args.out, results=_REPORT_RESULTS) as outputs:
        done = _report_run(data, str(args.data), models, settings, args, "report", outputs)
    return _report_print(args, *done)


def _cmd_demo(args: argparse.Namespace) -> int:
    from bayeshyst.data import load
    from bayeshyst.workflow import DEMO_DEFAULT, DEMO_QUICK, bundled_data

    plan = DEMO_QUICK if args.quick else DEMO_DEFAULT
    # the data regenerated into --out (no bundled data/) are the run's own, taken back
    # with the rest if it fails before its first result
    with removed_on_failure(args.out, results=_REPORT_RESULTS) as outputs:
        path = bundled_data("virtual_multifreq.csv", fallback_dir=Path(args.out) / "data")
        data = load(path)
        if plan.frequencies_hz is not None:
            data = data.select(plan.frequencies_hz)
        if not args.quiet:
            print(f"bayeshyst demo ({plan.description}) on the bundled virtual actuator "
                  f"data {path.name}", file=sys.stderr)
        # the plan's budget, the command line's seed and --quiet
        budget = {k: v for k, v in dataclasses.asdict(plan.settings.sampler).items()
                  if k not in ("seed", "progress", "checkpoint")}
        settings = dataclasses.replace(plan.settings,
                                       sampler=sampler_settings(args, **budget))
        done = _report_run(data, path.name, plan.models, settings, args, "demo", outputs)
    return _report_print(args, *done)


def _cmd_study(args: argparse.Namespace) -> int:
    from bayeshyst.outputs.assemble import study_output_figures
    from bayeshyst.outputs.study_outputs import write_study_outputs
    from bayeshyst.study import read_study, run_study
    from bayeshyst.study.tasks import slug

    # the whole study file is checked before anything starts (exit 2 on a bad one)
    study = read_study(args.study)
    out = Path(args.out) if args.out else Path(f"study-{slug(study.name)}")
    if not args.quiet:
        print(f"bayeshyst study: {study}; outputs in {out}/", file=sys.stderr)
    try:
        # each finished fit is stored as it completes: from the first one on, a failure
        # keeps what is there for the rerun to resume from
        with removed_on_failure(out, results=("fits/*.json",)):
            result = run_study(study, out, scheduler=args.scheduler, n_workers=args.workers,
                               serial=args.serial, retry_failed=args.retry_failed,
                               progress=not args.quiet)
            # the HTML report embeds the figures: --report draws them even with --no-figures
            draw = not args.no_figures or args.report
            summary = write_study_outputs(result, out, html=args.report,
                                          figures=study_output_figures(result) if draw else None)
    except KeyboardInterrupt:
        n_done = len(list((out / "fits").glob("*.json")))
        print(f"bayeshyst study: interrupted; {n_done} finished fit(s) are stored in "
              f"{out / 'fits'}; run the same command again to resume", file=sys.stderr)
        return 130
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        print(f"table: {out / 'table.csv'}; per frequency: {out / 'by_frequency.csv'}"
              + (f"; report: {out / 'study.html'}" if args.report else ""))
    return EXIT_OK


def _add_run_options(p: argparse.ArgumentParser, out_default: str, steps_help: str) -> None:
    """The options every command that samples shares: data, likelihood, output folder,
    seed, sampler budget, walkers, and what is printed and drawn."""
    p.add_argument("data", help="data file (.csv/.txt/.npz/.mat, JSON sidecar optional)")
    p.add_argument("--likelihood", default="gaussian", help="gaussian (default), student_t or ar1")
    p.add_argument("--out", default=out_default, help=f"output folder (default {out_default})")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--steps", type=positive_int, default=20_000, help=steps_help)
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="walkers per ensemble (default: from the number of parameters the "
                        "moves propose, max(12, 2 d + 2) structured, max(32, 4 ndim) de "
                        "and stretch)")
    p.add_argument("--moves", choices=MOVES, default="structured",
                   help="sampler moves: structured (default) = exact Gibbs draws of the "
                        "linear block + adaptive independence + differential evolution; "
                        "de = emcee's differential-evolution moves on every coordinate, "
                        "the previous engine, kept as a baseline; stretch = emcee's "
                        "affine-invariant stretch move")
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``bayeshyst`` command."""
    # argparse itself exits with status 2 on usage errors, as bad input should
    parser = argparse.ArgumentParser(prog="bayeshyst",
                     description="Bayesian identification of hysteresis in piezo actuators.")
    parser.add_argument("--version", action="version", version=f"bayeshyst {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p_models = sub.add_parser("models", help="list the models, their parameters and priors")
    p_models.add_argument("name", nargs="*", help="only these models")
    p_models.add_argument("--json", action="store_true", help="print JSON to stdout")
    p_models.set_defaults(func=_cmd_models)

    p_fit = sub.add_parser("fit", help="sample the posterior of one model given data")
    p_fit.add_argument("--model", required=True,
                       help="model name or spec string, e.g. bouc_wen+second_order")
    _add_run_options(p_fit, "bayeshyst-fit", "step budget per ensemble (default 20000)")
    p_fit.add_argument("--no-checkpoint", action="store_true",
                       help="do not checkpoint to OUT/checkpoint.h5 (and do not resume)")
    p_fit.set_defaults(func=_cmd_fit)

    p_cmp = sub.add_parser("compare", help="rank models per excitation frequency "
                           "(PSIS-LOO, WAIC, leave-one-frequency-out, BIC, stacking)")
    p_cmp.add_argument("--models", required=True,
                       help="comma-separated model specs, e.g. "
                            "pi_play,bouc_wen,pi_play+second_order,gp,gp_memory")
    _add_run_options(p_cmp, "bayeshyst-compare",
                     "step budget per ensemble of every fit (default 20000)")
    p_cmp.add_argument("--jobs", type=positive_int, default=None,
                       help="worker processes (default: one per core)")
    p_cmp.add_argument("--no-lofo", action="store_true",
                       help="skip the leave-one-frequency-out fits")
    p_cmp.add_argument("--max-refits", type=non_negative_int, default=5,
                       help="exact refits per fit for cycles with Pareto k > 0.7 (default 5)")
    p_cmp.add_argument("--gp-train", type=positive_int, default=1000,
                       help="training-subset size of the GP models (default 1000)")
    p_cmp.set_defaults(func=_cmd_compare)

    p_comp = sub.add_parser("compensate", help="design feedforward commands from the posterior "
                            "of one model and score their tracking per frequency")
    p_comp.add_argument("--model", required=True,
                        help="model name or spec string, e.g. pi_play+second_order")
    _add_run_options(p_comp, "bayeshyst-compensate", "step budget per ensemble (default 20000)")
    p_comp.add_argument("--reference", default="sine", metavar="sine|triangle|FILE",
                        help="reference to track: a sine or triangle at every frequency of "
                             "the data (default sine), or a CSV file with header t,y "
                             "(s, output unit), tracked once")
    p_comp.add_argument("--design-draws", type=positive_int, default=24, metavar="N",
                        help="posterior draws the posterior-aware commands are designed on "
                             "(default 24)")
    p_comp.add_argument("--quantile", type=probability, default=0.9, metavar="Q",
                        help="quantile of |error| over draws the robust command minimises, "
                             "in (0, 1) (default 0.9)")
    p_comp.add_argument("--plant", choices=("auto", "posterior"), default="auto",
                        help="what the commands are run on: auto (default) = the virtual "
                             "actuator named in the data's sidecar if any, else held-out "
                             "posterior draws; posterior = always held-out draws")
    p_comp.add_argument("--no-checkpoint", action="store_true",
                        help="do not checkpoint to OUT/checkpoint.h5 (and do not resume)")
    p_comp.set_defaults(func=_cmd_compensate)

    p_dg = sub.add_parser("diagnose", help="trace what a model leaves in its residual to a "
                          "missing effect, add it, refit, and report the error before and after")
    p_dg.add_argument("--model", required=True,
                      help="base model name or spec string, e.g. pi_play(n_operators=8)")
    _add_run_options(p_dg, "bayeshyst-diagnose",
                     "step budget per ensemble of every fit (default 20000)")
    p_dg.add_argument("--effects", default=None, metavar="A,B,...",
                      help="candidate effects, comma-separated (default all: creep, "
                           "rate_dependence, asymmetry, drift, delay, colored_noise)")
    p_dg.add_argument("--alpha", type=probability, default=0.01,
                      help="family-wise level of the residual tests (Holm), in (0, 1) "
                           "(default 0.01)")
    p_dg.add_argument("--threshold", type=non_negative_float, default=2.0, metavar="T",
                      help="an effect is kept when the held-out elpd improves by more than "
                           "T standard errors (default 2)")
    p_dg.add_argument("--max-rounds", type=positive_int, default=6, metavar="N",
                      help="most effects added (default 6)")
    p_dg.add_argument("--no-checkpoint", action="store_true",
                      help="do not checkpoint to OUT/checkpoints/ (and do not resume)")
    p_dg.set_defaults(func=_cmd_diagnose)

    p_rep = sub.add_parser("report", help="the whole study on one dataset: compare models per "
                           "frequency, diagnose the best, design feedforward; one HTML report")
    p_rep.add_argument("--models", default=None,
                       help="comma-separated model specs (default "
                            "pi_play,bouc_wen,pi_play+second_order,gp_memory)")
    _add_run_options(p_rep, "bayeshyst-report",
                     "step budget per ensemble of every fit (default 20000)")
    p_rep.add_argument("--jobs", type=positive_int, default=None,
                       help="worker processes of the comparison (default: one per core)")
    p_rep.add_argument("--no-lofo", action="store_true",
                       help="skip the leave-one-frequency-out fits")
    p_rep.add_argument("--max-refits", type=non_negative_int, default=5,
                       help="exact refits per fit for cycles with Pareto k > 0.7 (default 5)")
    p_rep.add_argument("--effects", default=None, metavar="A,B,...",
                       help="candidate effects of the diagnosis (default all)")
    p_rep.add_argument("--max-rounds", type=positive_int, default=6, metavar="N",
                       help="most effects the diagnosis adds (default 6)")
    p_rep.set_defaults(func=_cmd_report)

    p_demo = sub.add_parser("demo", help="the whole study (bayeshyst report) on the bundled "
                            "virtual-actuator data")
    p_demo.add_argument("--quick", action="store_true",
                        help="about a minute: 2 models, short chains (nothing converges)")
    p_demo.add_argument("--out", default="bayeshyst-demo",
                        help="output folder (default bayeshyst-demo)")
    p_demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p_demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p_demo.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p_demo.add_argument("--no-figures", action="store_true", help="skip the figures")
    p_demo.set_defaults(func=_cmd_demo)

    p_st = sub.add_parser("study", help="fit every model to every excitation frequency of "
                          "every dataset of a study file, on Dask; resumable")
    p_st.add_argument("study", help="study file (TOML): datasets, models, likelihoods, "
                                    "sampler settings, seeds")
    p_st.add_argument("--out", default=None,
                      help="output folder (default study-<name of the study>)")
    where = p_st.add_mutually_exclusive_group()
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="submit to the running Dask scheduler at ADDRESS "
                            "(tcp://host:port) instead of starting a local cluster")
    where.add_argument("--workers", type=positive_int, default=None, metavar="N",
                       help="worker processes of the local cluster (default: one per core)")
    where.add_argument("--serial", action="store_true",
                       help="no Dask: run the fits one after the other in this process")
    p_st.add_argument("--retry-failed", action="store_true",
                      help="run again the fits whose stored result is a failure")
    p_st.add_argument("--report", action="store_true", help="also write study.html")
    p_st.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p_st.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p_st.add_argument("--no-figures", action="store_true", help="skip the figures")
    p_st.set_defaults(func=_cmd_study)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (DataError, ParameterError, ModelError) as exc:
        print(f"bayeshyst {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # the reader went away (``bayeshyst models | head``): not an error; point stdout
        # at devnull so the interpreter's final flush does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except KeyboardInterrupt:
        print(f"bayeshyst {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
