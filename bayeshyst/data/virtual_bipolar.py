"""Bipolar mode of the virtual actuator: butterfly strain loops of a poled PZT element.

Driven through ±E beyond its coercive field, a ferroelectric switches its polarisation
and its strain traces a butterfly (MODELS.md §9). :class:`BipolarActuator` simulates
that with a known truth, for tests and examples of the ``butterfly`` models; it is
independent of :mod:`bayeshyst.models` (kernel :mod:`bayeshyst.data._bipolar_kernels`)
and of the unipolar :class:`~bayeshyst.data.virtual.VirtualActuator`, whose outputs
(and the bundled data) it leaves untouched.

Physics (input: field E in kV/mm; output: displacement in um)::

    P_sw = mean of R = n_relays^2 ±1 relays (alpha, beta) = (c + r, c - r)
           r on the Normal quantiles of (E_c, coercive_spread), c on those of
           (0, interaction_spread): a Preisach density symmetric about the origin
    P    = P_sw + chi E - sum_j kappa_j m_j          (relaxing remanence, see the kernel)
    S    = Q P^2 + d E + white sensor noise

Ground truth: the quantile grids are symmetric, so on the major loop (from saturation)
``P_sw`` crosses zero exactly at ``E = ±E_c`` (``coercive_field_kv_mm``): the field a
fitted coercive field is compared with. Remanent strain relaxes during holds at zero
field (``relax_fractions`` with time constants ``relax_taus_s``); every record starts
from the poled, relaxed state at zero field (positive saturation, then back to 0).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

from bayeshyst.data._bipolar_kernels import bipolar_path
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ParameterError

__all__ = ["BIPOLAR_UNITS", "BipolarActuator", "bipolar_records"]

#: Units of the records: time, field, displacement.
BIPOLAR_UNITS = {"t": "s", "u": "kV/mm", "y": "um"}

_SIMULATOR = "bayeshyst.data.virtual_bipolar.BipolarActuator"


def _positive(owner: str, name: str, value: Any, *, zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
        raise ParameterError(f"{owner}.{name}: expected a number, got {value!r}")
    ok = math.isfinite(value) and (value >= 0 if zero else value > 0)
    if not ok:
        raise ParameterError(f"{owner}.{name}: expected a finite value "
                             f"{'>= 0' if zero else '> 0'}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class BipolarActuator:
    """A simulated poled PZT element under bipolar drive, every effect known.

    Parameters
    ----------
    coercive_field_kv_mm : float, default 1.0
        ``E_c`` (kV/mm): median relay half-width; ``P_sw = 0`` at ``±E_c`` on the major loop.
    coercive_spread_kv_mm : float, default 0.12
        Standard deviation of the relay half-widths (kV/mm); every half-width must stay
        positive (refused otherwise, never clipped).
    interaction_spread_kv_mm : float, default 0.15
        Standard deviation of the relay centres (kV/mm): sloped branches, minor loops.
    n_relays : int, default 40
        Quantiles per axis (``n_relays^2`` relays).
    susceptibility_per_kv_mm : float, default 0.04
        Reversible polarisation ``chi E`` (units of saturation per kV/mm).
    q_um : float, default 1.5
        Strain (displacement) at saturation, ``S = Q P^2 + ...`` (um).
    d_lin_um_per_kv_mm : float, default 0.02
        Linear term (um per kV/mm).
    relax_fractions : tuple of float, default (0.03, 0.03, 0.03)
        Fractions ``kappa_j`` of the remanence that relax at zero field.
    relax_taus_s : tuple of float, default (0.05, 0.5, 5.0)
        Their time constants (s).
    noise_um : float, default 0.003
        Standard deviation of the white sensor noise (um); 0 switches it off.
    """

    coercive_field_kv_mm: float = 1.0
    coercive_spread_kv_mm: float = 0.12
    interaction_spread_kv_mm: float = 0.15
    n_relays: int = 40
    susceptibility_per_kv_mm: float = 0.04
    q_um: float = 1.5
    d_lin_um_per_kv_mm: float = 0.02
    relax_fractions: tuple[float, ...] = (0.03, 0.03, 0.03)
    relax_taus_s: tuple[float, ...] = (0.05, 0.5, 5.0)
    noise_um: float = 0.003

    def __post_init__(self) -> None:
        me = type(self).__name__
        _positive(me, "coercive_field_kv_mm", self.coercive_field_kv_mm)
        _positive(me, "coercive_spread_kv_mm", self.coercive_spread_kv_mm, zero=True)
        _positive(me, "interaction_spread_kv_mm", self.interaction_spread_kv_mm, zero=True)
        _positive(me, "susceptibility_per_kv_mm", self.susceptibility_per_kv_mm, zero=True)
        _positive(me, "q_um", self.q_um)
        _positive(me, "noise_um", self.noise_um, zero=True)
        if not math.isfinite(self.d_lin_um_per_kv_mm):
            raise ParameterError(f"{me}.d_lin_um_per_kv_mm: expected a finite value, "
                                 f"got {self.d_lin_um_per_kv_mm!r}")
        if isinstance(self.n_relays, bool) or not isinstance(self.n_relays, int) \
                or self.n_relays < 2:
            raise ParameterError(f"{me}.n_relays: expected an int >= 2, got {self.n_relays!r}")
        if len(self.relax_fractions) != len(self.relax_taus_s):
            raise ParameterError(f"{me}: relax_fractions and relax_taus_s differ in length "
                                 f"({len(self.relax_fractions)} and {len(self.relax_taus_s)})")
        for k, tau in zip(self.relax_fractions, self.relax_taus_s, strict=True):
            _positive(me, "relax_fractions", k, zero=True)
            _positive(me, "relax_taus_s", tau)
        if sum(self.relax_fractions) >= 1.0:
            raise ParameterError(f"{me}.relax_fractions: must sum to < 1 (the remanence "
                                 f"cannot relax past zero), got {sum(self.relax_fractions)!r}")
        half = self._half_widths()
        if half.min() <= 0:
            raise ParameterError(
                f"{me}: coercive_spread_kv_mm={self.coercive_spread_kv_mm!r} puts relay "
                f"half-widths at {half.min():.4g} <= 0 kV/mm; reduce the spread")

    def _quantiles(self) -> np.ndarray:
        return stats.norm.ppf((np.arange(self.n_relays) + 0.5) / self.n_relays)

    def _half_widths(self) -> np.ndarray:
        return self.coercive_field_kv_mm + self.coercive_spread_kv_mm * self._quantiles()

    def relays(self) -> tuple[np.ndarray, np.ndarray]:
        """Up- and down-switching fields ``(alpha, beta)`` of every relay (kV/mm), shape (R,)."""
        r = self._half_widths()
        c = self.interaction_spread_kv_mm * self._quantiles()
        rr, cc = np.meshgrid(r, c, indexing="ij")
        return np.ascontiguousarray((cc + rr).ravel()), np.ascontiguousarray((cc - rr).ravel())

    def poled_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Relays and relaxing parts after poling: positive saturation, back to zero field."""
        _, beta = self.relays()
        # coming down to E = 0 switches off exactly the relays with beta >= 0
        return np.where(beta >= 0.0, -1.0, 1.0), np.zeros(len(self.relax_taus_s))

    def simulate(self, t: Any, u: Any, *, rng: np.random.Generator | int | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Measured strain and true polarisation for the field ``u`` at times ``t``.

        Parameters
        ----------
        t, u : array_like, shape (N,)
            Times (s, strictly increasing) and field (kV/mm); the element starts poled
            and relaxed.
        rng : numpy.random.Generator or int, optional
            Noise source; required when ``noise_um > 0``.

        Returns
        -------
        y : ndarray, shape (N,)
            Displacement (um), noise included.
        p : ndarray, shape (N,)
            Polarisation (units of the relays' saturation), noise-free.
        """
        t = np.ascontiguousarray(t, dtype=float)
        u = np.ascontiguousarray(u, dtype=float)
        if t.ndim != 1 or t.shape != u.shape or t.size < 2:
            raise DataError(f"bipolar actuator: expected t and u 1-D of equal length >= 2, "
                            f"got {t.shape} and {u.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
            raise DataError("bipolar actuator: t and u must be finite")
        if not np.all(np.diff(t) > 0):
            raise DataError("bipolar actuator: t must increase strictly")
        if self.noise_um > 0 and rng is None:
            raise ParameterError("rng: noise is on; pass a numpy Generator or an int seed")
        alpha, beta = self.relays()
        relays, m = self.poled_state()
        y = np.empty(u.size)
        p = np.empty(u.size)
        bipolar_path(t, u, alpha, beta, relays, m, np.asarray(self.relax_taus_s, float),
                     np.asarray(self.relax_fractions, float), self.coercive_field_kv_mm,
                     self.susceptibility_per_kv_mm, self.q_um, self.d_lin_um_per_kv_mm, y, p)
        if self.noise_um > 0:
            y = y + np.random.default_rng(rng).normal(0.0, self.noise_um, u.size)
        return y, p

    def truth(self) -> dict[str, Any]:
        """Every parameter, as a JSON-serialisable dict (stored in each record's metadata)."""
        out = asdict(self)
        out["relax_fractions"] = list(self.relax_fractions)
        out["relax_taus_s"] = list(self.relax_taus_s)
        return {"simulator": _SIMULATOR,
                "chain": "E -> +-1 relay ensemble P_sw -> P = P_sw + chi E - relaxing "
                         "remanence -> S = Q P^2 + d E -> + white noise",
                **out}


def bipolar_records(actuator: BipolarActuator | None = None, *,
                    amplitudes_kv_mm: tuple[float, ...] = (1.5, 2.0, 2.5),
                    frequencies_hz: tuple[float, ...] = (1.0, 10.0), cycles: int = 3,
                    samples_per_cycle: int = 400, hold_s: float = 1.0,
                    seed: int = 0) -> Dataset:
    """Bipolar butterfly loops at several amplitudes and frequencies, each ending in a hold.

    Record ``(a, f)`` drives ``E = a sin(2 pi f t)`` for ``cycles`` cycles from the poled
    state, then holds ``E = 0`` for ``hold_s`` seconds (the remanent strain relaxes), at
    ``samples_per_cycle * f`` samples per second; the first cycle is warm-up. Its noise
    comes from ``default_rng([seed, i])`` (record ``i`` in amplitude-major order): the same
    seed gives the same data.

    Parameters
    ----------
    actuator : BipolarActuator, optional
        Default :class:`BipolarActuator()`.
    amplitudes_kv_mm : tuple of float
        Field amplitudes (kV/mm); above ``2 E_c`` a loop switches fully.
    frequencies_hz : tuple of float
        Drive frequencies (Hz).
    cycles : int
        Cycles per record (>= 1).
    samples_per_cycle : int
        Sampling (>= 8).
    hold_s : float
        Hold at zero field after the cycles (s), ``>= 0``; 0 for none.
    seed : int
        Root seed of the noise.

    Returns
    -------
    Dataset
        Records named ``bipolar_{a}kVmm@{f}Hz``, units :data:`BIPOLAR_UNITS`; metadata
        ``truth`` (:meth:`BipolarActuator.truth`), ``frequency_hz``, ``amplitude_kv_mm``,
        ``hold_start`` (first sample of the hold), ``seed``.
    """
    act = BipolarActuator() if actuator is None else actuator
    if not isinstance(act, BipolarActuator):
        raise ParameterError(f"actuator: expected a BipolarActuator, got {type(act).__name__}")
    for name, value, low in (("cycles", cycles, 1), ("samples_per_cycle", samples_per_cycle, 8),
                             ("seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
            raise ParameterError(f"{name}: expected an int >= {low}, got {value!r}")
    _positive("bipolar_records", "hold_s", hold_s, zero=True)
    if not amplitudes_kv_mm or not frequencies_hz:
        raise ParameterError("amplitudes_kv_mm and frequencies_hz must not be empty")
    records = []
    for a in amplitudes_kv_mm:
        _positive("bipolar_records", "amplitudes_kv_mm", a)
        for f in frequencies_hz:
            _positive("bipolar_records", "frequencies_hz", f)
            fs = samples_per_cycle * f
            n_drive = cycles * samples_per_cycle
            n_hold = round(hold_s * fs)
            t = np.arange(n_drive + 1 + n_hold) / fs
            u = np.zeros(t.size)
            u[:n_drive + 1] = a * np.sin(2.0 * np.pi * f * t[:n_drive + 1])
            u[n_drive] = 0.0  # the sine's end, exactly at zero field: the hold starts here
            i = len(records)
            y, _ = act.simulate(t, u, rng=np.random.default_rng([seed, i]))
            meta = {"source": "virtual bipolar actuator", "truth": act.truth(),
                    "frequency_hz": float(f), "amplitude_kv_mm": float(a),
                    "hold_start": int(n_drive), "seed": [int(seed), i]}
            records.append(Record(t=t, u=u, y=y, warmup=samples_per_cycle, metadata=meta,
                                  name=f"bipolar_{a:g}kVmm@{f:g}Hz", units=BIPOLAR_UNITS))
    return Dataset(records, name="virtual_bipolar")
