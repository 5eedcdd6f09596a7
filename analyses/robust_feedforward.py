"""Robust feedforward design: how well does a posterior-aware inverse track, per frequency?

Answers the control engineer's question: *if I drive the actuator through the inverse
of my identified hysteresis model, how much tracking error is left -- compared with no
compensation, with the inverse of the single best-fit (MAP) parameters, with the
posterior-aware inverse and with the robust one -- and does the error band the
posterior predicts hold?* For every model (``--models``) the posterior is sampled
(:func:`bayeshyst.inference.fit.fit_model`) and
:func:`bayeshyst.inverse.compensate.compensate` designs, per excitation frequency in the
data, four commands for a reference at that frequency (sine or triangle over the central
80 % of the measured output range; one warm-up cycle, two scored cycles):

* ``uncompensated`` -- the input scaled by the straight line through the measured loops;
* ``nominal`` -- the exact inverse of the MAP model;
* ``posterior`` -- the command whose posterior-mean output meets the reference;
* ``robust`` -- the command minimising the 90 % quantile of |error| over posterior draws.

The bundled ``data/virtual_multifreq.csv`` names its generator (the virtual actuator) in
its JSON sidecar, so the commands are run on **the true plant**, measured with its
sensor noise: the errors are real, not the model's opinion of itself. With data without
such a sidecar the commands run on posterior draws held out from the design, and every
output says so.
Errors are RMS (NRMSE) and max of ``y - y_d`` in % of the reference's peak-to-peak;
``realised_inside_band`` says whether the plant's NRMSE under the posterior command lies
in the 90 % interval predicted from held-out posterior draws.

Outputs in ``--out``: ``feedforward.csv`` (one row per model × frequency),
``feedforward.txt``, ``feedforward.png`` (NRMSE and max error against frequency per
command and model), one folder per model with what ``bayeshyst compensate`` writes
(:func:`bayeshyst.outputs.compensate_outputs.write_compensation_outputs`:
``summary.json``, ``compensation.csv``, ``curves.npz``, ``posterior.nc``, ...) and
``summary.json`` (written last).

Run (from the repository root)::

    python -m analyses.robust_feedforward                # full: 2 models, 5 frequencies,
                                                         # <= 20 000 sampler steps each
    python -m analyses.robust_feedforward --quick        # seconds: 1 model, 2 frequencies
    python -m analyses.robust_feedforward --models "pi_play(n_operators=8)+second_order" \\
        --reference triangle --quantile 0.95

Quick mode (``--quick``): model ``pi_play(n_operators=4)`` only, the lowest and highest
frequency, 200 sampler steps, 16 design draws, no per-model figures; the posterior is
NOT converged and the outputs say so.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from analyses._common import (
    DEFAULT_DATA,
    EXIT_OK,
    Progress,
    base_parser,
    budget,
    float_list,
    name_list,
    new_figure,
    positive_int,
    probability,
    run,
    save_figure,
    select_frequencies,
    slug,
    write_csv,
    write_text,
)
from bayeshyst.errors import ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.files import write_json

PROG = "robust_feedforward"
COMMANDS = ("uncompensated", "nominal", "posterior", "robust")

FULL_MODELS = ("pi_play(n_operators=8)+second_order", "bouc_wen+second_order")
QUICK_MODELS = ("pi_play(n_operators=4)",)
FULL = {"sampler": SamplerSettings(max_steps=20_000), "design_draws": 24}
QUICK = {"sampler": SamplerSettings(max_steps=200, first_chunk=200), "design_draws": 16}

TABLE_COLUMNS = ("model", "frequency_hz", "reference", "plant_kind", "converged",
                 *(f"{c}_nrmse_percent" for c in COMMANDS),
                 *(f"{c}_max_percent" for c in COMMANDS),
                 "band_lo_percent", "band_hi_percent", "realised_inside_band",
                 "output_coverage", "best_command", "improvement_factor", "n_saturated",
                 "model_error_percent")


def build_parser() -> argparse.ArgumentParser:
    """Options of the robust-feedforward analysis."""
    p = base_parser(PROG, __doc__)
    p.add_argument("--data", default=str(DEFAULT_DATA),
                   help="data file (default the bundled data/virtual_multifreq.csv, whose "
                        "sidecar names the true plant)")
    p.add_argument("--models", type=name_list, default=None, metavar="SPEC,SPEC,...",
                   help=f"model specs (default {','.join(FULL_MODELS)}; --quick "
                        f"{','.join(QUICK_MODELS)})")
    p.add_argument("--likelihood", default="gaussian",
                   help="gaussian (default), student_t or ar1")
    p.add_argument("--frequencies", type=float_list, default=None, metavar="F1,F2,...",
                   help="only these frequencies [Hz] (default all; --quick the lowest and "
                        "the highest)")
    p.add_argument("--reference", choices=("sine", "triangle"), default="sine",
                   help="reference shape at every frequency (default sine)")
    p.add_argument("--quantile", type=probability, default=0.9, metavar="Q",
                   help="quantile of |error| over draws the robust command minimises "
                        "(default 0.9)")
    p.add_argument("--design-draws", type=positive_int, default=None, metavar="N",
                   help="posterior draws the posterior-aware commands are designed on "
                        "(default 24; --quick 16)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="step budget per ensemble (default 20000; --quick 200)")
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="walkers per ensemble (default: from the number of parameters)")
    p.add_argument("--no-checkpoint", action="store_true",
                   help="do not checkpoint the samplers (OUT/<model>/checkpoint.h5)")
    return p


# ------------------------------------------------------------------------- results
def table_rows(spec: str, result: Any) -> list[dict[str, Any]]:
    """One row per frequency of the :class:`CompensationResult` of model ``spec``."""
    rows = []
    for r in result.rows:
        d = r.to_dict()
        row: dict[str, Any] = {"model": spec, "frequency_hz": r.frequency_hz,
                               "reference": r.reference, "plant_kind": result.plant_kind,
                               "converged": bool(result.converged)}
        for c in COMMANDS:
            row[f"{c}_nrmse_percent"] = d[f"{c}_nrmse_percent"]
            row[f"{c}_max_percent"] = d[f"{c}_max_percent"]
        row["band_lo_percent"], row["band_hi_percent"] = r.predicted_band_percent
        row["realised_inside_band"] = bool(r.realised_inside_band)
        row["output_coverage"] = r.output_coverage
        compensated = {c: row[f"{c}_nrmse_percent"] for c in COMMANDS[1:]
                       if math.isfinite(row[f"{c}_nrmse_percent"])}
        best = min(compensated, key=compensated.get) if compensated else None
        row["best_command"] = best
        row["improvement_factor"] = (row["uncompensated_nrmse_percent"] / compensated[best]
                                     if best and compensated[best] > 0 else math.nan)
        row["n_saturated"] = r.n_saturated
        row["model_error_percent"] = r.model_error_percent
        rows.append(row)
    return rows


def _f(x: Any, spec: str = ".3f") -> str:
    return format(x, spec) if isinstance(x, int | float) and math.isfinite(x) else "n/a"


def report_text(specs: list[str], results: list[Any], rows: list[dict[str, Any]],
                quick: bool) -> str:
    """The plain-text report (``feedforward.txt``)."""
    lines = ["ROBUST FEEDFORWARD: tracking NRMSE [% of the reference's stroke] per frequency"]
    bad = [m for m, r in zip(specs, results, strict=True) if not r.converged]
    if bad:
        lines += ["", "*" * 78, f"*** NOT converged: the posterior of {', '.join(bad)} did not "
                  "converge; bands and posterior-aware commands are provisional"
                  + (" (quick run)." if quick else " (raise --steps)."), "*" * 78]
    for spec, res in zip(specs, results, strict=True):
        lines += ["", f"== {spec}  ({'converged' if res.converged else 'NOT converged'})",
                  f"plant: {res.plant}",
                  f"{'f [Hz]':>8} {'none':>8} {'nominal':>8} {'posterior':>9} {'robust':>8} "
                  f"{'90 % band (posterior)':>22} {'inside':>7} {'best':>10} {'gain':>6}"]
        for row in (r for r in rows if r["model"] == spec):
            f = row["frequency_hz"]
            band = f"[{_f(row['band_lo_percent'])}, {_f(row['band_hi_percent'])}]"
            lines.append(
                f"{_f(f, 'g') if f is not None else 'ref':>8} "
                f"{_f(row['uncompensated_nrmse_percent']):>8} "
                f"{_f(row['nominal_nrmse_percent']):>8} {_f(row['posterior_nrmse_percent']):>9} "
                f"{_f(row['robust_nrmse_percent']):>8} {band:>22} "
                f"{'yes' if row['realised_inside_band'] else 'NO':>7} "
                f"{row['best_command'] or '-':>10} {_f(row['improvement_factor'], '.1f'):>5}x")
        lines.append("max error [%]: " + "; ".join(
            f"{_f(r['frequency_hz'], 'g')} Hz: none {_f(r['uncompensated_max_percent'], '.2f')}"
            f", robust {_f(r['robust_max_percent'], '.2f')}"
            for r in rows if r["model"] == spec))
        lines += [f"  {s}" for s in res.statements]
    return "\n".join(lines)


def plot_feedforward(specs: list[str], results: list[Any], rows: list[dict[str, Any]],
                     path: Path) -> Path:
    """NRMSE and max error against frequency: colour = command, line style = model; the
    posterior command's predicted 90 % band as a shaded bar beside each frequency."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    fig = new_figure(9.0, 4.2 + 0.2 * len(specs))
    ax_rms, ax_max = fig.subplots(1, 2)
    colours = {"uncompensated": "#7f7f7f", "nominal": "#1f77b4", "posterior": "#2ca02c",
               "robust": "#d62728"}
    styles = ["-", "--", ":", "-."]
    for i, spec in enumerate(specs):
        rs = [r for r in rows if r["model"] == spec and r["frequency_hz"] is not None]
        if not rs:
            continue
        f = np.array([r["frequency_hz"] for r in rs])
        for c in COMMANDS:
            for ax, key in ((ax_rms, "nrmse"), (ax_max, "max")):
                ax.plot(f, [r[f"{c}_{key}_percent"] for r in rs], styles[i % len(styles)],
                        marker="o", ms=3, color=colours[c])
        lo = np.array([r["band_lo_percent"] for r in rs])
        hi = np.array([r["band_hi_percent"] for r in rs])
        ax_rms.vlines(f * 1.08 ** (i + 1), lo, hi, lw=5, alpha=0.35, color=colours["posterior"])
    for ax, what in ((ax_rms, "tracking NRMSE"), (ax_max, "max |error|")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"{what} [% of stroke]")
        ax.grid(True, which="both", alpha=0.3)
    plant = results[0].plant_kind if results else ""
    bad = not all(r.converged for r in results)
    fig.suptitle(f"feedforward on the {plant}" + (" (NOT converged)" if bad else ""),
                 color="#c0392b" if bad else "k", fontsize=10)
    handles = [Line2D([], [], color=colours[c], marker="o", ms=3, label=c) for c in COMMANDS]
    handles.append(Patch(color=colours["posterior"], alpha=0.35,
                         label="predicted 90 % band (posterior command)"))
    if len(specs) > 1:
        handles += [Line2D([], [], color="k", ls=styles[i % len(styles)], label=spec)
                    for i, spec in enumerate(specs)]
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=7)
    return save_figure(fig, path)


# ---------------------------------------------------------------------------- main
def _analyse(args: argparse.Namespace) -> int:
    from bayeshyst import diagnostics
    from bayeshyst.data import load
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inverse.compensate import compensate
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs.assemble import compensation_figures
    from bayeshyst.outputs.compensate_outputs import write_compensation_outputs

    log = Progress(PROG, args.quiet)
    cfg = budget(args, QUICK, FULL, {"design_draws": args.design_draws})
    sampler = cfg["sampler"]
    # validate everything cheap before anything is written
    data = load(args.data)
    frequencies = args.frequencies
    if frequencies is None and args.quick and len(data.frequencies) >= 2:
        frequencies = (data.frequencies[0], data.frequencies[-1])
    data = select_frequencies(data, frequencies)
    if not data.frequencies:
        raise ParameterError(f"{args.data}: no record has a frequency_hz, so there is no "
                             "frequency to put a reference at; label the records' frequencies")
    specs = list(args.models or (QUICK_MODELS if args.quick else FULL_MODELS))
    models = [get_model(m) for m in specs]
    likelihood = get_likelihood(args.likelihood)
    out = Path(args.out)
    results, rows, per_model = [], [], []
    for spec, model in zip(specs, models, strict=True):
        folder = out / slug(spec)
        log(f"{spec}: fitting {data.name} ({len(data)} record(s); frequencies [Hz] "
            f"{', '.join(f'{f:g}' for f in data.frequencies)}), budget {sampler.max_steps} steps")
        fit = fit_model(data, model, likelihood, sampler=sampler.replace(
            checkpoint=None if args.no_checkpoint else folder / "checkpoint.h5"))
        log(f"{spec}: fit {'converged' if fit.converged else 'NOT converged'} "
            f"({fit.sampling.runtime_s:.1f} s); designing commands")
        result = compensate(data, model, fit=fit, reference=args.reference,
                            n_design_draws=cfg["design_draws"],
                            robust_quantile=args.quantile, sampler=sampler)
        idata = diagnostics.to_inference_data(fit.posterior, fit.sampling,
                                              seed=int(result.settings.get("seed", 0)))
        write_compensation_outputs(result, folder, fit=fit, idata=idata,
                                   data_path=str(args.data),
                                   figures=None if args.no_figures or args.quick
                                   else compensation_figures(result, fit=fit))
        these = table_rows(spec, result)
        for r in these:
            log(f"{spec} @ {_f(r['frequency_hz'], 'g')} Hz: NRMSE none "
                f"{_f(r['uncompensated_nrmse_percent'])} %, nominal "
                f"{_f(r['nominal_nrmse_percent'])} %, posterior "
                f"{_f(r['posterior_nrmse_percent'])} %, robust {_f(r['robust_nrmse_percent'])} %"
                f" ({'inside' if r['realised_inside_band'] else 'OUTSIDE'} the band)")
        results.append(result)
        rows += these
        per_model.append({"model": spec, "folder": slug(spec),
                          "converged": bool(result.converged), "plant": result.plant,
                          "plant_kind": result.plant_kind,
                          "statements": list(result.statements)})
    write_csv(out / "feedforward.csv", TABLE_COLUMNS, rows)
    text = report_text(specs, results, rows, args.quick)
    write_text(out / "feedforward.txt", text)
    figures = []
    if not args.no_figures:
        figures.append(plot_feedforward(specs, results, rows, out / "feedforward.png").name)
    converged = all(r.converged for r in results)
    summary = {
        "command": PROG, "quick": bool(args.quick), "data": str(args.data),
        "frequencies_hz": list(data.frequencies), "reference": args.reference,
        "converged": converged, "status": "converged" if converged else "NOT converged",
        "models": per_model, "rows": rows,
        "percent_of": "peak-to-peak of the reference",
        "settings": {**cfg, "sampler": sampler.to_dict(), "robust_quantile": args.quantile,
                     "likelihood": likelihood.name, "seed": sampler.seed},
        "files": {"table": "feedforward.csv", "text": "feedforward.txt", "figures": figures,
                  "per_model": [m["folder"] for m in per_model]},
        "runtime_s": round(log.elapsed, 2),
    }
    write_json(out / "summary.json", summary)
    print(text)
    print(f"outputs in {out}/: summary.json, feedforward.csv, feedforward.txt"
          + "".join(f", {f}" for f in figures)
          + "".join(f", {m['folder']}/" for m in per_model))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the robust-feedforward analysis; return the exit status (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    return run(PROG, _analyse, args)


if __name__ == "__main__":
    sys.exit(main())
