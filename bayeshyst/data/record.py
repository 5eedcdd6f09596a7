"""The validated measurement container :class:`Record`, and frequency identities.

A :class:`Record` is one contiguous measurement of an actuator: time ``t``, input ``u``
and output ``y`` sampled together, plus metadata. Everything downstream (models,
likelihoods, reports) trusts a Record without re-checking it, so validation happens
exactly once, in ``__post_init__``, and the arrays are stored as read-only float64
copies so that nobody can invalidate a Record after it was checked.

Records travel in a :class:`~bayeshyst.data.dataset.Dataset` (one per excitation
frequency, typically).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from bayeshyst.errors import DataError

__all__ = ["DEFAULT_UNITS", "MAGNITUDE_MAX", "MIN_SAMPLES", "RESOLUTION_MIN", "SPAN_MIN",
           "Record", "frequency_key", "frequency_label"]

def frequency_key(f: float | None) -> float | None:
    """The identity of an excitation frequency: the value to 6 significant digits.

    Values that agree to 6 significant digits are one frequency (a file's 10 and a
    computed 10.000000001 Hz group together).

    Every grouping and comparison of frequencies goes through it, via
    :attr:`Record.frequency_hz`; ``metadata["frequency_hz"]`` keeps the value as given.
    """
    return None if f is None else float(f"{float(f):.6g}")


def frequency_label(f: float | None) -> str:
    """``"10 Hz"``, or ``"unknown"`` for records without a frequency.

    Parameters
    ----------
    f : float or None
        An excitation frequency in Hz (a :func:`frequency_key`), None when unknown.

    Returns
    -------
    str
    """
    return "unknown" if f is None else f"{f:g} Hz"


#: Fewest samples a Record may hold. Four is the smallest count that can contain one
#: rise and one fall of the input (a minimal loop) and still leave two scored samples
#: after a one-sample warm-up; anything shorter cannot inform a hysteresis model.
MIN_SAMPLES = 4

# The magnitudes of input and output that a fit handles, checked by check_fittable when
# data are read from a file. Measured with ``bayeshyst fit`` (pi_play, 200 steps) on a
# synthetic record (u 13..142 V, y 6..27 um, noise 0.05 um) with u and y multiplied by
# 10^k: the summaries are scale-equivariant (every parameter's mean and sd, RMSE) for
# u and y from 1e-149 to 1e152 times together, y alone from 1e-99 to 1e151 and u alone
# from 1e-148 to 1e142, i.e. while the gain span(y)/span(u) stays within 1e+-150. Past
# that the fit breaks on float64 itself: squares of the data, of the gain and its
# inverse (the linear block's Grams and prior precisions) overflow past ~1.3e154 or
# underflow below ~1.5e-154 (at y ~ 1e-199 every density is zero; at gain ~ 1e159 the
# Grams are singular). Bounding |x| by 1e50 and the span by 1e-50 keeps every such
# square, gain^2 (<= 1e200) and sum of 1e8 squares (<= 1e108) a hundred orders of
# magnitude inside float64, while no physical unit choice comes near the bounds.
#: Largest ``max|x|`` of the input and of the output of a fittable file.
MAGNITUDE_MAX = 1e50
#: Smallest peak-to-peak span of the input and of the output of a fittable file.
SPAN_MIN = 1e-50
# A column that sits far from zero varies over few float64 values: with y offset to
# 2e13 its 21 um span spans ~5e3 ulps and the fit of the measurement above went wrong
# (RMSE 1.5x the unshifted fit's, 3.8x with 100x less noise); offset to 2e10 and 2e11
# (span/max|y| = 1e-9, 1e-10) it matched to every printed digit, at 2e12 it began to
# drift (RMSE 1.3 % off with the smaller noise). A span of at least 1e-9 max|x| leaves
# at most 2.2e-7 of the span per ulp, far below any sensor's noise.
#: Smallest ``span / max|x|`` of the input and of the output of a fittable file.
RESOLUTION_MIN = 1e-9

#: Units assumed for columns that the caller does not specify.
DEFAULT_UNITS: Mapping[str, str] = MappingProxyType({"t": "s", "u": "V", "y": "um"})


def _default_units() -> dict[str, str]:
    return dict(DEFAULT_UNITS)


def _freeze(value: Any) -> Any:
    """Return an immutable equivalent of a metadata value (dict -> proxy, list -> tuple)."""
    if isinstance(value, np.ndarray):
        return _freeze(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return MappingProxyType({k: _freeze(v) for k, v in value.items()})
    if isinstance(value, list | tuple):
        return tuple(_freeze(v) for v in value)
    return value


def _thaw(value: Any) -> Any:
    """Inverse of :func:`_freeze` for mappings (mappingproxy cannot be pickled)."""
    if isinstance(value, Mapping):
        return {k: _thaw(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(_thaw(v) for v in value)
    return value


def _where(name: str, metadata: Mapping[str, Any]) -> str:
    """Human-readable identification of a record for error messages."""
    source = metadata.get("source")
    return f"record {name!r}" + (f" (source {source})" if source else "")


def _as_vector(values: Any, column: str, where: str, dtype: type = np.float64) -> np.ndarray:
    """Convert ``values`` to a read-only 1-D copy of ``dtype`` or raise DataError."""
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{where}: column {column!r}: cannot convert to an array ({exc})") from exc
    if arr.dtype.kind not in "biuf":
        raise DataError(
            f"{where}: column {column!r}: expected real numbers, found dtype {arr.dtype}"
        )
    if arr.ndim != 1:
        raise DataError(
            f"{where}: column {column!r}: expected a 1-D array, found shape {arr.shape}"
        )
    out = np.array(arr, dtype=dtype, copy=True)
    out.flags.writeable = False
    return out


def _covariates(values: Any, n: int, where: str) -> Mapping[str, np.ndarray]:
    """Validated read-only covariate columns (see :class:`Record`)."""
    if not isinstance(values, Mapping):
        raise DataError(f"{where}: covariates: expected a mapping name -> (n,) array, "
                        f"found {type(values).__name__}")
    out = {}
    for name, raw in values.items():
        if not isinstance(name, str) or not name or name in ("t", "u", "y", "segment"):
            raise DataError(f"{where}: covariates: expected a column name other than "
                            f"t, u, y, segment, found {name!r}")
        arr = _as_vector(raw, name, where)
        if arr.size != n:
            raise DataError(f"{where}: covariate {name!r}: expected {n} samples (the length "
                            f"of 't'), found {arr.size}")
        finite = np.isfinite(arr)
        if not finite.all():
            i = _first_bad(~finite)
            raise DataError(f"{where}: covariate {name!r}, sample index {i} (0-based): "
                            f"expected a finite value, found {float(arr[i])!r}")
        out[name] = arr
    return MappingProxyType(out)


def _first_bad(mask: np.ndarray) -> int:
    """Index of the first True in a boolean mask (caller knows there is one)."""
    return int(np.argmax(mask))


@dataclass(frozen=True, eq=False, repr=False)
class Record:
    """One contiguous, validated measurement of an actuator.

    Parameters
    ----------
    t : array_like of float, shape (n,)
        Sample times [s], finite and strictly increasing; ``n >= MIN_SAMPLES`` (4).
    u : array_like of float, shape (n,)
        Input, e.g. drive voltage [``units["u"]``, V by default].
    y : array_like of float, shape (n,)
        Output, e.g. displacement [``units["y"]``, µm by default].
    segment : array_like of int, shape (n,), optional
        Per-sample integer label of experiment segments (e.g. frequency blocks or
        protocol phases). Float input is accepted only if integer-valued.
    warmup : int, default 0
        Number of leading samples that a model simulates (to build up its hysteretic
        memory) but that no likelihood scores. Must leave at least 2 scored samples.
    metadata : mapping, optional
        Free-form facts. Recognised keys: ``frequency_hz`` (float > 0 or None),
        ``amplitude``, ``source`` (file or provenance), ``temperature_c``. Stored as a
        read-only mapping; lists become tuples and NumPy values Python scalars/tuples.
    units : mapping of str to str, optional
        Units of the columns; missing keys take :data:`DEFAULT_UNITS`.
    name : str, default "record"
        Identifier, unique within a :class:`~bayeshyst.data.dataset.Dataset`.
    covariates : mapping of str to array_like, optional
        Other measured channels of the same samples (temperature, load, a second sensor,
        a coil current), ``name -> (n,)`` finite values, named as in the file. No model
        reads them unless it asks for one by name; the diagnosis looks at every one as a
        candidate driver of what the model misses. Stored as a read-only mapping of
        read-only float64 copies.

    Raises
    ------
    DataError
        If any check fails. The message names the record (and its source file when
        known), the column, the 0-based sample index, and what was expected vs found.

    Notes
    -----
    Arrays are stored as read-only float64 (``segment``: int64) copies. Records are
    immutable; derive new ones with :meth:`with_` (``dataclasses.replace``) or
    :meth:`slice`, which re-validate.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    segment: np.ndarray | None = None
    warmup: int = 0
    metadata: Mapping[str, Any] = field(default_factory=dict)
    units: Mapping[str, str] = field(default_factory=_default_units)
    name: str = "record"
    covariates: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise DataError(f"record name: expected a non-empty string, found {self.name!r}")
        if not isinstance(self.metadata, Mapping):
            raise DataError(
                f"record {self.name!r}: metadata: expected a mapping, "
                f"found {type(self.metadata).__name__}"
            )
        bad_keys = [k for k in self.metadata if not isinstance(k, str)]
        if bad_keys:
            raise DataError(
                f"record {self.name!r}: metadata: expected string keys, found {bad_keys[0]!r}"
            )
        metadata = _freeze(self.metadata)
        where = _where(self.name, metadata)

        columns = {c: _as_vector(getattr(self, c), c, where) for c in ("t", "u", "y")}
        n = columns["t"].size
        for c in ("u", "y"):
            if columns[c].size != n:
                raise DataError(
                    f"{where}: column {c!r}: expected {n} samples (the length of 't'), "
                    f"found {columns[c].size}"
                )
        if n < MIN_SAMPLES:
            raise DataError(
                f"{where}: expected at least {MIN_SAMPLES} samples (MIN_SAMPLES), found {n}"
            )
        for c, arr in columns.items():
            finite = np.isfinite(arr)
            if not finite.all():
                i = _first_bad(~finite)
                raise DataError(
                    f"{where}: column {c!r}, sample index {i} (0-based): "
                    f"expected a finite value, found {float(arr[i])!r}"
                )
        t = columns["t"]
        steps = np.diff(t)
        if not (steps > 0).all():
            i = _first_bad(steps <= 0) + 1
            kind = "duplicate time" if steps[i - 1] == 0 else "decreasing time"
            raise DataError(
                f"{where}: column 't', sample index {i} (0-based): expected strictly "
                f"increasing time (> {float(t[i - 1])!r} at index {i - 1}), "
                f"found {float(t[i])!r} ({kind})"
            )

        segment = None
        if self.segment is not None:
            raw = _as_vector(self.segment, "segment", where)
            if raw.size != n:
                raise DataError(
                    f"{where}: column 'segment': expected {n} samples (the length of 't'), "
                    f"found {raw.size}"
                )
            integral = np.isfinite(raw) & (raw == np.round(raw))
            if not integral.all():
                i = _first_bad(~integral)
                raise DataError(
                    f"{where}: column 'segment', sample index {i} (0-based): "
                    f"expected an integer label, found {float(raw[i])!r}"
                )
            segment = raw.astype(np.int64)
            segment.flags.writeable = False

        warmup = self.warmup
        if isinstance(warmup, bool) or not isinstance(warmup, int | np.integer):
            raise DataError(f"{where}: warmup: expected an integer, found {warmup!r}")
        warmup = int(warmup)
        if not 0 <= warmup <= n - 2:
            raise DataError(
                f"{where}: warmup: expected 0 <= warmup <= {n - 2} (at least 2 scored samples "
                f"out of {n}), found {warmup}"
            )

        if not isinstance(self.units, Mapping):
            raise DataError(
                f"{where}: units: expected a mapping, found {type(self.units).__name__}"
            )
        units = {**DEFAULT_UNITS, **self.units}
        for key, unit in units.items():
            if not isinstance(key, str) or not isinstance(unit, str):
                raise DataError(
                    f"{where}: units: expected str -> str, found {key!r}: {unit!r}"
                )

        freq = metadata.get("frequency_hz")
        if freq is not None:
            ok = isinstance(freq, int | float) and not isinstance(freq, bool)
            if not ok or not math.isfinite(freq) or freq <= 0:
                raise DataError(
                    f"{where}: metadata 'frequency_hz': expected a positive finite number or "
                    f"None, found {freq!r}"
                )
            metadata = MappingProxyType({**metadata, "frequency_hz": float(freq)})

        covariates = _covariates(self.covariates, n, where)

        # frozen dataclass: object.__setattr__ is the sanctioned way to normalise fields
        for key, value in (
            ("covariates", covariates),
            *columns.items(),
            ("segment", segment),
            ("warmup", warmup),
            ("metadata", metadata),
            ("units", MappingProxyType(units)),
        ):
            object.__setattr__(self, key, value)

    # -- derived quantities -------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    def __len__(self) -> int:
        return self.n

    @functools.cached_property
    def dt(self) -> float:
        """Sampling step [s].

        The mean step ``duration / (n - 1)`` when every step is within 1 % of it (uniform
        sampling whose time stamps carry rounding jitter, where the median would be
        biased by the rounding pattern), else the median step (robust to gaps).
        """
        steps = np.diff(self.t)
        mean = self.duration / (self.n - 1)
        if np.all(np.abs(steps - mean) <= 0.01 * mean):
            return float(mean)
        return float(np.median(steps))

    @property
    def fs(self) -> float:
        """Sampling rate [Hz], ``1 / dt``."""
        return 1.0 / self.dt

    @property
    def duration(self) -> float:
        """``t[-1] - t[0]`` [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def frequency_hz(self) -> float | None:
        """Excitation frequency [Hz] from ``metadata["frequency_hz"]``, or None.

        Rounded to 6 significant digits (:func:`frequency_key`: the frequency's identity).
        """
        return frequency_key(self.metadata.get("frequency_hz"))

    @property
    def measured_output(self) -> bool:
        """Whether ``y`` was measured (False for an input read alone, ``y`` zeros).

        ``metadata["output_measured"]``, set by a reader given a file without an output
        column; True when absent.
        """
        return bool(self.metadata.get("output_measured", True))

    @property
    def band_hz(self) -> tuple[float, float] | None:
        """The input's band [Hz] from ``metadata["band_hz"]``, or None.

        Set when the record's excitation was classified (a multisine or broadband input).
        """
        band = self.metadata.get("band_hz")
        if isinstance(band, tuple | list) and len(band) == 2:
            return float(band[0]), float(band[1])
        return None

    @property
    def group(self) -> str:
        """The group a record is reported in: ``"10 Hz"``, ``"band 5-150 Hz"`` or ``"unknown"``.

        Its excitation frequency when it has one; else, for a multisine or broadband
        record, its band (records driven over the same band are one group); else
        ``"unknown"``.
        """
        # deferred: groups imports this module (its identity is the one label source)
        from bayeshyst.data.groups import group_key, group_label

        return group_label(group_key(self))

    @property
    def source(self) -> str | None:
        """Provenance (``metadata["source"]``), or None."""
        source = self.metadata.get("source")
        return None if source is None else str(source)

    @property
    def scored(self) -> slice:
        """Slice of the samples a likelihood scores (everything after the warm-up)."""
        return slice(self.warmup, self.n)

    @property
    def scored_mask(self) -> np.ndarray:
        """Boolean mask, shape (n,), True for scored samples."""
        mask = np.zeros(self.n, dtype=bool)
        mask[self.warmup :] = True
        return mask

    @property
    def n_scored(self) -> int:
        """Number of scored samples, ``n - warmup``."""
        return self.n - self.warmup

    @property
    def stroke(self) -> float:
        """Peak-to-peak output over the whole record [``units["y"]``]."""
        return float(np.ptp(self.y))

    # -- derivation -----------------------------------------------------------------
    def with_(self, **changes: Any) -> Record:
        """Return a re-validated copy with fields replaced (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def slice(
        self,
        start: int | None = None,
        stop: int | None = None,
        *,
        warmup: int | None = None,
        name: str | None = None,
    ) -> Record:
        """Return samples ``start:stop`` as a new Record (metadata and units kept).

        Parameters
        ----------
        start, stop : int, optional
            Python slice bounds in samples (negative values count from the end).
        warmup : int, optional
            Warm-up of the new record, counted from its **new** start. Default: the
            parent's warm-up count, because a cut segment starts from an unknown
            hysteretic state and needs the same burn-in as the original did.
        name : str, optional
            Default ``"<name>[start:stop]"``.
        """
        lo, hi, _ = slice(start, stop).indices(self.n)
        hi = max(hi, lo)
        seg = None if self.segment is None else self.segment[lo:hi]
        return dataclasses.replace(
            self,
            covariates={k: v[lo:hi] for k, v in self.covariates.items()},
            t=self.t[lo:hi],
            u=self.u[lo:hi],
            y=self.y[lo:hi],
            segment=seg,
            warmup=self.warmup if warmup is None else warmup,
            name=f"{self.name}[{lo}:{hi}]" if name is None else name,
        )

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        # rebuild through __init__: read-only mappings are not picklable, and
        # multiprocessing pools (emcee, joblib) must be able to ship Records to workers
        return (
            Record,
            (self.t, self.u, self.y, self.segment, self.warmup, _thaw(self.metadata),
             dict(self.units), self.name, dict(self.covariates)),
        )

    # -- comparison and display --------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Record):
            return NotImplemented
        if (self.segment is None) != (other.segment is None):
            return False
        arrays = ("t", "u", "y") + (() if self.segment is None else ("segment",))
        return (
            self.name == other.name
            and self.warmup == other.warmup
            and dict(self.units) == dict(other.units)
            and self.metadata == other.metadata
            and all(np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays)
            and set(self.covariates) == set(other.covariates)
            and all(np.array_equal(v, other.covariates[k]) for k, v in self.covariates.items())
        )

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays: not hashable

    def __str__(self) -> str:
        freq = self.frequency_hz
        f = "f=?" if freq is None else f"f={freq:g} Hz"
        return (
            f"Record {self.name!r}: n={self.n}, t={self.t[0]:g}..{self.t[-1]:g} "
            f"{self.units['t']}, fs={self.fs:.6g} Hz, {f}, "
            f"u={self.u.min():.4g}..{self.u.max():.4g} {self.units['u']}, "
            f"stroke={self.stroke:.4g} {self.units['y']}, warmup={self.warmup}"
        )

    def __repr__(self) -> str:
        return (
            f"Record(name={self.name!r}, n={self.n}, warmup={self.warmup}, "
            f"frequency_hz={self.frequency_hz!r})"
        )
