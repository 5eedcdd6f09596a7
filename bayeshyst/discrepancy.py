"""Model discrepancy: a reduced-rank Gaussian process over the loop's own coordinates.

The statistical model becomes ``y = f(u; theta) + delta(x) + eps`` (Kennedy & O'Hagan
2001): ``f`` is the hysteresis model, ``eps`` the sensor noise, and ``delta`` what the
model family cannot represent, as a smooth function of where on the loop a sample is,

``x = (u_n, b, rho)``:

* ``u_n`` -- the input scaled to ``[-1, 1]`` over the training data's range;
* ``b`` -- the position on the branch: the output of one stop (elastic-perfectly-
  plastic) operator of the input, ``b_k = clip(b_(k-1) + 2 (u_k - u_(k-1)) / u_half,
  -1, 1)`` from ``b = 0`` at the first sample. It is +1 on a rising branch and -1 on a
  falling one once the input has travelled half its range since the last reversal,
  and moves linearly in between: rate-independent, and continuous in time both where a
  branch starts and where it ends (a bare direction of travel would put a step of
  ``2 delta_b`` in ``delta`` at every reversal, which no command can follow);
* ``rho`` -- the record's excitation frequency, ``log10 f`` scaled to ``[-1, 1]`` over
  the training frequencies (the loop's rate); 0 and unused with one frequency.

``delta(x) = delta_c(u_n, rho) + b delta_b(u_n, rho)`` with two independent zero-mean
squared-exponential GPs (amplitudes ``amplitude`` and ``branch_amplitude``, shared
length-scales ``length`` in ``u_n`` and ``rate_length`` in ``rho``): a common shape
error (asymmetry, saturation) and a loop-width error that changes sign across a reversal.

**Reduced rank** (Solin & Särkkä 2020, Hilbert-space approximation): on ``[-L, L]``
the SE kernel is ``k(x, x') ~ sum_j S(sqrt(lambda_j)) phi_j(x) phi_j(x')`` with
``phi_j(x) = L^-1/2 sin(pi j (x + L) / 2L)``, ``lambda_j = (pi j / 2L)^2`` and the
spectral density ``S(w) = sqrt(2 pi) l exp(-l^2 w^2 / 2)`` (times the squared
amplitude); products of these in ``u_n`` and ``rho``. So
``delta = B(x) (s(amplitudes, lengths) * xi)`` with a fixed basis ``B`` (N, m),
column scales ``s`` and **standardised coefficients** ``xi ~ N(0, I)``: the
coefficients are a linear block with a Gaussian prior (sampled exactly by the
posterior's linear-block move, cost O(N m)), the amplitudes and lengths are ordinary
nonlinear parameters. ``L = 2.5`` (the data span ``[-1, 1]``; a closer boundary
depresses the variance near the data's ends, tested) and ``m_u = 16`` basis functions
hold the approximation for ``length >= 1.75 L / m_u = 0.27`` (Riutort-Mayol et al.
2023), where the length prior puts 94 % of its mass.

**Confounding with theta.** ``delta`` can mimic the model's parameters; two things keep
``theta`` meaning what it says. (1) Orthogonality to the model's sensitivities
(Plumlee 2017, in its linearised, reduced-rank form): over the training samples,
``delta = B w`` is constrained to be orthogonal to ``[1, u_n]`` and to ``d f / d theta``
at a reference point (:class:`Anchor`, the MAP of the model without discrepancy), by
confining the coefficients ``w`` to the null space of ``C = Q^T B`` (``Q`` an
orthonormal basis of those directions): ``w = (I - V V^T) w0`` with ``V`` the
row space of ``C``. Whatever the model can explain by moving ``theta`` stays with
``theta``, and ``delta`` keeps only what no parameter change reaches. The constraint
acts on the coefficients, not on the basis functions: ``delta`` stays a function of
``x`` alone, evaluated the same way on any input (a feedforward command) with no
knowledge of the model's state, and the projector has norm 1, so ``delta`` is never
larger than its unconstrained prior allows. (Projecting the basis *functions* off the
sensitivities instead -- the first version -- left columns that were small residues of
large sines; their coefficients grew to match, the parts cancelled on the training
records only, and along a feedforward command or a warm-up branch ``delta`` reached
20 % of the stroke.) (2) Priors that keep ``delta`` small and smooth: half-normal
amplitudes of scale 5 % of the output span and length-scales of median half the input
range.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.models.blocks.smooth import BASIS_HALF_WIDTH, log_se_spectrum, sine_basis
from bayeshyst.models.pi import stop_response
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace

__all__ = ["DISC", "DISCREPANCY_KINDS", "Anchor", "Discrepancy", "make_discrepancy"]

#: Prefix of the discrepancy's parameters in a posterior's space.
DISC = "disc"
#: What ``--discrepancy`` accepts.
DISCREPANCY_KINDS = ("none", "hsgp")
#: Half-width of the basis domain over data scaled to [-1, 1].
_L = BASIS_HALF_WIDTH
#: Amplitude prior scale, as a fraction of the output span.
_AMPLITUDE_SHARE = 0.05
#: Overlaps with the model's sensitivities below this share of the strongest count as
#: none (rounding): every other direction is constrained. The constraint has norm 1
#: whatever its rank, so no direction needs sparing for the sake of new inputs.
PROJECTION_CUTOFF = 1e-8


def branch_coordinate(u: np.ndarray, half: float) -> np.ndarray:
    """The position on the branch ``b`` (N,): a stop operator of ``u`` with range ``[-1, 1]``.

    ``b_0 = 0``, ``b_k = clip(b_(k-1) + 2 (u_k - u_(k-1)) / half, -1, 1)``: +1 after the
    input has risen by ``half`` (input unit), -1 after it has fallen by as much, linear
    in between; continuous in time, independent of the rate. It is the stop operator of
    threshold ``half / 2`` (:func:`~bayeshyst.models.pi.stop_response`) over that
    threshold.
    """
    r = 0.5 * half
    return stop_response(u, r) / r


@dataclass(frozen=True, eq=False)
class Anchor:
    """The model and reference point whose sensitivities the discrepancy is kept off.

    Attributes
    ----------
    model : HysteresisModel
    space : ParamSpace
        The model's parameter space (its free parameters are differentiated).
    z : ndarray, shape (space.ndim,)
        The reference point in the space's unconstrained coordinates.
    """

    model: Any
    space: ParamSpace
    z: np.ndarray

    def sensitivities(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``d f / d z`` (N, k) by central differences at :attr:`z` on an input ``u`` (N,).

        Columns whose difference is not finite (a simulation failed) are left out: the
        projection then spares that direction, it does not fail.
        """
        k = self.z.size
        if k == 0:
            return np.empty((np.size(u), 0))
        h = 1e-4 * np.maximum(1.0, np.abs(self.z))
        pts = np.concatenate([self.z[None, :] + np.diag(h), self.z[None, :] - np.diag(h)])
        theta = self.space.unpack(pts)
        y = self.model.run_batch(np.asarray(u, float), np.asarray(t, float), theta).y
        jac = ((y[:k] - y[k:]) / (2.0 * h[:, None])).T
        return jac[:, np.all(np.isfinite(jac), axis=0)]


@dataclass(frozen=True, eq=False)
class Discrepancy:
    """A reduced-rank GP discrepancy ``delta(u_n, b, rho)`` (see the module docstring).

    Build it with :meth:`for_data`, which fixes the scalings and the orthogonalisation
    from the training records; the same object then evaluates the basis on new inputs
    (a feedforward command) in the same coordinates.

    Attributes
    ----------
    n_input : int
        Basis functions in ``u_n`` per component.
    n_rate : int
        Basis functions in ``rho`` (1 when the data have one frequency).
    u_centre, u_half : float
        Input scaling (input unit): ``u_n = (u - u_centre) / u_half``.
    rate_centre, rate_half : float
        ``rho = (log10 f - rate_centre) / rate_half`` (``rate_half`` 0: one frequency).
    y_span : float
        Output span of the training data (output unit): the amplitude prior's scale.
    y_unit : str
    anchor : Anchor or None
        Model and reference point whose sensitivities ``delta`` is kept orthogonal to
        (used when the object is built; evaluating the basis does not need it).
    constraint : ndarray, shape (m, r)
        Orthonormal directions of the coefficients removed from the basis, ``B = B_raw
        (I - V V^T)``: those along which ``delta`` would overlap ``[1, u_n, df/dz]``
        over the training samples.
    """

    n_input: int = 16
    n_rate: int = 1
    u_centre: float = 0.0
    u_half: float = 1.0
    rate_centre: float = 0.0
    rate_half: float = 0.0
    y_span: float = 1.0
    y_unit: str = ""
    anchor: Anchor | None = field(default=None, repr=False)
    constraint: np.ndarray | None = field(default=None, repr=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_data(cls, data: Any, *, n_input: int = 16, n_rate: int = 3,
                 anchor: Anchor | None = None) -> Discrepancy:
        """The discrepancy for a Dataset (scalings and orthogonalisation from its records).

        Parameters
        ----------
        data : Dataset
            Training records (every sample counts for the scalings, the scored ones for
            the orthogonalisation).
        n_input : int
            Basis functions in the input per component (>= 4).
        n_rate : int
            Most basis functions in the frequency; used only with >= 2 frequencies
            (then ``min(n_rate, number of frequencies)``).
        anchor : Anchor, optional
            Keep ``delta`` orthogonal to the model's sensitivities there too (default:
            to ``[1, u_n]`` only).
        """
        if int(n_input) < 4 or int(n_rate) < 1:
            raise ParameterError(f"discrepancy: n_input >= 4 and n_rate >= 1 expected, got "
                                 f"{n_input}, {n_rate}")
        records = list(data)
        u = np.concatenate([np.asarray(r.u, float) for r in records])
        y = np.concatenate([np.asarray(r.y, float) for r in records])
        u_lo, u_hi = float(u.min()), float(u.max())
        if not u_hi > u_lo:
            raise ParameterError("discrepancy: the input is constant; nothing to model")
        freqs = sorted({float(r.frequency_hz) for r in records
                        if r.frequency_hz is not None and r.frequency_hz > 0})
        if len(freqs) >= 2:
            lo, hi = math.log10(freqs[0]), math.log10(freqs[-1])
            rate_centre, rate_half, nr = 0.5 * (lo + hi), 0.5 * (hi - lo), min(n_rate, len(freqs))
        else:
            rate_centre, rate_half, nr = 0.0, 0.0, 1
        units = dict(getattr(records[0], "units", None) or {})
        base = cls(int(n_input), int(nr), 0.5 * (u_lo + u_hi), 0.5 * (u_hi - u_lo),
                   rate_centre, rate_half, float(np.ptp(y)) or 1.0, str(units.get("y", "")),
                   anchor)
        # the constraint over the scored samples of the training data: an orthonormal
        # basis Q of the directions [1, u_n, df/dz] (each scaled to unit rms so that the
        # rank decision treats them alike; collinear ones -- a gain parameter is u_n --
        # dropped), then the coefficient directions whose functions overlap them
        rows, trend = [], []
        for r in records:
            s0 = r.scored.start or 0
            rows.append(base.raw_basis(r.u, r.frequency_hz)[s0:])
            trend.append(base._trend(r.u, r.t)[s0:])
        b, a = np.concatenate(rows), np.concatenate(trend)
        scale = np.sqrt(np.mean(a**2, axis=0))
        a = a / np.where(scale > 0, scale, 1.0)
        q, sv, _ = np.linalg.svd(a, full_matrices=False)
        q = q[:, sv > 1e-8 * sv[0]]
        _, sc, vt = np.linalg.svd(q.T @ b, full_matrices=False)
        keep = sc > PROJECTION_CUTOFF * sc[0] if sc.size and sc[0] > 0 else np.zeros(0, bool)
        return replace(base, constraint=np.ascontiguousarray(vt[keep].T))

    def _trend(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The directions ``delta`` is kept off, (N, k): ``[1, u_n, df/dz]``."""
        out = np.column_stack([np.ones(np.size(u)), self.scaled_input(u)])
        if self.anchor is not None:
            out = np.column_stack([out, self.anchor.sensitivities(u, t)])
        return out

    # ------------------------------------------------------------------ coordinates
    @property
    def size(self) -> int:
        """Number of basis functions ``m`` (both components)."""
        return 2 * self.n_input * self.n_rate

    @property
    def has_rate(self) -> bool:
        """Whether ``delta`` depends on the excitation frequency."""
        return self.n_rate > 1

    def scaled_input(self, u: np.ndarray) -> np.ndarray:
        """``u_n`` (N,) of an input (input unit)."""
        return (np.asarray(u, float) - self.u_centre) / self.u_half

    def rate_coordinate(self, frequency_hz: float | None) -> float:
        """``rho`` of an excitation frequency (0 without one, or with one training frequency).

        Raises ParameterError outside the basis domain (2.5 times the training range):
        the reduced-rank basis does not extrapolate.
        """
        if not self.has_rate or frequency_hz is None or not frequency_hz > 0:
            return 0.0
        rho = (math.log10(frequency_hz) - self.rate_centre) / self.rate_half
        if abs(rho) > _L:
            lo = 10 ** (self.rate_centre - self.rate_half)
            hi = 10 ** (self.rate_centre + self.rate_half)
            raise ParameterError(f"discrepancy: frequency {frequency_hz:g} Hz is too far "
                                 f"outside the training frequencies [{lo:g}, {hi:g}] Hz")
        return rho

    def raw_basis(self, u: np.ndarray, frequency_hz: float | None) -> np.ndarray:
        """The basis before orthogonalisation, (N, m): common columns, then branch columns."""
        un = self.scaled_input(u)
        if np.any(np.abs(un) > _L):
            raise ParameterError(f"discrepancy: input reaches {float(np.max(np.abs(un))):.3g} "
                                 f"half-ranges from the training centre; the basis covers {_L}")
        pu, _ = sine_basis(un, self.n_input)
        # one frequency: no rate factor at all (a lone sine of the rate would scale the
        # kernel by 1/L)
        pr = (sine_basis(np.array([self.rate_coordinate(frequency_hz)]), self.n_rate)[0]
              if self.has_rate else np.ones((1, 1)))
        common = (pu[:, :, None] * pr[0][None, None, :]).reshape(un.size, -1)
        b = branch_coordinate(u, self.u_half)
        return np.concatenate([common, b[:, None] * common], axis=1)

    def basis(self, u: np.ndarray, frequency_hz: float | None) -> np.ndarray:
        """The basis ``B`` (N, m) on an input ``u`` (N,) at an excitation frequency.

        A function of the input's history and the frequency only (not of the model or
        its state), so a feedforward command gets the same ``delta`` as training data
        with the same coordinates.
        """
        raw = self.raw_basis(u, frequency_hz)
        if self.constraint is None or self.constraint.shape[1] == 0:
            return raw
        return raw - (raw @ self.constraint) @ self.constraint.T

    # ------------------------------------------------------------------ parameters
    def param_space(self) -> ParamSpace:
        """``xi`` (m,), ``amplitude``, ``branch_amplitude``, ``length`` [, ``rate_length``]."""
        amp = _AMPLITUDE_SHARE * self.y_span
        params = [
            Param("xi", Normal(0.0, 1.0), shape=(self.size,), unit="1",
                  description="standardised basis coefficients of the discrepancy"),
            Param("amplitude", HalfNormal(amp), unit=self.y_unit,
                  description="sd of the discrepancy common to both branches"),
            Param("branch_amplitude", HalfNormal(amp), unit=self.y_unit,
                  description="sd of the discrepancy that differs between branches"),
            Param("length", LogNormal.from_median(0.5, 0.4), unit="1",
                  description="length-scale in the input scaled to [-1, 1]"),
        ]
        if self.has_rate:
            params.append(Param("rate_length", LogNormal.from_median(1.0, 0.5), unit="1",
                                description="length-scale in log frequency scaled to [-1, 1]"))
        return ParamSpace(tuple(params))

    def column_scale(self, theta: Mapping[str, Any]) -> np.ndarray:
        """Scales ``s`` (W, m) of the basis columns: ``sqrt`` of the spectral densities.

        ``theta`` holds ``amplitude``, ``branch_amplitude``, ``length`` (and
        ``rate_length``) as arrays (W,) or scalars; ``delta = B (s * xi)``.
        """
        amp = np.atleast_1d(np.asarray(theta["amplitude"], float)).ravel()
        amp_b = np.atleast_1d(np.asarray(theta["branch_amplitude"], float)).ravel()
        ell = np.atleast_1d(np.asarray(theta["length"], float)).ravel()
        w = amp.size
        _, wu = sine_basis(np.zeros(1), self.n_input)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            log_s = log_se_spectrum(wu, ell)[:, :, None]  # (W, m_u, 1)
            if self.has_rate:
                _, wr = sine_basis(np.zeros(1), self.n_rate)
                ell_r = np.atleast_1d(np.asarray(theta["rate_length"], float)).ravel()
                log_s = log_s + log_se_spectrum(wr, ell_r)[:, None, :]
            root = np.exp(0.5 * log_s).reshape(w, -1)
            return np.concatenate([amp[:, None] * root, amp_b[:, None] * root], axis=1)

    def coefficients(self, theta: Mapping[str, Any]) -> np.ndarray:
        """Basis coefficients ``s * xi`` (W, m)."""
        xi = np.asarray(theta["xi"], float).reshape(-1, self.size)
        return self.column_scale(theta) * xi

    def fingerprint(self) -> str:
        """What this discrepancy is, as 16 hex digits: scalings, basis sizes, constraint.

        Two discrepancies built on the same data at different anchors have the same
        parameter space but different bases; a fit's identity (and so its checkpoint)
        must tell them apart. The constraint enters through its projector ``V V^T``,
        which does not depend on the signs or order the SVD gave the directions.
        """
        h = hashlib.sha256(repr((self.n_input, self.n_rate, self.u_centre, self.u_half,
                                 self.rate_centre, self.rate_half, self.y_span)).encode())
        if self.constraint is not None and self.constraint.shape[1]:
            proj = self.constraint @ self.constraint.T
            h.update((np.round(proj, 10) + 0.0).tobytes())  # + 0.0: no -0.0 bytes
        return h.hexdigest()[:16]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (what summary.json records)."""
        return {"kind": "hsgp", "basis_functions": self.size, "input_basis": self.n_input,
                "rate_basis": self.n_rate, "input_centre": self.u_centre,
                "input_half_range": self.u_half,
                "rate_log10_hz": ([self.rate_centre - self.rate_half,
                                   self.rate_centre + self.rate_half] if self.has_rate else None),
                "amplitude_prior_sd": _AMPLITUDE_SHARE * self.y_span}


def make_discrepancy(kind: str | Discrepancy | None, data: Any) -> Discrepancy | None:
    """``None`` for ``"none"``/None, :meth:`Discrepancy.for_data` for ``"hsgp"``; else an error.

    ``"hsgp"`` here is kept off ``[1, u_n]`` only; :func:`~bayeshyst.inference.
    discrepancy_fit.attach_discrepancy` adds the model's sensitivities at its MAP.
    """
    if kind is None or isinstance(kind, Discrepancy):
        return kind
    if kind == "none":
        return None
    if kind == "hsgp":
        return Discrepancy.for_data(data)
    raise ParameterError(f"discrepancy must be one of {DISCREPANCY_KINDS}, got {kind!r}")
