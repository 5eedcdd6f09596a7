"""Model-selection study: which hysteresis model predicts best, per data set and frequency.

Answers the question of a model-selection study across frequencies: for every data set
and every excitation frequency in it, which of the candidate models has the best
expected predictive density for a held-out input cycle (PSIS-LOO, ``elpd_loo``), by how
much (Δelpd and its paired standard error), with which stacking weight and tracking error
(NRMSE of the posterior-mean prediction), and whether the fits behind the numbers
converged. Each data set goes through :func:`bayeshyst.selection.compare_models`
(a fit per model and frequency, plus the joint fit over all frequencies, and in full
mode the leave-one-frequency-out fits); the study collects one long table.

Data sets (``--datasets``, default all four):

* ``virtual`` -- the bundled ``data/virtual_multifreq.csv`` (``--data`` to replace it):
  the virtual actuator at 1, 10, 50, 100 and 200 Hz;
* ``piezo_150v`` -- measured piezo actuator, ±150 V / 1 Hz
  (:func:`~bayeshyst.data.measured.load_piezo_actuator_150v`);
* ``micromanipulator`` -- measured piezo micromanipulator, 1 Hz
  (:func:`~bayeshyst.data.measured.load_piezo_micromanipulator`, ``which="model"``);
* ``mr_damper`` -- measured MR damper at one coil current (``--mr-current``, default
  0.5 A), 0.1-5 Hz (:func:`~bayeshyst.data.measured.load_mr_damper`).

The measured sets are read from ``../shared/data`` (or ``$BAYESHYST_SHARED_DATA``); when
that folder is absent they are skipped with the reason printed and recorded in
``summary.json``. They are shortened as documented in :mod:`analyses._common`: full
mode decimates every record to about 200 samples per excitation cycle and keeps the
warm-up plus at most 10 cycles (the 150 V record also loses all but 0.2 s of its 0 V
lead-in); quick mode keeps about 50 samples per cycle and 3 cycles, and of the
multi-frequency sets only the lowest and the highest frequency. The bundled set is used
whole in full mode; quick mode keeps every 2nd sample (100 per cycle). Every record's cut is
in ``summary.json`` (``datasets[*].records``).

Outputs in ``--out``: ``table.csv`` and ``table.json`` (one row per data set ×
frequency × model: ``dataset, frequency_hz, model, elpd_loo, se, delta_elpd, delta_se,
weight, nrmse_percent, converged`` and more), ``study.txt``, ``winners.png`` (the winner
per data set × frequency), one folder per data set with what ``bayeshyst compare``
writes, and ``summary.json`` (written last).

Run (from the repository root)::

    python -m analyses.model_selection_study              # full: 4 models, 4 data sets,
                                                          # <= 10 000 steps, LOFO (hours)
    python -m analyses.model_selection_study --quick      # seconds: 2 models, 2 frequencies
    python -m analyses.model_selection_study --datasets virtual,mr_damper \\
        --models "pi_play,bouc_wen" --jobs 2

The MR damper is compared on its own default list (:data:`MODELS_BY_DATASET`): Spencer's
force form ``bouc_wen(sign=1, parametrisation='saturation')``, with and without the viscous
term on the velocity column, ``bouc_wen_freq(sign=1)``, the piezo form as the contrast
and ``gp_memory``; ``--models`` sets one list for every data set.

Quick mode (``--quick``): models ``bouc_wen`` and ``pi_play(n_operators=4)`` (the MR
damper: the force form and the piezo form), 200
sampler steps, no leave-one-frequency-out fits, no exact LOO refits; its rankings are
NOT converged and the table's ``converged`` column says so.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from analyses._common import (
    DEFAULT_DATA,
    EXIT_OK,
    MEASURED,
    MR_CURRENTS,
    Cut,
    Progress,
    base_parser,
    budget,
    cut_record,
    describe_cut,
    load_measured,
    name_list,
    new_figure,
    non_negative_int,
    positive_int,
    run,
    save_figure,
    slug,
    write_csv,
    write_text,
)
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.files import write_json

PROG = "model_selection_study"
DATASETS = ("virtual", *MEASURED)

FULL_MODELS = ("pi_play", "bouc_wen", "pi_play(n_operators=6)+second_order", "gp_memory")
QUICK_MODELS = ("bouc_wen", "pi_play(n_operators=4)")
#: Spencer's force form of Bouc–Wen, ``F = k x + h``, in the saturation coordinates.
MR_BOUC_WEN = "bouc_wen(sign=1, parametrisation='saturation')"
#: Default models of a data set whose loop is not a piezo stage's (``--models`` sets one
#: list for all). An MR damper's force loop runs the other way round (steep after each
#: reversal, then a plateau): the piezo form ``k u - h`` and the play-PI cannot draw it
#: for any parameters (fitted anyway: a linear spring, RMSE 146 N at 0 A), so the study
#: compares the force form, the force form with the damper's viscous term on the
#: velocity column the data carry (what the residual loop found first at every current
#: it ran on), the frequency-dependent variant in the same orientation, and the GP; the
#: piezo form stays in full mode as the contrast.
MODELS_BY_DATASET = {
    "mr_damper": {
        "full": (MR_BOUC_WEN, f"{MR_BOUC_WEN}+aux(column='velocity_mm_s')",
                 "bouc_wen_freq(sign=1)", "bouc_wen", "gp_memory"),
        "quick": (MR_BOUC_WEN, "bouc_wen"),
    },
}


def default_models(key: str, quick: bool) -> tuple[str, ...]:
    """The models a data set is compared on when ``--models`` is not given."""
    mode = "quick" if quick else "full"
    if key in MODELS_BY_DATASET:
        return MODELS_BY_DATASET[key][mode]
    return QUICK_MODELS if quick else FULL_MODELS
FULL = {"sampler": SamplerSettings(max_steps=10_000), "lofo": True, "max_refits": 5,
        "cut": Cut(samples_per_cycle=200, cycles=10, trim_rest_s=0.2)}
# 3 cycles after the warm-up: the cycle-wise LOO needs >= 2 whole cycles for a standard
# error (a partial last cycle joins its neighbour)
QUICK = {"sampler": SamplerSettings(max_steps=200, first_chunk=200), "lofo": False,
         "max_refits": 0,
         "cut": Cut(samples_per_cycle=50, cycles=3, trim_rest_s=0.2)}
#: Quick mode halves the bundled records' 200 samples per cycle (all 4 cycles kept).
QUICK_VIRTUAL_CUT = Cut(samples_per_cycle=100)

TABLE_COLUMNS = ("dataset", "frequency_hz", "model", "elpd_loo", "se", "delta_elpd",
                 "delta_se", "weight", "nrmse_percent", "converged", "rank", "best",
                 "max_error_percent", "elpd_lofo", "lofo_se", "n_params", "n_cycles",
                 "max_pareto_k", "error")


def build_parser() -> argparse.ArgumentParser:
    """Options of the model-selection study."""
    p = base_parser(PROG, __doc__)
    p.add_argument("--datasets", type=name_list, default=DATASETS, metavar="A,B,...",
                   help=f"data sets to compare on (default all: {', '.join(DATASETS)})")
    p.add_argument("--models", type=name_list, default=None, metavar="SPEC,SPEC,...",
                   help=f"model specs for every data set (default {','.join(FULL_MODELS)}; "
                        f"--quick {','.join(QUICK_MODELS)}; the MR damper: Spencer's force "
                        f"form, see MODELS_BY_DATASET)")
    p.add_argument("--data", default=str(DEFAULT_DATA),
                   help="file of the 'virtual' data set (default the bundled "
                        "data/virtual_multifreq.csv)")
    p.add_argument("--mr-current", type=float, default=0.5, choices=MR_CURRENTS,
                   metavar="A", help="coil current of the MR-damper tests [A]: 0, 0.25, 0.5 "
                   "(default), 0.75 or 1")
    p.add_argument("--likelihood", default="gaussian",
                   help="gaussian (default), student_t or ar1")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="step budget per ensemble of every fit (default 10000; --quick 200)")
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="walkers per ensemble (default: from the number of parameters)")
    p.add_argument("--jobs", type=positive_int, default=None,
                   help="worker processes (default one per core)")
    p.add_argument("--max-refits", type=non_negative_int, default=None,
                   help="exact LOO refits per fit for cycles with Pareto k > 0.7 "
                        "(default 5; --quick 0)")
    p.add_argument("--no-lofo", action="store_true",
                   help="skip the leave-one-frequency-out fits (always skipped in --quick)")
    return p


# --------------------------------------------------------------------------- data
def _ends(values: Sequence[float]) -> tuple[float, ...]:
    """The lowest and the highest of ``values`` (all of them when there are <= 2)."""
    values = sorted(values)
    return tuple(values) if len(values) <= 2 else (values[0], values[-1])


def load_datasets(args: argparse.Namespace, cut: Cut, log: Progress
                  ) -> tuple[list[tuple[str, Any]], list[dict[str, str]]]:
    """The data sets to compare on, and those skipped (with the reason).

    Raises DataError for a bad ``--data`` or when nothing is left to compare.
    """
    from bayeshyst.data import Dataset, load
    from bayeshyst.data.measured import shared_data_root

    unknown = [d for d in args.datasets if d not in DATASETS]
    if unknown:
        raise ParameterError(f"--datasets: unknown {unknown}; known: {', '.join(DATASETS)}")
    chosen, skipped = [], []
    shared_error = None
    if any(d in MEASURED for d in args.datasets):
        try:
            shared_data_root()
        except DataError as exc:
            shared_error = str(exc)
    for key in args.datasets:
        if key == "virtual":
            data = load(args.data)
            if args.quick:
                keep = _ends(data.frequencies)
                data = data.select(keep) if keep else data
                data = Dataset([cut_record(r, QUICK_VIRTUAL_CUT) for r in data],
                               name=data.name)
            chosen.append((key, data))
            continue
        if shared_error is not None:
            reason = f"measured data not available: {shared_error}"
            skipped.append({"dataset": key, "reason": reason})
            log(f"skipping {key}: {reason}")
            continue
        try:
            mr_freqs = None
            if key == "mr_damper" and args.quick:
                all_f = load_measured("mr_damper", Cut(), mr_current=args.mr_current).frequencies
                mr_freqs = _ends(all_f)
            data = load_measured(key, cut, mr_current=args.mr_current, mr_frequencies=mr_freqs)
        except DataError as exc:
            skipped.append({"dataset": key, "reason": str(exc)})
            log(f"skipping {key}: {exc}")
            continue
        chosen.append((key, data))
    if not chosen:
        reasons = "; ".join(f"{s['dataset']}: {s['reason']}" for s in skipped)
        raise DataError(f"no data set left to compare on ({reasons})")
    return chosen, skipped


# ------------------------------------------------------------------------- results
def table_rows(key: str, result: Any) -> list[dict[str, Any]]:
    """One row per frequency × model of one data set (the joint 'all' rows excluded)."""
    rows = []
    for fc in result.per_frequency:
        for rank, s in enumerate(fc.scores, start=1):
            rows.append({
                "dataset": key, "frequency_hz": fc.frequency_hz, "model": s.model,
                "elpd_loo": s.elpd_loo, "se": s.se, "delta_elpd": s.delta_elpd,
                "delta_se": s.delta_se, "weight": s.weight, "nrmse_percent": s.nrmse_percent,
                "converged": bool(s.converged), "rank": rank, "best": s.model == fc.best,
                "max_error_percent": s.max_error_percent, "elpd_lofo": s.elpd_lofo,
                "lofo_se": s.lofo_se, "n_params": s.n_params, "n_cycles": s.n_cycles,
                "max_pareto_k": s.max_pareto_k, "error": s.error,
            })
    return rows


def winners(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per data set × frequency: the winner, the runner-up's Δelpd ± se, convergence."""
    out = []
    groups: dict[tuple[str, Any], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["dataset"], r["frequency_hz"]), []).append(r)
    for (key, f), rs in groups.items():
        ranked = sorted(rs, key=lambda r: r["rank"])
        best = next((r for r in ranked if r["best"]), None)
        runner = ranked[1] if len(ranked) > 1 else None
        margin = -runner["delta_elpd"] if runner and runner["error"] is None else math.nan
        margin_se = runner["delta_se"] if runner and runner["error"] is None else math.nan
        clear = bool(math.isfinite(margin) and margin > 2 * margin_se)
        out.append({"dataset": key, "frequency_hz": f,
                    "winner": None if best is None else best["model"],
                    "runner_up": None if runner is None else runner["model"],
                    "margin_elpd": margin, "margin_se": margin_se, "clear": clear,
                    "all_converged": all(r["converged"] for r in rs)})
    return out


def _f(x: Any, spec: str = ".1f") -> str:
    return format(x, spec) if isinstance(x, int | float) and math.isfinite(x) else "—"


def _flabel(f: Any) -> str:
    return "unknown" if f is None else f"{f:g} Hz"


def study_text(rows: list[dict[str, Any]], wins: list[dict[str, Any]],
               skipped: list[dict[str, str]], quick: bool) -> str:
    """The plain-text summary (``study.txt``)."""
    lines = ["MODEL-SELECTION STUDY: best model per data set and frequency by PSIS-LOO "
             "(one input cycle left out)"]
    if not all(r["converged"] for r in rows):
        n_bad = sum(not r["converged"] for r in rows)
        lines += ["", f"*** NOT converged: {n_bad} of {len(rows)} rows rest on fits whose "
                  "sampler did not converge; their rankings are provisional"
                  + (" (quick run)" if quick else " (raise --steps)") + ". ***"]
    for s in skipped:
        lines.append(f"skipped {s['dataset']}: {s['reason']}")
    current = None
    for w in wins:
        if w["dataset"] != current:
            current = w["dataset"]
            lines += ["", f"== {current}"]
        margin = (f"by {_f(w['margin_elpd'])} ± {_f(w['margin_se'])} over {w['runner_up']}"
                  if w["runner_up"] else "(single model)")
        verdict = "clear (> 2 se)" if w["clear"] else "not clear (<= 2 se)"
        conv = "" if w["all_converged"] else "  [NOT converged]"
        lines.append(f"  {_flabel(w['frequency_hz']):>10}: {w['winner']} {margin}; "
                     f"{verdict}{conv}")
        for r in rows:
            if r["dataset"] == w["dataset"] and r["frequency_hz"] == w["frequency_hz"]:
                err = f"  failed: {r['error']}" if r["error"] else ""
                lines.append(f"      {r['rank']}. {r['model']:<36} elpd {_f(r['elpd_loo']):>9} "
                             f"(se {_f(r['se'])}), Δ {_f(r['delta_elpd']):>8}, weight "
                             f"{_f(r['weight'], '.2f')}, NRMSE {_f(r['nrmse_percent'], '.3f')} %"
                             f"{'' if r['converged'] else ', not converged'}{err}")
    return "\n".join(lines)


def plot_winners(wins: list[dict[str, Any]], models: Sequence[str], path: Path) -> Path:
    """A grid: one row per data set, one cell per frequency, coloured by the winner."""
    from matplotlib.patches import Patch, Rectangle

    keys = list(dict.fromkeys(w["dataset"] for w in wins))
    ncol = max(sum(w["dataset"] == k for w in wins) for k in keys)
    fig = new_figure(max(6.0, 1.6 + 1.7 * ncol), 1.1 + 0.8 * len(keys))
    ax = fig.add_subplot()
    palette = ["#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#edc948",
               "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"]
    colour = {m: palette[i % len(palette)] for i, m in enumerate(models)}
    for i, key in enumerate(keys):
        cells = sorted((w for w in wins if w["dataset"] == key),
                       key=lambda w: math.inf if w["frequency_hz"] is None else w["frequency_hz"])
        for j, w in enumerate(cells):
            y = len(keys) - 1 - i
            ax.add_patch(Rectangle((j, y), 0.96, 0.92, facecolor=colour.get(w["winner"], "#ddd"),
                                   hatch=None if w["all_converged"] else "//",
                                   edgecolor="white", alpha=1.0 if w["clear"] else 0.55))
            margin = (f"+{_f(w['margin_elpd'])} ± {_f(w['margin_se'])}"
                      if math.isfinite(w["margin_elpd"]) else "")
            ax.text(j + 0.48, y + 0.46, f"{_flabel(w['frequency_hz'])}\n{margin}",
                    ha="center", va="center", fontsize=7,
                    bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "none", "pad": 1.5})
    ax.set_xlim(0, ncol)
    ax.set_ylim(0, len(keys))
    ax.set_yticks([len(keys) - 0.54 - i for i in range(len(keys))], keys, fontsize=8)
    ax.set_xticks([])
    for side in ("top", "right", "bottom", "left"):
        ax.spines[side].set_visible(False)
    handles = [Patch(facecolor=colour[m], label=m) for m in models]
    handles.append(Patch(facecolor="white", edgecolor="k", hatch="//", label="NOT converged"))
    fig.legend(handles=handles, loc="outside lower center", ncol=min(3, len(handles)),
               fontsize=7)
    ax.set_title("best model by elpd_loo per data set and frequency\n(cell: margin over the "
                 "runner-up ± se; pale: margin <= 2 se)", fontsize=8)
    return save_figure(fig, path)


# ---------------------------------------------------------------------------- main
def _study(args: argparse.Namespace) -> int:
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.outputs.assemble import comparison_figures
    from bayeshyst.outputs.compare_outputs import write_comparison_outputs
    from bayeshyst.selection import check_models, compare_models

    log = Progress(PROG, args.quiet)
    cfg = budget(args, QUICK, FULL, {"max_refits": args.max_refits,
                                     "lofo": False if args.no_lofo else None})
    # validate everything cheap before anything is written
    models_for = {key: check_models(list(args.models or default_models(key, args.quick)))
                  for key in args.datasets}
    get_likelihood(args.likelihood)
    datasets, skipped = load_datasets(args, cfg["cut"], log)
    out = Path(args.out)
    rows: list[dict[str, Any]] = []
    per_dataset = []
    for key, data in datasets:
        models = models_for[key]
        freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
        log(f"{key}: {len(models)} models on {data.name} ({len(data)} record(s), "
            f"{data.n_samples} samples; frequencies [Hz]: {freqs})")
        result = compare_models(data, models, likelihood=args.likelihood,
                                sampler=cfg["sampler"], lofo=cfg["lofo"],
                                max_refits=cfg["max_refits"], n_jobs=args.jobs,
                                out_dir=out / slug(key), progress=not args.quiet)
        write_comparison_outputs(result, out / slug(key),
                                 data_path=args.data if key == "virtual" else data.name,
                                 figures=None if args.no_figures or args.quick
                                 else comparison_figures(result))
        these = table_rows(key, result)
        rows += these
        n_conv = sum(r["converged"] for r in these)
        log(f"{key}: done in {result.runtime_s:.1f} s; winners "
            + ", ".join(f"{k}: {v}" for k, v in result.winners().items())
            + f"; {n_conv}/{len(these)} rows converged")
        per_dataset.append({"dataset": key, "name": data.name,
                            "frequencies_hz": list(data.frequencies),
                            "records": describe_cut(data), "folder": slug(key),
                            "models": list(models),
                            "overall_best": result.overall.best,
                            "failed_fits": [t.error for t in result.failed],
                            "runtime_s": round(result.runtime_s, 2)})
    wins = winners(rows)
    write_csv(out / "table.csv", TABLE_COLUMNS, rows)
    write_json(out / "table.json", rows)
    text = study_text(rows, wins, skipped, args.quick)
    write_text(out / "study.txt", text)
    figures = []
    if not args.no_figures:
        every = list(dict.fromkeys(m for key, _ in datasets for m in models_for[key]))
        figures.append(plot_winners(wins, every, out / "winners.png").name)
    converged = all(r["converged"] for r in rows)
    summary = {
        "command": PROG, "quick": bool(args.quick),
        "models": {key: list(models_for[key]) for key, _ in datasets},
        "likelihood": args.likelihood, "converged": converged,
        "status": "converged" if converged else "NOT converged",
        "winners": wins, "datasets": per_dataset, "skipped": skipped,
        "settings": {"sampler": cfg["sampler"].to_dict(),
                     "lofo": cfg["lofo"], "max_refits": cfg["max_refits"],
                     "n_jobs": args.jobs, "seed": cfg["sampler"].seed,
                     "mr_current_a": args.mr_current,
                     "cut": {"samples_per_cycle": cfg["cut"].samples_per_cycle,
                             "cycles": cfg["cut"].cycles,
                             "trim_rest_s": cfg["cut"].trim_rest_s}},
        "files": {"table": ["table.csv", "table.json"], "text": "study.txt",
                  "figures": figures, "per_dataset": [d["folder"] for d in per_dataset]},
        "runtime_s": round(log.elapsed, 2),
    }
    write_json(out / "summary.json", summary)
    print(text)
    print(f"outputs in {out}/: summary.json, table.csv, table.json, study.txt"
          + "".join(f", {f}" for f in figures)
          + "".join(f", {d['folder']}/" for d in per_dataset))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the model-selection study; return the exit status (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    return run(PROG, _study, args)


if __name__ == "__main__":
    sys.exit(main())
