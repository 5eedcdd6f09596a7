"""The ``bayeshyst`` argument parser: one sub-command per verb."""

from __future__ import annotations

import argparse

from bayeshyst._version import __version__
from bayeshyst.cli.commands import (
    cmd_compare,
    cmd_compensate,
    cmd_diagnose,
    cmd_export,
    cmd_fit,
    cmd_invert,
    cmd_models,
    cmd_predict,
)
from bayeshyst.cli.options import (
    closed_probability,
    column_mapping,
    initial_condition,
    non_negative_float,
    non_negative_int,
    positive_int,
    probability,
    unit_mapping,
    working_rate,
)
from bayeshyst.cli.study_commands import cmd_demo, cmd_report, cmd_study
from bayeshyst.inference.settings import MOVES
from bayeshyst.likelihoods import likelihood_names

__all__ = ["add_run_options", "add_working_rate_option", "build_parser"]


def add_run_options(p: argparse.ArgumentParser, out_default: str, steps_help: str) -> None:
    """Add the options every command that samples shares.

    Data, likelihood, output folder, seed, sampler budget, walkers, moves, and what is
    printed and drawn.
    """
    p.add_argument("data", help="data file (.csv/.txt/.npz/.mat, JSON sidecar optional)")
    p.add_argument("--columns", type=column_mapping, default=None, metavar="t=..,u=..,y=..",
                   help="which columns of the file are time, input and output (with or "
                        "without their units), e.g. 't=Time [s],u=Voltage,y=Displacement'; "
                        "default: t,u,y, the sidecar's mapping, or names such as time, "
                        "voltage, displacement. Units in the header ('Time [ms]', 'x (nm)', "
                        "'U/V', 'B [mT]') are converted: time to s, a voltage to V, a "
                        "length to um, a force to N, a current to A, a flux density to T, "
                        "a field to A/m; other units are kept, no unit is 'unknown'")
    p.add_argument("--units", type=unit_mapping, default=None, metavar="u=..,y=..",
                   help="units of the file's columns where neither the header nor the "
                        "sidecar gives them, e.g. 'u=A/m,y=mT' or 't=ms'; converted like "
                        "header units (a header unit must agree)")
    p.add_argument("--no-frequency-labels", action="store_true",
                   help="leave records without a frequency_hz unlabelled (default: their "
                        "excitation frequency is estimated from the input's cycles, and a "
                        "record holding several frequencies is split into one per block)")
    p.add_argument("--likelihood", default="gaussian", choices=likelihood_names(),
                   help="observation model: gaussian (default), student_t or ar1")
    p.add_argument("--out", default=out_default, help=f"output folder (default {out_default})")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--steps", type=positive_int, default=20_000, help=steps_help)
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="walkers per ensemble (default: from the number of parameters the "
                        "moves propose: max(24, 4 d + 4) structured (up to 48 for a "
                        "larger ESS target), max(32, 4 ndim) de and stretch)")
    p.add_argument("--moves", choices=MOVES, default="structured",
                   help="sampler moves: structured (default) = exact Gibbs draws of the "
                        "linear block + adaptive independence + differential evolution; "
                        "de = emcee's differential-evolution moves on every coordinate, "
                        "the previous engine, kept as a baseline; stretch = emcee's "
                        "affine-invariant stretch move")
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")


def add_working_rate_option(p: argparse.ArgumentParser) -> None:
    """Add ``--working-rate {auto,full,HZ}`` (``diagnose``, ``compare``, ``report``)."""
    p.add_argument("--working-rate", type=working_rate, default="auto",
                   metavar="auto|full|HZ",
                   help="rate the records are fitted at: auto (default) decimates each "
                        "record, anti-aliased, to the slowest rate that keeps its output's "
                        "and input's spectrum above the noise floor and >= 100 samples per "
                        "excitation cycle (bayeshyst.data.working_rate); full keeps every "
                        "sample; a number decimates to at least that many Hz")


def add_saved_fit_options(p: argparse.ArgumentParser, out_default: str, files: str) -> None:
    """The options of the commands that read a saved fit: FIT, --out, --json, --quiet."""
    p.add_argument("fit", metavar="FIT", help="a fit's output folder or its posterior .nc file")
    p.add_argument("--out", default=out_default, metavar="DIR",
                   help=f"output folder (default {out_default}): {files}")
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p.add_argument("--quiet", action="store_true", help="no progress line on stderr")


#: one example per command, shown under its --help
EXAMPLES = {
    "models": ["bayeshyst models pi_play creep --json"],
    "fit": ["bayeshyst fit scope.csv --model bouc_wen+second_order --out fit-bw",
            "bayeshyst fit scope.csv --model pi_play --columns 't=Time [ms],u=Drive,y=Sensor' "
            "--likelihood ar1"],
    "compare": ["bayeshyst compare data/virtual_multifreq.csv --models pi_play,bouc_wen,gp "
                "--out cmp"],
    "compensate": ["bayeshyst compensate data/virtual_multifreq.csv --model "
                   "'pi_play(n_operators=8)+second_order' --reference sine --out comp"],
    "invert": ["bayeshyst invert fit-bw --reference ref.csv --objective robust --out cmd"],
    "predict": ["bayeshyst predict fit-bw other-record.csv --out pred",
                "bayeshyst predict fit-bw test-multisine.h5 --columns u=multisine/u,"
                "y=multisine/y --units u=N,y=m --initial periodic:3 --out pred-ms"],
    "export": ["bayeshyst export fit-pi --format c --reference ref.csv --out ctrl"],
    "diagnose": ["bayeshyst diagnose data/virtual_multifreq.csv --model pi_play --out diag"],
    "report": ["bayeshyst report data/virtual_multifreq.csv --models pi_play,bouc_wen,gp_memory "
               "--out rep"],
    "demo": ["bayeshyst demo --quick --out demo"],
    "study": ["bayeshyst study my-study.toml --jobs 8 --out my-study --report"],
}


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
    p_models.set_defaults(func=cmd_models)

    p_fit = sub.add_parser("fit", help="sample the posterior of one model given data")
    p_fit.add_argument("--model", required=True,
                       help="model name or spec string, e.g. bouc_wen+second_order")
    add_run_options(p_fit, "bayeshyst-fit", "step budget per ensemble (default 20000)")
    p_fit.add_argument("--no-checkpoint", action="store_true",
                       help="do not checkpoint to OUT/checkpoint.h5 (and do not resume)")
    p_fit.add_argument("--discrepancy", choices=("none", "hsgp"), default="none",
                       help="model-discrepancy term: none (default) or hsgp, a reduced-rank "
                            "(Hilbert-space) GP over the loop's coordinates (input, branch "
                            "position, frequency)")
    p_fit.add_argument("--no-calibration", action="store_true",
                       help="skip the leave-cycles-out calibration check (one more posterior "
                            "run without the last cycle of every record)")
    p_fit.set_defaults(func=cmd_fit)

    p_cmp = sub.add_parser("compare", help="rank models per excitation frequency "
                           "(PSIS-LOO, WAIC, leave-one-frequency-out, BIC, stacking)")
    p_cmp.add_argument("--models", required=True,
                       help="comma-separated model specs, e.g. "
                            "pi_play,bouc_wen,pi_play+second_order,gp,gp_memory")
    add_run_options(p_cmp, "bayeshyst-compare",
                     "step budget per ensemble of every fit (default 20000)")
    p_cmp.add_argument("--jobs", type=positive_int, default=None,
                       help="worker processes (default: one per core)")
    p_cmp.add_argument("--no-lofo", action="store_true",
                       help="skip the leave-one-frequency-out fits")
    p_cmp.add_argument("--max-refits", type=non_negative_int, default=5,
                       help="exact refits per fit for cycles with Pareto k > 0.7 (default 5)")
    p_cmp.add_argument("--gp-train", type=positive_int, default=1000,
                       help="training-subset size of the GP models (default 1000)")
    p_cmp.add_argument("--gp-sampling", action="store_true",
                       help="sample the GP models' hyperparameters (same sampler and "
                            "criteria as every model) and score them mixed over the "
                            "draws; minutes per GP fit instead of seconds")
    add_working_rate_option(p_cmp)
    p_cmp.set_defaults(func=cmd_compare)

    p_comp = sub.add_parser("compensate", help="design feedforward commands from the posterior "
                            "of one model and score their tracking per frequency")
    p_comp.add_argument("--model", required=True,
                        help="model name or spec string, e.g. pi_play+second_order")
    add_run_options(p_comp, "bayeshyst-compensate", "step budget per ensemble (default 20000)")
    p_comp.add_argument("--reference", default="sine", metavar="sine|triangle|FILE",
                        help="reference to track: a sine or triangle at every frequency of "
                             "the data (default sine), or a CSV file with header t,y "
                             "(s, output unit), tracked once")
    p_comp.add_argument("--jobs", type=positive_int, default=None,
                        help="worker processes evaluating the references (default: one "
                             "per core; the result does not depend on it)")
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
    p_comp.add_argument("--discrepancy", choices=("none", "hsgp"), default="none",
                        help="fit with a model-discrepancy term (hsgp) and design and predict "
                             "the commands against model + discrepancy (default none)")
    p_comp.add_argument("--validation", default=None, metavar="FILE",
                        help="measured records NOT fitted on, driven along paths like the "
                             "commands' (minor loops, another amplitude): the bands carry "
                             "their residual instead of the training residual (same columns "
                             "and units as DATA)")
    p_comp.add_argument("--discrepancy-transfer", type=closed_probability, default=0.5,
                        metavar="P",
                        help="with --discrepancy hsgp and no --validation: probability that "
                             "the discrepancy learned on the identification loops holds "
                             "along the commands' paths; the bands mix both cases (default "
                             "0.5; 1 = trust it everywhere)")
    p_comp.add_argument("--nominal-inverse", choices=("numerical", "closed_form"),
                        default="numerical",
                        help="the nominal command: the MAP inverted numerically (default) "
                             "or by the model's closed-form inverse (pi_play, mbw, "
                             "bouc_wen, bouc_wen_asym, duhem)")
    p_comp.set_defaults(func=cmd_compensate)

    p_inv = sub.add_parser("invert", help="a feedforward command for a reference from a saved "
                           "fit (fit/compare/diagnose/report output), without refitting")
    add_saved_fit_options(p_inv, "bayeshyst-invert", "command.csv, summary.json")
    p_inv.add_argument("--reference", required=True, metavar="FILE",
                       help="CSV file with header t,y (s, output unit): the trajectory to "
                            "follow")
    p_inv.add_argument("--objective", choices=("nominal", "mean", "robust"), default="mean",
                       help="nominal = inverse of the MAP model; mean (default) = the "
                            "posterior-mean output follows the reference; robust = the "
                            "quantile of |error| over draws is smallest")
    p_inv.add_argument("--design-draws", type=positive_int, default=24, metavar="N",
                       help="posterior draws the mean/robust command is designed on "
                            "(default 24)")
    p_inv.add_argument("--predict-draws", type=positive_int, default=100, metavar="N",
                       help="held-out posterior draws the band is predicted from "
                            "(default 100)")
    p_inv.add_argument("--quantile", type=probability, default=0.9, metavar="Q",
                       help="quantile of |error| the robust command minimises (default 0.9)")
    p_inv.add_argument("--discrepancy-transfer", type=closed_probability, default=0.5,
                       metavar="P",
                       help="for a fit with a discrepancy: probability that it holds along "
                            "the reference's paths; the band mixes both cases (default 0.5)")
    p_inv.add_argument("--seed", type=int, default=0,
                       help="seeds the choice of draws (default 0): same seed, same command")
    p_inv.set_defaults(func=cmd_invert)

    p_pred = sub.add_parser("predict", help="a saved fit's posterior predictive on another "
                            "record, in free run, scored against its measured output")
    add_saved_fit_options(p_pred, "bayeshyst-predict", "predictions.csv, scores.csv, "
                          "summary.json, figures/")
    p_pred.add_argument("data", metavar="DATA",
                        help="data file (.csv/.txt/.npz/.mat/.h5) with the input and the "
                             "measured output; converted to the fit's units when its header "
                             "or sidecar gives others")
    p_pred.add_argument("--columns", type=column_mapping, default=None,
                        metavar="t=..,u=..,y=..",
                        help="which columns (or HDF5 datasets) of DATA are time, input and "
                             "output, as for fit")
    p_pred.add_argument("--units", type=unit_mapping, default=None, metavar="u=..,y=..",
                        help="units of DATA's columns where neither the header nor the "
                             "sidecar gives them, as for fit")
    p_pred.add_argument("--no-frequency-labels", action="store_true",
                        help="leave records without a frequency_hz unlabelled")
    p_pred.add_argument("--initial", type=initial_condition, default="relaxed",
                        metavar="relaxed|rest|warmup:S|periodic:K",
                        help="the model's state before each record: relaxed at its first "
                             "input (default, as in the fit); rest (relaxed at zero input); "
                             "warmup:S (the first S seconds simulated, not scored); "
                             "periodic:K (the record holds whole periods: played K times, "
                             "the last scored)")
    p_pred.add_argument("--draws", type=positive_int, default=400, metavar="N",
                        help="posterior draws simulated (default 400, at most those stored)")
    p_pred.add_argument("--seed", type=int, default=0,
                        help="seeds the draws, the noise and the PIT (default 0)")
    p_pred.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p_pred.set_defaults(func=cmd_predict)

    p_exp = sub.add_parser("export", help="a saved fit's inverse for a real-time controller: "
                           "JSON parameters, C99 source or a lookup table")
    add_saved_fit_options(p_exp, "bayeshyst-export", "inverse.json, the C files or the "
                          "table, summary.json")
    p_exp.add_argument("--format", choices=("json", "c", "table"), default="json",
                       dest="fmt", help="json (default): the inverse's parameters; c: also "
                                        "a C99 header and source; table: the branch tables "
                                        "(also of a model with a closed form) as CSV too")
    p_exp.add_argument("--method", choices=("auto", "play_pi", "mbw", "table"),
                       default="auto",
                       help="auto (default): the closed-form inverse where the hysteresis is "
                            "a play-PI or a modified Bouc-Wen, else branch tables")
    p_exp.add_argument("--prefix", default="bh", metavar="NAME",
                       help="C identifier prefix of the generated code (default bh)")
    p_exp.add_argument("--reference", default=None, metavar="FILE",
                       help="a t,y CSV to replay the exported inverse on: its error against "
                            "the exact inverse goes into summary.json")
    p_exp.set_defaults(func=cmd_export)

    p_dg = sub.add_parser("diagnose", help="trace what a model leaves in its residual to a "
                          "missing effect, add it, refit, and report the error before and after")
    p_dg.add_argument("--model", required=True,
                      help="base model name or spec string, e.g. pi_play(n_operators=8)")
    add_run_options(p_dg, "bayeshyst-diagnose",
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
    p_dg.add_argument("--screen", action="store_true",
                      help="screen every fired block from its MAP before sampling: one "
                           "that loses its gate even with the screen's error given is not "
                           "sampled, one that may pass is sampled beyond the round's budget")
    p_dg.add_argument("--jobs", type=positive_int, default=None,
                      help="processes fitting at once: workers fit ahead of the loop the "
                           "candidates it may need next (default: one per core; the "
                           "result does not depend on it)")
    add_working_rate_option(p_dg)
    p_dg.set_defaults(func=cmd_diagnose)

    p_rep = sub.add_parser("report", help="the whole study on one dataset: compare models per "
                           "frequency, diagnose the best, design feedforward; one HTML report")
    p_rep.add_argument("--models", default=None,
                       help="comma-separated model specs (default "
                            "pi_play,bouc_wen,pi_play+second_order,gp_memory)")
    add_run_options(p_rep, "bayeshyst-report",
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
    p_rep.add_argument("--screen", action="store_true",
                       help="the diagnosis screens every fired block from its MAP before "
                            "sampling (see diagnose --screen)")
    p_rep.add_argument("--no-calibration", action="store_true",
                       help="skip the uncertainty analysis' calibration check (one more "
                            "posterior run of the final model without the last cycle of "
                            "every record)")
    p_rep.add_argument("--validation", default=None, metavar="FILE",
                       help="measured records NOT fitted on, driven along paths like the "
                            "feedforward commands': the tracking bands carry their residual "
                            "instead of the training residual (as in compensate)")
    add_working_rate_option(p_rep)
    p_rep.set_defaults(func=cmd_report)

    p_demo = sub.add_parser("demo", help="the whole study (bayeshyst report) on the bundled "
                            "virtual-actuator data")
    p_demo.add_argument("--quick", action="store_true",
                        help="about half a minute: 2 models, 2 frequencies, one "
                             "diagnosis round, every fit converged")
    p_demo.add_argument("--out", default="bayeshyst-demo",
                        help="output folder (default bayeshyst-demo)")
    p_demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p_demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p_demo.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p_demo.add_argument("--no-figures", action="store_true", help="skip the figures")
    p_demo.set_defaults(func=cmd_demo)

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
    where.add_argument("--jobs", "--workers", dest="workers", type=positive_int, default=None,
                       metavar="N", help="worker processes of the local cluster (default: one "
                                         "per core; --workers is the same option)")
    where.add_argument("--serial", action="store_true",
                       help="no Dask: run the fits one after the other in this process")
    p_st.add_argument("--retry-failed", action="store_true",
                      help="run again the fits whose stored result is a failure")
    p_st.add_argument("--report", action="store_true", help="also write study.html")
    p_st.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p_st.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p_st.add_argument("--no-figures", action="store_true", help="skip the figures")
    p_st.set_defaults(func=cmd_study)
    for name, p in sub.choices.items():
        p.add_argument("-v", "--verbose", action="count", default=0,
                       help="log what the library does on stderr (-v: steps, -vv: details)")
        p.epilog = "example:\n  " + "\n  ".join(EXAMPLES[name])
        p.formatter_class = argparse.RawDescriptionHelpFormatter
    return parser

