"""The commands: each runs the library, builds what its writer needs, writes, prints.

Each command computes what its writer needs (a fit's InferenceData, the figures of
:mod:`bayeshyst.outputs.assemble`), hands both to its writer in :mod:`bayeshyst.outputs`
and prints the summary the writer returns; ``--json`` prints it with the serialiser
``summary.json`` was written with, so the two are the same text. A command that fails
before its first result leaves its output folder as it found it
(:func:`bayeshyst.files.removed_on_failure`).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.cli.options import EXIT_OK, effect_list, sampler_settings
from bayeshyst.errors import DataError, ModelError
from bayeshyst.files import json_text, removed_on_failure

__all__ = ["cmd_compare", "cmd_compensate", "cmd_diagnose", "cmd_export", "cmd_fit",
           "cmd_invert", "cmd_models", "cmd_predict", "load_data", "load_validation",
           "working_data"]


def load_validation(args: argparse.Namespace) -> Any:
    """``--validation FILE`` read like the data (same ``--columns``), or None."""
    from bayeshyst.data import label_frequencies, load

    if args.validation is None:
        return None
    validation = load(args.validation, columns=args.columns,
                      units=args.units)
    return validation if args.no_frequency_labels else label_frequencies(validation)


def load_data(args: argparse.Namespace) -> Any:
    """The command's data file with its ``--columns``, frequencies found where missing.

    Records without a ``frequency_hz`` are classified from their input (periodic,
    stepped, multisine or broadband) and labelled, split into steps or kept whole
    accordingly (:func:`bayeshyst.data.segment.label_frequencies`) unless
    ``--no-frequency-labels``. One line per classified record says what its excitation
    is and what was done with it; the unit conversions the header asked for, the
    frequencies found and what does not look like a piezo stage
    (:func:`bayeshyst.data.units.plausibility`) are printed too, unless ``--quiet``.
    """
    from bayeshyst.data import label_frequencies, load
    from bayeshyst.data.units import plausibility

    # predict takes an input alone too (a command whose output is what is asked for)
    data = load(args.data, columns=args.columns, units=args.units,
                require_output=args.command != "predict")
    if not args.no_frequency_labels:
        data = label_frequencies(data)
    if not args.quiet:
        where = f"bayeshyst {args.command}: {args.data}"
        found: dict[str, list[str]] = {}
        classified: dict[str, str] = {}  # one line per record of the file (pieces' parent)
        for r in data:
            parent = str(r.metadata.get("parent", r.name))
            if "excitation_note" in r.metadata:
                classified.setdefault(parent, str(r.metadata["excitation_note"]))
            if "frequency_source" in r.metadata:
                found.setdefault(parent, []).append(
                    f"{r.frequency_hz:g} Hz ({r.metadata['frequency_source']})")
            elif "frequency_note" in r.metadata and "excitation_note" not in r.metadata:
                print(f"{where}: record {r.name!r}: {r.metadata['frequency_note']}",
                      file=sys.stderr)
        for name, note in classified.items():
            print(f"{where}: record {name!r}: {note}", file=sys.stderr)
        for name, labels in found.items():
            print(f"{where}: record {name!r} has no frequency_hz; found from its input: "
                  f"{', '.join(labels)} (--no-frequency-labels to keep it unlabelled)",
                  file=sys.stderr)
        notes = dict.fromkeys(n for r in data for key in ("column_roles", "unit_conversions")
                              for n in r.metadata.get(key, ()))
        for n in notes:
            print(f"{where}: {n}", file=sys.stderr)
        for w in plausibility(data):
            print(f"bayeshyst {args.command}: warning: {w}", file=sys.stderr)
    return data


def working_data(args: argparse.Namespace, data: Any) -> tuple[Any, Any]:
    """The data at their working rate (``--working-rate``), said in one line on stderr.

    Returns ``(data, WorkingRate)`` (:func:`bayeshyst.data.working_rate.to_working_rate`;
    the same data when every record is kept whole).
    """
    from bayeshyst.data.working_rate import to_working_rate

    working, info = to_working_rate(data, rate=args.working_rate)
    if not args.quiet:
        print(f"bayeshyst {args.command}: {info.line()}", file=sys.stderr, flush=True)
    return working, info


def _params(space: Any) -> list[dict[str, Any]]:
    params = []
    for p in space.params:
        params.append({"name": p.name, "shape": list(p.shape), "unit": p.unit,
                       "prior": str(p.prior), "description": p.description})
    for p in space.fixed_params:
        params.append({"name": p.name, "shape": list(p.shape), "unit": p.unit,
                       "fixed": np.asarray(space.fixed[p.name]).tolist(),
                       "description": p.description})
    return params


def _first_line(obj: Any) -> str:
    return ((type(obj).__doc__ or "").strip().splitlines() or [""])[0]


def _models_summary(names: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
    """The hysteresis models, GP models and effect blocks among ``names``, as JSON."""
    from bayeshyst import models
    from bayeshyst.gp import gp_features, gp_from_spec
    from bayeshyst.models.blocks import block_class, block_names

    out: dict[str, list[dict[str, Any]]] = {"models": [], "gaussian_processes": [],
                                            "effect_blocks": []}
    for name in names:
        if gp_features(name) is not None:
            gp = gp_from_spec(name)
            out["gaussian_processes"].append({
                "name": name, "class": type(gp).__name__, "features": gp_features(name),
                "summary": _first_line(gp),
                "use": "a nonparametric peer: fit, compare and report score it like the "
                       "parametric models; no parameters to sample, no inverse"})
        elif name in block_names():
            cls = block_class(name)
            block = cls(**cls.example)
            example = ", ".join(f"{k}={v!r}" for k, v in cls.example.items())
            out["effect_blocks"].append({
                "name": name, "class": type(block).__name__, "equation": block.equation,
                "rate_dependent": bool(block.rate_dependent), "summary": _first_line(block),
                "use": f"append to a model spec: pi_play+{name}"
                       + (f"({example})" if example else ""),
                "settings": {k: v for k, v in vars(block).items() if not k.startswith("_")},
                "parameters": _params(block.param_space())})
        else:
            model = models.get(name)
            out["models"].append({
                "name": name, "class": type(model).__name__, "equation": model.equation,
                "rate_dependent": bool(model.rate_dependent),
                "analytic_inverse": bool(model.has_inverse), "summary": _first_line(model),
                "settings": {k: v for k, v in vars(model).items() if not k.startswith("_")},
                "parameters": _params(model.param_space())})
    return out


def cmd_models(args: argparse.Namespace) -> int:
    """``bayeshyst models [NAME ...]``: models, GP models, effect blocks and their priors."""
    from bayeshyst import models
    from bayeshyst.gp import gp_names
    from bayeshyst.models.blocks import block_names

    names = [*models.names(), *gp_names(), *block_names()]
    if args.name:
        unknown = [n for n in args.name if n not in names]
        if unknown:
            raise ModelError(f"unknown model(s) {unknown}; available: {', '.join(names)}")
        names = args.name
    summary = _models_summary(names)
    if args.json:
        json.dump(summary, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
        return EXIT_OK
    titles = {"models": "hysteresis models", "gaussian_processes": "Gaussian-process models",
              "effect_blocks": "effect blocks (compose with +)"}
    for key, entries in summary.items():
        if not entries:
            continue
        if len(args.name) != 1:
            print(f"== {titles[key]}\n")
        for m in entries:
            flags = [f for f, on in (("rate-dependent", m.get("rate_dependent")),
                                     ("analytic inverse", m.get("analytic_inverse"))) if on]
            settings = ", ".join(f"{k}={v}" for k, v in m.get("settings", {}).items())
            head = f"{m['name']}  [{m['class']}({settings})]"
            if "equation" in m:
                head += f"  {m['equation']}"
            print(head + (f"  ({'; '.join(flags)})" if flags else ""))
            print(f"    {m['summary']}")
            if "use" in m:
                print(f"    {m['use']}")
            for p in m.get("parameters", []):
                shape = "x".join(map(str, p["shape"])) or "scalar"
                what = p.get("prior") or f"fixed = {np.round(p['fixed'], 4).tolist()}"
                print(f"    {p['name']:<16} {shape:<7} {p['unit']:<8} {what}  - "
                      f"{p['description']}")
            print()
    return EXIT_OK


def cmd_fit(args: argparse.Namespace) -> int:
    """``bayeshyst fit DATA --model M``: sample one posterior; write and print its summary."""
    from bayeshyst import diagnostics
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs import write_fit_outputs
    from bayeshyst.outputs.assemble import fit_figures

    # validate everything cheap before the long part starts
    data = load_data(args)
    model = get_model(args.model)
    likelihood = get_likelihood(args.likelihood)
    out = Path(args.out)
    checkpoint = None if args.no_checkpoint else out / "checkpoint.h5"
    if not args.quiet:
        print(f"bayeshyst fit: {model.name} / {likelihood.name} on {data.name} "
              f"({len(data)} record(s), {data.n_samples} samples)", file=sys.stderr)
    sampler = sampler_settings(args, checkpoint=checkpoint)
    with removed_on_failure(out) as outputs:
        fit = fit_model(data, model, likelihood, sampler=sampler,
                        discrepancy=args.discrepancy, calibration=not args.no_calibration)
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


def cmd_compare(args: argparse.Namespace) -> int:
    """``bayeshyst compare DATA --models A,B``: rank models per frequency; write, print."""
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.outputs.assemble import comparison_figures
    from bayeshyst.outputs.compare_outputs import write_comparison_outputs
    from bayeshyst.selection import check_models, compare_models

    # validate everything cheap before the long part starts
    data = load_data(args)
    models = check_models(args.models)
    get_likelihood(args.likelihood)
    out = Path(args.out)
    sampler = sampler_settings(args)
    data, rate = working_data(args, data)
    if not args.quiet:
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        print(f"bayeshyst compare: {', '.join(models)} on {data.name} ({len(data)} record(s); "
              f"frequencies [Hz]: {freqs})", file=sys.stderr)
    # each finished fit stores its posterior: from the first one on, a failure keeps
    # what is there for the rerun to resume from
    with removed_on_failure(out, results=("posteriors/*.nc",)):
        result = compare_models(data, models, likelihood=args.likelihood, sampler=sampler,
                                lofo=not args.no_lofo, max_refits=args.max_refits,
                                gp_n_train=args.gp_train, gp_sampling=args.gp_sampling,
                                n_jobs=args.jobs, out_dir=out,
                                progress=sampler.progress)
        figures = None if args.no_figures else comparison_figures(result)
        summary = write_comparison_outputs(result, out, figures=figures,
                                           data_path=str(args.data),
                                           working_rate=rate.to_dict())
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


def cmd_compensate(args: argparse.Namespace) -> int:
    """``bayeshyst compensate DATA --model M``: design feedforward commands per frequency."""
    from bayeshyst import diagnostics
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inverse.compensate import compensate
    from bayeshyst.inverse.references import REFERENCE_KINDS, load_reference
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs.assemble import compensation_figures
    from bayeshyst.outputs.compensate_outputs import write_compensation_outputs, written_files

    # validate everything cheap before the long part starts
    data = load_data(args)
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
    validation = load_validation(args)
    if args.nominal_inverse == "closed_form":
        from bayeshyst.inverse.closed_form import check_closed_form

        check_closed_form(model)
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
        fit = fit_model(data, model, likelihood, sampler=sampler,
                        discrepancy=args.discrepancy)
        # the sampled chains are the first result: should the design fail, their
        # checkpoint stays and the rerun resumes from it instead of sampling again
        outputs.keep()
        result = compensate(data, model, fit=fit, reference=reference,
                            plant=None if args.plant == "auto" else args.plant,
                            n_design_draws=args.design_draws, robust_quantile=args.quantile,
                            sampler=sampler, validation=validation,
                            nominal_inverse=args.nominal_inverse,
                            discrepancy_transfer=args.discrepancy_transfer, n_jobs=args.jobs)
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


def cmd_invert(args: argparse.Namespace) -> int:
    """``bayeshyst invert FIT --reference REF.csv``: a command from a saved fit."""
    from bayeshyst.inference.saved import load_fit
    from bayeshyst.inverse.command import design_command
    from bayeshyst.inverse.references import load_reference
    from bayeshyst.outputs.invert_outputs import write_invert_outputs

    # read and check both inputs before anything is written
    fit = load_fit(args.fit)
    reference = load_reference(args.reference)
    out = Path(args.out)
    if not args.quiet:
        print(f"bayeshyst invert: {args.objective} command for {reference.kind} "
              f"({reference.t.size} samples) from {fit.path} ({fit.model.name}, "
              f"{fit.n_draws} draws)", file=sys.stderr)
    with removed_on_failure(out):
        design = design_command(fit, reference, objective=args.objective,
                                n_design_draws=args.design_draws,
                                n_predict_draws=args.predict_draws, quantile=args.quantile,
                                seed=args.seed,
                                discrepancy_transfer=args.discrepancy_transfer)
        summary = write_invert_outputs(design, out, fit_path=str(fit.path),
                                       reference_path=str(args.reference),
                                       units=dict(fit.data[0].units))
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(design)
        print(f"outputs in {out}/: command.csv, summary.json")
    return EXIT_OK


def cmd_predict(args: argparse.Namespace) -> int:
    """``bayeshyst predict FIT DATA``: a saved fit's predictive on other records, scored."""
    from bayeshyst.inference.saved import load_fit
    from bayeshyst.outputs.assemble import prediction_figures
    from bayeshyst.outputs.predict_outputs import write_predict_outputs

    # read and check both inputs, and predict, before anything is written
    fit = load_fit(args.fit)
    data = load_data(args)
    if not args.quiet:
        print(f"bayeshyst predict: {fit.model.name} from {fit.path} on {data.name} "
              f"({len(data)} record(s), {data.n_samples} samples); initial state "
              f"{args.initial.describe()}", file=sys.stderr)
    result = fit.predict(data, initial=args.initial, n_draws=args.draws, seed=args.seed)
    out = Path(args.out)
    with removed_on_failure(out):
        figures = None if args.no_figures else prediction_figures(result)
        summary = write_predict_outputs(result, out, fit_path=str(fit.path),
                                        data_path=str(args.data), figures=figures)
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        print(f"outputs in {out}/: predictions.csv, scores.csv, summary.json"
              + ("" if args.no_figures else f", {len(summary['files']['figures'])} figure(s)"))
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    """``bayeshyst export FIT --format json|c|table``: the inverse for a controller."""
    from bayeshyst.inference.saved import load_fit
    from bayeshyst.inverse.export import export_inverse, replay_error
    from bayeshyst.inverse.numerical import invert
    from bayeshyst.inverse.references import load_reference
    from bayeshyst.outputs.export_outputs import write_export_outputs

    if not args.prefix.isidentifier():
        raise DataError(f"--prefix must be a C identifier, got {args.prefix!r}")
    fit = load_fit(args.fit)
    reference = None if args.reference is None else load_reference(args.reference)
    out = Path(args.out)
    if not args.quiet:
        print(f"bayeshyst export: {args.fmt} inverse of {fit.path} ({fit.model.name})",
              file=sys.stderr)
    # a table is asked for: tabulate even a model with a closed form
    method = "table" if args.fmt == "table" and args.method == "auto" else args.method
    export = export_inverse(fit, method=method)
    replay = None
    if reference is not None:
        theta, offset = fit.posterior.model_draws(fit.map_z[None, :])
        exact = invert(fit.model, reference.y_d, reference.t, theta, offset=offset,
                       u_limits=export.u_limits)
        replay = {"t": reference.t, "y_d": reference.y_d, "u": export.apply(reference.y_d),
                  "reference": str(args.reference),
                  "error_percent": replay_error(export, exact.u, reference.y_d)}
    with removed_on_failure(out):
        summary = write_export_outputs(export, out, fmt=args.fmt, prefix=args.prefix,
                                       fit_path=str(fit.path), replay=replay)
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(export)
        if replay is not None:
            print(f"on {args.reference}: max |u - exact inverse| = "
                  f"{replay['error_percent']:.3g} % of the command span")
        print(f"outputs in {out}/: " + ", ".join(summary["files"]))
    return EXIT_OK


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``bayeshyst diagnose DATA --model M``: the residual loop, before and after."""
    from bayeshyst.diagnosis import EFFECTS, diagnose
    from bayeshyst.inference.predict import check_at_full_rate
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs.assemble import diagnosis_figures
    from bayeshyst.outputs.diagnose_outputs import write_diagnosis_outputs

    # validate everything cheap before the long part starts
    data = load_data(args)
    model = get_model(args.model)
    likelihood = get_likelihood(args.likelihood)
    effects = tuple(EFFECTS) if args.effects is None else effect_list(args.effects)
    out = Path(args.out)
    checkpoints = None if args.no_checkpoint else out / "checkpoints"
    sampler = sampler_settings(args)
    full = data
    data, rate = working_data(args, data)
    n_fits = 0

    def on_fit(fit: Any) -> None:
        nonlocal n_fits
        n_fits += 1
        outputs.keep()  # a finished fit is a result: its checkpoint makes a rerun quick
        if args.quiet:
            return
        fired = [t.effect for t in fit.analysis.fired()]
        conv = "converged" if fit.sampling.converged else "NOT converged"
        scan = fit.analysis.drivers
        drivers = [d.driver for d in scan.selected] if scan is not None else []
        lines = [f"{x.frequency_hz:.4g} Hz" for x in fit.analysis.lines]
        print(f"bayeshyst diagnose: fit {n_fits} done: {fit.label} ({conv}); RMSE "
              f"{fit.overall.rmse:.4g}, elpd {fit.elpd:.1f}; tests firing on its residual: "
              f"{', '.join(fired) or 'none'}; it depends on: {', '.join(drivers) or 'nothing'}"
              + (f"; lines at {', '.join(lines)}" if lines else ""), file=sys.stderr,
              flush=True)

    if not args.quiet:
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        print(f"bayeshyst diagnose: {model.name} / {likelihood.name} on {data.name} "
              f"({len(data)} record(s); frequencies [Hz]: {freqs}); candidate effects: "
              f"{', '.join(effects)}", file=sys.stderr)
    with removed_on_failure(out) as outputs:
        result = diagnose(data, args.model, likelihood.name, effects=effects,
                          alpha=args.alpha, threshold=args.threshold,
                          max_rounds=args.max_rounds, sampler=sampler,
                          checkpoint_dir=checkpoints, on_fit=on_fit, n_jobs=args.jobs,
                          screen=args.screen)
        entry = rate.to_dict()
        if rate.changed:
            # the working rate is a choice of the fit; the records are what was measured
            check = check_at_full_rate(result.final.fit, full, data, seed=sampler.seed)
            entry["full_rate_check"] = check.to_dict()
            if not args.quiet:
                print(f"bayeshyst diagnose: final fit: {check}", file=sys.stderr, flush=True)
        figures = None if args.no_figures else diagnosis_figures(result)
        summary = write_diagnosis_outputs(result, out, figures=figures,
                                          data_name=str(args.data), working_rate=entry)
    if args.json:
        sys.stdout.write(json_text(summary))
    else:
        print(result)
        print(f"outputs in {out}/: " + ", ".join(summary["outputs"])
              + ("" if checkpoints is None else ", checkpoints/"))
    return EXIT_OK
