"""The commands that run the whole study: ``report``, ``demo`` and ``study``.

As in :mod:`bayeshyst.cli.commands`: each runs the library, hands what it computed to
its writer in :mod:`bayeshyst.outputs` and prints the summary the writer returns; a run
that fails before its first result leaves its output folder as it found it.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from bayeshyst.cli.commands import load_data, load_validation, working_data
from bayeshyst.cli.options import EXIT_OK, effect_list, sampler_settings
from bayeshyst.files import RunOutputs, json_text, removed_on_failure

__all__ = ["cmd_demo", "cmd_report", "cmd_study"]


# a report's comparison stores each finished fit's posterior here; from the first one
# on, a failed report keeps what is there for the rerun to resume from
_REPORT_RESULTS = ("compare/posteriors/*.nc",)


def _report_run(data: Any, data_path: str, models: tuple[str, ...], settings: Any,
                args: argparse.Namespace, command: str,
                outputs: RunOutputs, validation: Any = None,
                working_rate: dict[str, Any] | None = None) -> tuple[Any, Any]:
    """The shared part of ``report`` and ``demo``: run every stage and write.

    ``outputs`` is the caller's :func:`removed_on_failure` of ``--out`` (a finished
    diagnosis fit marks the first result); ``working_rate`` is what :func:`working_data`
    did (``WorkingRate.to_dict()``), for the writer. Returns ``(result, summary)`` for
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
                        progress=settings.sampler.progress, on_fit=on_fit,
                        validation=validation)
    posteriors = report_posteriors(result)
    figures = None if args.no_figures else report_figures(result, posteriors)
    summary = write_report_outputs(result, out, posteriors=posteriors, figures=figures,
                                   data_path=data_path, working_rate=working_rate)
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
        else effect_list(args.effects), max_rounds=args.max_rounds, n_jobs=args.jobs,
        calibration=not args.no_calibration, screen=args.screen)


def cmd_report(args: argparse.Namespace) -> int:
    """``bayeshyst report DATA``: compare, diagnose, compensate; write report.html."""
    from bayeshyst.selection import check_models
    from bayeshyst.workflow import DEFAULT_MODELS

    # validate everything cheap before the long part starts
    data = load_data(args)
    models = check_models(args.models) if args.models else DEFAULT_MODELS
    settings = _report_settings(args)
    # the validation records are predicted, and predictions stay at full rate
    validation = load_validation(args)
    # run_report takes the data as given: the working rate is applied here
    data, rate = working_data(args, data)
    with removed_on_failure(args.out, results=_REPORT_RESULTS) as outputs:
        result, summary = _report_run(data, str(args.data), models, settings, args,
                                      "report", outputs, validation, rate.to_dict())
    return _report_print(args, result, summary)


def cmd_demo(args: argparse.Namespace) -> int:
    """``bayeshyst demo``: the report on the bundled data at the demo's budget."""
    from bayeshyst.data import load
    from bayeshyst.demo import DEMO_DEFAULT, DEMO_QUICK, bundled_data

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


def cmd_study(args: argparse.Namespace) -> int:
    """``bayeshyst study SPEC.toml``: many datasets × models, resumable; write the tables."""
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


