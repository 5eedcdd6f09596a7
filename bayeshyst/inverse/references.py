"""Reference trajectories and the setting of a feedforward design.

A design is evaluated on references at each excitation frequency of the data
(:func:`design_references`: a sine or triangle spanning the central 80 % of the data's
output range, or one trajectory read with :func:`load_reference`), within the command
range the data's inputs support (:func:`command_limits`), and run on the virtual
actuator that generated the data when there is one (:func:`virtual_plant`).
Shared by :func:`~bayeshyst.inverse.compensate.compensate` and the model-averaged design
(:mod:`bayeshyst.inverse.averaged`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.parsing import is_number
from bayeshyst.data.units import ROLE_NAMES, conversion, split_header
from bayeshyst.data.virtual import VirtualActuator
from bayeshyst.errors import DataError, ParameterError

__all__ = [
    "REFERENCE_KINDS",
    "REFERENCE_MARGIN",
    "U_MARGIN",
    "Reference",
    "command_limits",
    "design_references",
    "load_reference",
    "reference_signal",
    "virtual_plant",
]

#: Built-in reference shapes.
REFERENCE_KINDS = ("sine", "triangle")
#: Fraction of the data's output range the built-in references leave free at each end.
REFERENCE_MARGIN = 0.1


# ---------------------------------------------------------------------------- references


@dataclass(frozen=True)
class Reference:
    """A desired output trajectory.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Times (s), from 0.
    y_d : ndarray, shape (N,)
        Desired output (output unit).
    scored : ndarray of bool, shape (N,)
        Samples the tracking error is measured on (after the warm-up).
    kind : str
        ``"sine"``, ``"triangle"`` or the file name.
    frequency_hz : float or None
    periodic : bool
        Whether ``y_d`` holds whole periods (the inverse dynamics is then the periodic
        steady state).
    covariates : dict of str to ndarray (N,) or None
        Measured columns along the reference (a reference file's other numeric columns,
        e.g. the temperature the command will run at), for a model that reads them.
    """

    t: np.ndarray
    y_d: np.ndarray
    scored: np.ndarray
    kind: str
    frequency_hz: float | None
    periodic: bool
    covariates: dict[str, np.ndarray] | None = None

    @property
    def stroke(self) -> float:
        """Peak-to-peak of the reference (the percentages' denominator)."""
        return float(np.ptp(self.y_d))


def reference_signal(kind: str, frequency_hz: float, fs: float, y_lo: float, y_hi: float,
                     *, cycles: int = 2, warmup_cycles: int = 1) -> Reference:
    """A periodic reference from ``y_lo`` to ``y_hi``, starting at rest at ``y_lo``.

    Parameters
    ----------
    kind : {"sine", "triangle"}
    frequency_hz : float
        Its frequency (Hz), > 0.
    fs : float
        Sampling rate (Hz); rounded to a whole number of samples per cycle.
    y_lo, y_hi : float
        Lowest and highest desired output (output unit), ``y_lo < y_hi``.
    cycles, warmup_cycles : int
        Scored cycles and the cycles before them.
    """
    if kind not in REFERENCE_KINDS:
        raise ParameterError(f"reference must be one of {REFERENCE_KINDS} or a file, "
                             f"got {kind!r}")
    if not (frequency_hz > 0 and fs > 0 and y_hi > y_lo):
        raise ParameterError(f"reference needs frequency > 0, fs > 0, y_lo < y_hi; got "
                             f"{frequency_hz}, {fs}, {y_lo}, {y_hi}")
    per_cycle = max(8, round(fs / frequency_hz))
    n = per_cycle * (cycles + warmup_cycles)
    phase = (np.arange(n) % per_cycle) / per_cycle
    shape = (0.5 - 0.5 * np.cos(2 * np.pi * phase) if kind == "sine"
             else 1.0 - 2.0 * np.abs(phase - 0.5))
    t = np.arange(n) / (per_cycle * frequency_hz)
    scored = np.arange(n) >= per_cycle * warmup_cycles
    return Reference(t, y_lo + (y_hi - y_lo) * shape, scored, kind, float(frequency_hz), True)


def load_reference(path: str | Path) -> Reference:
    """A reference from a CSV file with a header naming ``t`` and ``y`` (s, output unit).

    Instrument names work too (``Time [ms]``, ``Position (nm)``; the names of
    :data:`bayeshyst.data.units.ROLE_NAMES`), their units converted to s and µm.

    Every sample is scored; the file should start at rest (the inverse of dynamics
    needs its pre-actuation before the motion starts). Every other column is a measured
    column along the reference (``Reference.covariates``, named as in the header: e.g.
    ``temperature_c``, the conditions the command will run at, for a model that reads
    that column). Raises DataError naming the file, column and row of a problem.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataError(f"{path}: cannot read reference file: {exc.strerror}") from None
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines:
        raise DataError(f"{path}: reference file is empty")
    header = [h.strip() for h in lines[0].split(",")]
    # 't' and 'y', or an instrument's names with units ("Time [ms]", "Position (nm)")
    names = {"t": ROLE_NAMES["t"], "y": (*ROLE_NAMES["y"], "y_d", "reference", "desired")}
    index: dict[str, int] = {}
    for role, accepted in names.items():
        fits = [j for j, h in enumerate(header) if h == role] or [
            j for j, h in enumerate(header) if split_header(h)[0].lower() in accepted]
        if len(fits) != 1:
            raise DataError(f"{path}: header must name columns 't' and 'y' (or time and "
                            f"position, with units in brackets), "
                            + ("missing" if not fits else "several fit") + f" {role!r} in "
                            f"{header}")
        index[role] = fits[0]
    it, iy = index["t"], index["y"]
    first = lines[1].split(",") if len(lines) > 1 else []
    # the other columns that hold numbers are measured columns; text columns (a note,
    # a label) are ignored, as the data reader does
    extra = [j for j in range(len(header)) if j not in (it, iy)
             and j < len(first) and is_number(first[j])]
    if len({header[j] for j in extra}) != len(extra) or any(not header[j] for j in extra):
        raise DataError(f"{path}: the other columns must have distinct, non-empty names, "
                        f"got {[header[j] for j in extra]}")
    scale = {}
    for role, j in index.items():
        conv = conversion(role, split_header(header[j])[1])
        scale[role] = 1.0 if conv is None else conv[0]
    rows = []
    for row, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        values = []
        for j in (it, iy, *extra):
            try:
                values.append(float(cells[j]))
            except IndexError:
                raise DataError(f"{path}: row {row}: no cell in column {header[j]!r} "
                                f"(the row has {len(cells)} cells)") from None
            except ValueError:
                raise DataError(f"{path}: row {row}, column {header[j]!r}: expected a "
                                f"number, got {cells[j].strip()!r}") from None
        rows.append(values)
    arr = np.array(rows)
    if arr.shape[0] < 8:
        raise DataError(f"{path}: expected at least 8 samples, got {arr.shape[0]}")
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if bad.size:
        raise DataError(f"{path}: row {int(bad[0]) + 2}: values must be finite")
    steps = np.diff(arr[:, 0])
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0])
        raise DataError(f"{path}: column 't', row {i + 3}: time must increase, "
                        f"{arr[i + 1, 0]!r} follows {arr[i, 0]!r}")
    arr[:, :2] = arr[:, :2] * np.array([scale["t"], scale["y"]])
    t = arr[:, 0] - arr[0, 0]
    if np.ptp(arr[:, 1]) <= 0:
        raise DataError(f"{path}: column 'y' is constant: nothing to track")
    covariates = {header[j]: arr[:, 2 + i].copy() for i, j in enumerate(extra)} or None
    return Reference(t, arr[:, 1].copy(), np.ones(t.size, dtype=bool), path.name, None, False,
                     covariates)


#: how far beyond the data's input range a command may go, as a fraction of that range
#: at each end (every design's default)
U_MARGIN = 0.25


def command_limits(data: Dataset, u_margin: float = U_MARGIN) -> tuple[float, float]:
    """The admissible command range (input unit).

    The data's input range widened by ``u_margin`` of its span at each end.
    """
    u_all = np.concatenate([r.u for r in data])
    lo_u, hi_u = float(u_all.min()), float(u_all.max())
    return (lo_u - u_margin * (hi_u - lo_u), hi_u + u_margin * (hi_u - lo_u))


def design_references(data: Dataset, reference: str | Reference, *, cycles: int = 2,
                      warmup_cycles: int = 1) -> list[tuple[Reference, Dataset]]:
    """The references a design is evaluated on, each with the records it belongs to.

    Parameters
    ----------
    data : Dataset
    reference : {"sine", "triangle"} or Reference
        A built-in shape spans the central 80 % of the data's output range
        (:data:`REFERENCE_MARGIN` off each end), one per frequency of the data at its
        sampling rate; a :class:`Reference` is used once, with all records.
    cycles, warmup_cycles : int
        Scored and unscored cycles of a built-in reference.

    Raises
    ------
    DataError
        If a built-in reference is asked for and no record has a frequency.
    """
    if isinstance(reference, Reference):
        return [(reference, data)]
    y_all = np.concatenate([r.y for r in data])
    y_lo = float(y_all.min()) + REFERENCE_MARGIN * float(np.ptp(y_all))
    y_hi = float(y_all.max()) - REFERENCE_MARGIN * float(np.ptp(y_all))
    refs = []
    for f, group in data.by_frequency().items():
        if f is None:
            continue
        refs.append((reference_signal(reference, f, group[0].fs, y_lo, y_hi, cycles=cycles,
                                      warmup_cycles=warmup_cycles), group))
    if not refs:
        raise DataError(f"{data.name}: no record has a frequency_hz; pass a reference "
                        "file or label the records' frequencies")
    return refs


def virtual_plant(data: Dataset) -> VirtualActuator | None:
    """The virtual actuator that generated ``data`` (its ``truth`` metadata).

    With its sensor noise, as it generated the data: a command run on it gives the
    error a measurement would show (pass ``rng`` to its ``simulate``;
    ``.without("noise")`` for the true position). None for measured data (no record
    carries a ``truth``).
    """
    for rec in data:
        truth = rec.metadata.get("truth")
        if truth is not None:
            return VirtualActuator.from_truth(truth)
    return None
