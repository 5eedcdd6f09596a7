"""Plumbing shared by the analysis scripts: options, progress lines, bad-input handling,
atomic output files, figures, and the documented cuts of the measured data sets.

Nothing here computes a result; the scripts call the library for that.

Cutting the measured sets
-------------------------
Measured records are long (the 150 V piezo: 50 001 samples at 5 kHz for a 1 Hz sine) and
every posterior evaluation simulates them whole, so the studies shorten them in two
documented ways, both recorded in each record's ``metadata["analysis_cut"]``:

* **decimation** -- every k-th sample is kept, with ``k = round(fs / (f * spc))`` for a
  target of about ``spc`` samples per excitation cycle (never below one: nothing is
  interpolated or filtered). The excitations are slow sines (0.1-5 Hz) sampled 40-5 000 times per
  cycle, so what is dropped is sensor noise and duplicate information, not loop shape.
  The warm-up (samples simulated but not scored) is divided by k, rounded up.
* **cycles** -- after the warm-up only the first ``n`` excitation cycles are kept.

The piezo 150 V record also starts with 3.3 s at 0 V before the sine: ``trim_rest``
keeps only the last 0.2 s of that rest (the model state at 0 V is the relaxed one
either way).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst import cli as _cli
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ModelError, ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.files import write_rows_csv as write_csv  # one CSV writer
from bayeshyst.selection import split_top_level

__all__ = [
    "BAD_INPUT",
    "DATA_DIR",
    "DEFAULT_DATA",
    "EXIT_BAD_INPUT",
    "EXIT_INTERNAL",
    "EXIT_OK",
    "MEASURED",
    "MR_CURRENTS",
    "REPO",
    "Cut",
    "Progress",
    "base_parser",
    "budget",
    "cut_record",
    "describe_cut",
    "float_list",
    "load_measured",
    "name_list",
    "new_figure",
    "non_negative_float",
    "non_negative_int",
    "positive_int",
    "probability",
    "run",
    "save_figure",
    "select_frequencies",
    "slug",
    "write_csv",
    "write_text",
]

REPO = Path(__file__).resolve().parents[1]
DATA_DIR = REPO / "data"
DEFAULT_DATA = DATA_DIR / "virtual_multifreq.csv"

EXIT_OK, EXIT_INTERNAL, EXIT_BAD_INPUT = 0, 1, 2
#: What counts as bad input (exit status 2, one line on stderr): the library's own errors.
BAD_INPUT = (DataError, ParameterError, ModelError)

#: The measured data sets, by the short name the scripts' ``--datasets`` take.
MEASURED = ("piezo_150v", "micromanipulator", "mr_damper")
#: Coil currents of the MR-damper tests [A].
MR_CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)


# --------------------------------------------------------------------------- options
# the command line's own argparse types (one definition for every command)
positive_int = _cli.positive_int
non_negative_int = _cli.non_negative_int
non_negative_float = _cli.non_negative_float
probability = _cli.probability


def budget(args: argparse.Namespace, quick: Mapping[str, Any], full: Mapping[str, Any],
           overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The quick or full settings of an analysis with its command-line overrides applied.

    ``cfg["sampler"]`` is the one :class:`~bayeshyst.inference.settings.SamplerSettings`
    every fit of the analysis samples with: the quick or full one with ``--seed``,
    ``--walkers`` (``n_walkers``) and ``--steps`` (``max_steps``, capping
    ``first_chunk``) applied. Each entry of ``overrides`` that is not None replaces the
    setting of that name (which must exist: a misspelt name raises KeyError instead of
    being ignored).
    """
    cfg = dict(quick if args.quick else full)
    sampler: SamplerSettings = cfg["sampler"]
    changes: dict[str, Any] = {"seed": args.seed}
    if args.steps is not None:
        changes["max_steps"] = args.steps
        changes["first_chunk"] = min(sampler.first_chunk, args.steps)
    if getattr(args, "walkers", None) is not None:
        changes["n_walkers"] = args.walkers
    cfg["sampler"] = sampler.replace(**changes)
    for key, value in (overrides or {}).items():
        if key not in cfg:
            raise KeyError(f"no setting {key!r} to override; have {sorted(cfg)}")
        if value is not None:
            cfg[key] = value
    return cfg


def float_list(text: str) -> tuple[float, ...]:
    """An argparse type: ``"1,10,100"`` -> ``(1.0, 10.0, 100.0)``, positive finite numbers."""
    out = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got "
                                             f"{text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"expected positive numbers, got {part!r}")
        out.append(value)
    if not out:
        raise argparse.ArgumentTypeError(f"expected at least one number, got {text!r}")
    return tuple(out)


def name_list(text: str) -> tuple[str, ...]:
    """An argparse type: comma-separated names at the top level (a model spec such as
    ``pi_play(n_operators=6,r_max=100)`` keeps its commas), duplicates dropped."""
    names = tuple(dict.fromkeys(p for p in split_top_level(text) if p))
    if not names:
        raise argparse.ArgumentTypeError(f"expected at least one name, got {text!r}")
    return names


def base_parser(prog: str, doc: str | None) -> argparse.ArgumentParser:
    """The options every analysis takes: ``--quick``, ``--out``, ``--seed``, ``--quiet``,
    ``--no-figures``. ``doc`` (the module docstring) gives the description."""
    head = (doc or "").strip().split("\n\n")[0]
    parser = argparse.ArgumentParser(prog=prog, description=head)
    out_default = f"analyses-out/{prog}"
    parser.add_argument("--quick", action="store_true",
                        help="tiny budgets: a smoke run of seconds whose numbers are NOT "
                             "converged (and say so)")
    parser.add_argument("--out", default=out_default,
                        help=f"output folder (default {out_default})")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    return parser


# ------------------------------------------------------------------------- running
class Progress:
    """Progress lines on stderr: ``<prog> [  12.3 s] message``."""

    def __init__(self, prog: str, quiet: bool = False) -> None:
        self.prog, self.quiet, self.t0 = prog, quiet, time.perf_counter()

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(f"{self.prog} [{self.elapsed:7.1f} s] {message}", file=sys.stderr,
                  flush=True)

    @contextlib.contextmanager
    def follow(self, logger: str, level: int = logging.INFO) -> Iterator[None]:
        """Within the block, the library logger ``logger``'s records at ``level`` and above
        are progress lines too (e.g. the diagnosis loop's gate decisions, which a run of
        hours otherwise shows only at its end)."""
        if self.quiet:
            yield
            return
        target, progress = logging.getLogger(logger), self

        class _Forward(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                progress(record.getMessage())

        handler, old_level = _Forward(level), target.level
        target.addHandler(handler)
        if target.getEffectiveLevel() > level:
            target.setLevel(level)
        try:
            yield
        finally:
            target.removeHandler(handler)
            target.setLevel(old_level)


def run(prog: str, body: Callable[[argparse.Namespace], int],
        args: argparse.Namespace) -> int:
    """Run ``body(args)``; bad input gives exit status 2 and one line on stderr."""
    try:
        return int(body(args))
    except BAD_INPUT as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


# --------------------------------------------------------------------------- files
def slug(text: str) -> str:
    """A file-name-safe form of a model spec or data set name."""
    out = "".join(c if c.isalnum() or c in "._+-" else "_" for c in text).strip("_")
    return out or "unnamed"


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` (newline-terminated) atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text if text.endswith("\n") else text + "\n")
    return Path(path)


def new_figure(width: float, height: float) -> Any:
    """A matplotlib Figure on an Agg canvas (no pyplot, no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Any, path: Path, dpi: int = 110) -> Path:
    """Write ``fig`` as PNG atomically; return the path."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    return Path(path)


# ---------------------------------------------------------------------------- data
def select_frequencies(data: Dataset, frequencies: Sequence[float] | None) -> Dataset:
    """The records at ``frequencies`` [Hz] (all when None); DataError naming what exists."""
    if frequencies is None:
        return data
    missing = [f for f in frequencies
               if not any(math.isclose(f, g, rel_tol=1e-9) for g in data.frequencies)]
    if missing:
        have = ", ".join(f"{f:g}" for f in data.frequencies) or "none"
        raise DataError(f"{data.name}: no record at {', '.join(f'{f:g}' for f in missing)} Hz; "
                        f"frequencies in the data: {have}")
    return data.select(frequencies)


@dataclass(frozen=True)
class Cut:
    """How a measured record is shortened (see the module docstring).

    samples_per_cycle : int or None
        Decimate to about this many samples per excitation cycle (None: keep all).
    cycles : int or None
        Scored cycles kept after the warm-up (None: all).
    trim_rest_s : float or None
        Keep only this much of a leading rest at 0 V (None: keep it all).
    """

    samples_per_cycle: int | None = None
    cycles: int | None = None
    trim_rest_s: float | None = None


def _ordinal(k: int) -> str:
    """``2`` -> ``"2nd"``, ``11`` -> ``"11th"``, ``25`` -> ``"25th"``."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def cut_record(rec: Record, cut: Cut) -> Record:
    """``rec`` shortened by ``cut``; ``metadata["analysis_cut"]`` says how."""
    notes = []
    f = rec.frequency_hz
    if cut.trim_rest_s is not None and rec.n > 4:
        moving = np.flatnonzero(rec.u != rec.u[0])
        lead = round(cut.trim_rest_s * rec.fs)
        start = int(moving[0]) - lead if moving.size else 0
        if start > 0 and rec.warmup > start:
            meta = dict(rec.metadata)
            for key in ("excitation_start_index", "virgin_branch_end_index"):
                if isinstance(meta.get(key), int):
                    meta[key] = meta[key] - start
            rec = rec.slice(start, None, warmup=rec.warmup - start, name=rec.name)
            rec = rec.with_(metadata=meta)
            notes.append(f"0 V lead-in cut to its last {cut.trim_rest_s:g} s "
                         f"(first {start} samples dropped)")
    if cut.samples_per_cycle is not None and f is not None:
        k = max(1, round(rec.fs / (f * cut.samples_per_cycle)))
        if k > 1:
            fs0 = rec.fs
            meta = dict(rec.metadata)
            meta["sampling_rate_hz"] = fs0 / k
            for key in ("excitation_start_index", "virgin_branch_end_index"):
                if isinstance(meta.get(key), int):
                    meta[key] = meta[key] // k
            seg = None if rec.segment is None else rec.segment[::k]
            rec = rec.with_(t=rec.t[::k], u=rec.u[::k], y=rec.y[::k], segment=seg,
                            covariates={c: v[::k] for c, v in rec.covariates.items()},
                            warmup=min(math.ceil(rec.warmup / k), rec.t[::k].size - 2),
                            metadata=meta)
            notes.append(f"every {_ordinal(k)} sample kept ({fs0:.6g} Hz -> {fs0 / k:.6g} Hz)")
    if cut.cycles is not None and f is not None:
        stop = rec.warmup + round(cut.cycles * rec.fs / f)
        if stop < rec.n:
            rec = rec.slice(0, stop, name=rec.name)
            notes.append(f"warm-up + {cut.cycles} cycle(s) kept ({stop} samples)")
    note = "; ".join(notes) or "used whole"
    return rec.with_(metadata={**rec.metadata, "analysis_cut": note})


def describe_cut(data: Dataset) -> list[dict[str, Any]]:
    """Per record: name, samples, sampling rate, warm-up and how it was cut."""
    return [{"record": r.name, "frequency_hz": r.frequency_hz, "n": r.n, "fs_hz": r.fs,
             "warmup": r.warmup, "cut": r.metadata.get("analysis_cut", "used whole")}
            for r in data]


def load_measured(key: str, cut: Cut, *, mr_current: float = 0.5,
                  mr_frequencies: Sequence[float] | None = None) -> Dataset:
    """One measured data set from the shared folder, cut by ``cut``.

    Parameters
    ----------
    key : {"piezo_150v", "micromanipulator", "mr_damper"}
        ``piezo_150v``: :func:`~bayeshyst.data.measured.load_piezo_actuator_150v` (its
        0 V lead-in trimmed when ``cut.trim_rest_s`` is set); ``micromanipulator``:
        :func:`~bayeshyst.data.measured.load_piezo_micromanipulator` (``which="model"``);
        ``mr_damper``: :func:`~bayeshyst.data.measured.load_mr_damper` at one coil
        current (its frequencies are the comparison's axis).
    cut : Cut
    mr_current : float
        Coil current of the MR-damper tests [A].
    mr_frequencies : sequence of float, optional
        MR-damper frequencies kept (default all six).

    Raises
    ------
    DataError
        When the shared folder (``shared_data_root``) or the set is missing.
    """
    from bayeshyst.data import measured

    if key == "piezo_150v":
        data = measured.load_piezo_actuator_150v()
    elif key == "micromanipulator":
        data = measured.load_piezo_micromanipulator(which="model")
    elif key == "mr_damper":
        data = measured.load_mr_damper(current_a=mr_current, frequency_hz=mr_frequencies)
    else:
        raise ParameterError(f"unknown measured data set {key!r}; known: {', '.join(MEASURED)}")
    if key != "piezo_150v":
        cut = Cut(cut.samples_per_cycle, cut.cycles, None)
    return Dataset([cut_record(r, cut) for r in data], name=data.name)
