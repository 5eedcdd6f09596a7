"""An inverse for a real-time controller: JSON parameters and dependency-free C99.

:func:`export_inverse` turns a saved fit (:func:`~bayeshyst.inference.saved.load_fit`)
into an :class:`InverseExport` at its MAP:

* ``method="play_pi"`` -- the model's hysteresis is a play-PI: its exact inverse is again
  a play-PI (Kuhnen 2003, review ref. [52]; :func:`~bayeshyst.models.pi.play_pi_inverse`),
  ``u = p0' v + sum_i w'_i F_{r'_i}[v]`` with ``v = y_d - offset``;
* ``method="mbw"`` -- the modified Bouc–Wen (review ref. [99]) of polynomial order <= 2:
  its closed-form inverse, Eq. 55 (:meth:`~bayeshyst.models.modified_bouc_wen.ModifiedBoucWen.
  inverse`): the output polynomial's root, then the inverse MBW operator solved exactly
  on every monotone step;
* ``method="table"`` -- any other rate-independent model: its major loop's ascending and
  descending branches tabulated as monotone ``y -> u`` tables. After a reversal at
  ``(y_r, u_r)`` the command follows the new branch blended linearly so that it starts
  at ``u_r`` and meets the branch at the table's far end (continuous at every reversal;
  exact on the major loop, approximate inside it -- :attr:`InverseExport.table_error_percent`
  says how far, against the exact numerical inverse on a reference).

Linear dynamics after the hysteresis (``second_order``, ``arx``, ``delay``) are exported
as their parameters (``dynamics``): their stable inverse is non-causal (it needs the
reference ahead, :mod:`bayeshyst.inverse.lti`), so a controller applies it to the
reference before the hysteresis inverse, with the preview it has. The C code implements
the hysteresis inverse sample by sample with a fixed-size state and no allocation; its
arithmetic is written in the same order as :meth:`InverseExport.apply`, the Python
reference the tests replay it against.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.inference.saved import SavedFit
from bayeshyst.inverse.references import U_MARGIN, command_limits
from bayeshyst.models.compose import Composite, block_namespaces, leading_part, model_spec
from bayeshyst.models.modified_bouc_wen import ModifiedBoucWen
from bayeshyst.models.pi import PrandtlIshlinskii, play_pi_inverse
from bayeshyst.params import ParamSpace
from bayeshyst.tables import TableRecord

__all__ = ["EXPORT_FORMAT", "InverseExport", "export_inverse", "replay_error"]

#: version of the exported JSON layout
EXPORT_FORMAT = 1
#: points per branch table
TABLE_POINTS = 512


def _c_array(values: np.ndarray) -> str:
    return "{" + ", ".join(f"{float(v):.17g}" for v in np.asarray(values).ravel()) + "}"


@dataclass(frozen=True)
class InverseExport(TableRecord):
    """A fit's inverse, ready for a controller (see the module docstring).

    Attributes
    ----------
    model : str
        The fitted model's spec string.
    method : {"play_pi", "mbw", "table"}
    parameters : dict of str to ndarray or float
        ``play_pi``: ``p0`` (V per output unit), ``w`` (n,), ``r`` (n,, output unit),
        ``offset`` (output unit); ``mbw``: ``c1``, ``c2`` (0 for order 1), ``rho``,
        ``lam``, ``offset``; ``table``: ``y_up``, ``u_up``, ``y_down``, ``u_down``
        (each (TABLE_POINTS,), strictly increasing ``y``).
    dynamics : tuple of dict
        Linear dynamics after the hysteresis: ``{"block": name, "parameters": {...}}``.
    u_limits : (float, float)
        The command range the inverse was built for (input unit).
    units : dict
        ``u`` and ``y`` units.
    fit_converged : bool
    notes : tuple of str
    """

    model: str
    method: str
    parameters: dict[str, Any] = field(repr=False)
    dynamics: tuple[dict[str, Any], ...]
    u_limits: tuple[float, float]
    units: dict[str, str]
    fit_converged: bool
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The JSON export (``inverse.json``)."""
        params = {k: (np.asarray(v).tolist() if np.ndim(v) else float(v))
                  for k, v in self.parameters.items()}
        return {"format": EXPORT_FORMAT, "model": self.model, "method": self.method,
                "parameters": params, "dynamics": list(self.dynamics),
                "u_limits": list(self.u_limits), "units": dict(self.units),
                "fit_converged": self.fit_converged, "notes": list(self.notes)}

    def to_dataframe(self) -> Any:
        """The inverse's numbers: per operator (``w``, ``r``) or per table point."""
        import pandas as pd

        p = self.parameters
        if self.method == "play_pi":
            return pd.DataFrame({"operator": np.arange(1, np.size(p["w"]) + 1),
                                 "w": p["w"], "r": p["r"]})
        return pd.DataFrame({k: p[k] for k in ("y_up", "u_up", "y_down", "u_down")})

    def __str__(self) -> str:
        what = {"play_pi": "exact play-PI inverse", "mbw": "exact MBW inverse (Eq. 55)",
                "table": "branch tables with blended reversals"}[self.method]
        lines = [f"inverse of {self.model}: {what}"
                 + ("; dynamics to invert upstream: "
                    + ", ".join(d["block"] for d in self.dynamics) if self.dynamics else "")]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    # ------------------------------------------------------------------ Python replay
    def apply(self, y_d: Any) -> np.ndarray:
        """The command for ``y_d`` (N,), sample by sample, as the C code computes it."""
        y = np.asarray(y_d, dtype=float).ravel()
        u = np.empty_like(y)
        p = self.parameters
        if self.method == "play_pi":
            w, r = np.asarray(p["w"], float), np.asarray(p["r"], float)
            state = np.empty(w.size)
            for k in range(y.size):
                v = y[k] - p["offset"]
                if k == 0:
                    state[:] = v
                acc = p["p0"] * v
                for i in range(w.size):
                    lo, hi = v - r[i], v + r[i]
                    vi = state[i]
                    vi = lo if vi < lo else (hi if vi > hi else vi)
                    state[i] = vi
                    acc += w[i] * vi
                u[k] = acc
            return u
        if self.method == "mbw":
            half = (1.0 / p["rho"] - 1.0) / p["lam"]
            wp = up_ = 0.0
            for k in range(y.size):
                v = y[k] - p["offset"]
                w = 2.0 * v / (p["c1"] + math.sqrt(p["c1"] * p["c1"] + 4.0 * p["c2"] * v))
                if k == 0:
                    wp, up_ = w, w
                dw = w - wp
                if dw != 0.0:
                    a = math.copysign(half, dw)
                    up_ = w + a + (up_ - wp - a) * math.exp(-p["lam"] * abs(dw))
                u[k] = up_
                wp = w
            return u
        up = (np.asarray(p["y_up"], float), np.asarray(p["u_up"], float))
        down = (np.asarray(p["y_down"], float), np.asarray(p["u_down"], float))
        y_lo, y_hi = max(up[0][0], down[0][0]), min(up[0][-1], down[0][-1])
        branch, y_prev, y_r, u_r = 1, 0.0, 0.0, 0.0
        for k in range(y.size):
            yk = min(max(y[k], y_lo), y_hi)
            if k == 0:
                # relaxed start: midway between the branches
                u_r = 0.5 * (_interp(up, yk) + _interp(down, yk))
                y_r, y_prev = yk, yk
            elif (yk > y_prev and branch < 0) or (yk < y_prev and branch > 0):
                # a reversal at the previous sample: the new branch starts there
                y_r, u_r = y_prev, u[k - 1]
                branch = -branch
            u[k] = _blend(up if branch > 0 else down, branch, yk, y_r, u_r, y_lo, y_hi)
            y_prev = yk
        return u

    # ------------------------------------------------------------------ C99
    def c_code(self, prefix: str = "bh") -> tuple[str, str]:
        """``(header, source)`` of a C99 implementation of :meth:`apply`.

        The API: ``<prefix>_state``, ``<prefix>_reset(&s)``, ``double
        <prefix>_step(&s, double y_desired)`` -> the command; no allocation, no library
        beyond the C standard headers.
        """
        if not prefix.isidentifier():
            raise ParameterError(f"prefix must be a C identifier, got {prefix!r}")
        P = prefix.upper()
        guard = f"{P}_INVERSE_H"
        head = [f"/* Inverse of {self.model} exported by bayeshyst ({self.method}).",
                f"   Input of {prefix}_step: desired output [{self.units.get('y', '')}];",
                f"   returns the command [{self.units.get('u', '')}]. */",
                f"#ifndef {guard}", f"#define {guard}", ""]
        p = self.parameters
        if self.method == "play_pi":
            n = int(np.size(p["w"]))
            head += [f"#define {P}_N_OPERATORS {n}",
                     f"typedef struct {{ double v[{P}_N_OPERATORS]; int started; }} "
                     f"{prefix}_state;"]
            body = [f"static const double {P}_P0 = {float(p['p0']):.17g};",
                    f"static const double {P}_OFFSET = {float(p['offset']):.17g};",
                    f"static const double {P}_W[{P}_N_OPERATORS] = {_c_array(p['w'])};",
                    f"static const double {P}_R[{P}_N_OPERATORS] = {_c_array(p['r'])};",
                    "",
                    f"void {prefix}_reset({prefix}_state *s) {{ s->started = 0; }}",
                    "",
                    f"double {prefix}_step({prefix}_state *s, double y_desired)",
                    "{",
                    f"    double v = y_desired - {P}_OFFSET;",
                    f"    double acc = {P}_P0 * v;",
                    "    int i;",
                    "    if (!s->started) {",
                    f"        for (i = 0; i < {P}_N_OPERATORS; ++i) s->v[i] = v;",
                    "        s->started = 1;",
                    "    }",
                    f"    for (i = 0; i < {P}_N_OPERATORS; ++i) {{",
                    f"        double lo = v - {P}_R[i], hi = v + {P}_R[i], vi = s->v[i];",
                    "        vi = vi < lo ? lo : (vi > hi ? hi : vi);",
                    "        s->v[i] = vi;",
                    f"        acc += {P}_W[i] * vi;",
                    "    }",
                    "    return acc;",
                    "}"]
        elif self.method == "mbw":
            head += [f"typedef struct {{ double w_prev, u_prev; int started; }} {prefix}_state;"]
            body = ["#include <math.h>", "",
                    *[f"static const double {P}_{k.upper()} = {float(p[k]):.17g};"
                      for k in ("c1", "c2", "rho", "lam", "offset")],
                    "",
                    f"void {prefix}_reset({prefix}_state *s) {{ s->started = 0; }}",
                    "",
                    f"double {prefix}_step({prefix}_state *s, double y_desired)",
                    "{",
                    f"    double half = (1.0 / {P}_RHO - 1.0) / {P}_LAM;",
                    f"    double v = y_desired - {P}_OFFSET;",
                    f"    double w = 2.0 * v / ({P}_C1 + sqrt({P}_C1 * {P}_C1 + 4.0 * {P}_C2 "
                    "* v));",
                    "    double dw;",
                    "    if (!s->started) { s->w_prev = w; s->u_prev = w; s->started = 1; }",
                    "    dw = w - s->w_prev;",
                    "    if (dw != 0.0) {",
                    "        double a = copysign(half, dw);",
                    f"        s->u_prev = w + a + (s->u_prev - s->w_prev - a) * exp(-{P}_LAM "
                    "* fabs(dw));",
                    "    }",
                    "    s->w_prev = w;",
                    "    return s->u_prev;",
                    "}"]
        else:
            m = int(np.size(p["y_up"]))
            head += [f"#define {P}_TABLE_POINTS {m}",
                     f"typedef struct {{ int branch, started; double y_prev, y_r, u_r, "
                     f"u_prev; }} {prefix}_state;"]
            body = [f"static const double {P}_Y_UP[{P}_TABLE_POINTS] = {_c_array(p['y_up'])};",
                    f"static const double {P}_U_UP[{P}_TABLE_POINTS] = {_c_array(p['u_up'])};",
                    f"static const double {P}_Y_DOWN[{P}_TABLE_POINTS] = "
                    f"{_c_array(p['y_down'])};",
                    f"static const double {P}_U_DOWN[{P}_TABLE_POINTS] = "
                    f"{_c_array(p['u_down'])};",
                    "",
                    "static double interp(const double *ys, const double *us, double y)",
                    "{",
                    f"    int lo = 0, hi = {P}_TABLE_POINTS - 1;",
                    "    double f;",
                    "    if (y <= ys[0]) return us[0];",
                    "    if (y >= ys[hi]) return us[hi];",
                    "    while (hi - lo > 1) { int mid = (lo + hi) / 2; "
                    "if (ys[mid] <= y) lo = mid; else hi = mid; }",
                    "    f = (y - ys[lo]) / (ys[hi] - ys[lo]);",
                    "    return us[lo] + f * (us[hi] - us[lo]);",
                    "}",
                    "",
                    f"void {prefix}_reset({prefix}_state *s) {{ s->started = 0; "
                    "s->branch = 1; }",
                    "",
                    f"double {prefix}_step({prefix}_state *s, double y_desired)",
                    "{",
                    f"    double y_lo = {P}_Y_UP[0] > {P}_Y_DOWN[0] ? {P}_Y_UP[0] : "
                    f"{P}_Y_DOWN[0];",
                    f"    double y_hi = {P}_Y_UP[{P}_TABLE_POINTS - 1] < "
                    f"{P}_Y_DOWN[{P}_TABLE_POINTS - 1] ? {P}_Y_UP[{P}_TABLE_POINTS - 1] : "
                    f"{P}_Y_DOWN[{P}_TABLE_POINTS - 1];",
                    "    double y = y_desired < y_lo ? y_lo : (y_desired > y_hi ? y_hi : "
                    "y_desired);",
                    "    double base, at_r, u;",
                    "    if (!s->started) {",
                    f"        s->u_r = 0.5 * (interp({P}_Y_UP, {P}_U_UP, y) + "
                    f"interp({P}_Y_DOWN, {P}_U_DOWN, y));",
                    "        s->y_r = y; s->y_prev = y; s->branch = 1; s->started = 1;",
                    "    } else if ((y > s->y_prev && s->branch < 0) || "
                    "(y < s->y_prev && s->branch > 0)) {",
                    "        s->y_r = s->y_prev; s->u_r = s->u_prev; s->branch = -s->branch;",
                    "    }",
                    "    if (s->branch > 0) {",
                    f"        base = interp({P}_Y_UP, {P}_U_UP, y);",
                    f"        at_r = interp({P}_Y_UP, {P}_U_UP, s->y_r);",
                    "        u = y_hi > s->y_r ? base + (s->u_r - at_r) * (y_hi - y) / "
                    "(y_hi - s->y_r) : base;",
                    "    } else {",
                    f"        base = interp({P}_Y_DOWN, {P}_U_DOWN, y);",
                    f"        at_r = interp({P}_Y_DOWN, {P}_U_DOWN, s->y_r);",
                    "        u = s->y_r > y_lo ? base + (s->u_r - at_r) * (y - y_lo) / "
                    "(s->y_r - y_lo) : base;",
                    "    }",
                    "    s->y_prev = y; s->u_prev = u;",
                    "    return u;",
                    "}"]
        head += [f"void {prefix}_reset({prefix}_state *s);",
                 f"double {prefix}_step({prefix}_state *s, double y_desired);",
                 "", f"#endif /* {guard} */", ""]
        source = [f"/* Inverse of {self.model} exported by bayeshyst; see "
                  f"{prefix}_inverse.h. */", f'#include "{prefix}_inverse.h"', "", *body, ""]
        return "\n".join(head), "\n".join(source)


def _interp(table: tuple[np.ndarray, np.ndarray], y: float) -> float:
    ys, us = table
    if y <= ys[0]:
        return float(us[0])
    if y >= ys[-1]:
        return float(us[-1])
    lo, hi = 0, ys.size - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ys[mid] <= y:
            lo = mid
        else:
            hi = mid
    f = (y - ys[lo]) / (ys[hi] - ys[lo])
    return float(us[lo] + f * (us[hi] - us[lo]))


def _blend(table: tuple[np.ndarray, np.ndarray], branch: int, y: float, y_r: float,
           u_r: float, y_lo: float, y_hi: float) -> float:
    base, at_r = _interp(table, y), _interp(table, y_r)
    if branch > 0:
        return base + (u_r - at_r) * (y_hi - y) / (y_hi - y_r) if y_hi > y_r else base
    return base + (u_r - at_r) * (y - y_lo) / (y_r - y_lo) if y_r > y_lo else base


# ------------------------------------------------------------------------------ building
def _split_dynamics(model: Any, theta: Mapping[str, Any]
                    ) -> tuple[Any, dict[str, Any], list[dict[str, Any]]]:
    """The part before the trailing linear dynamics with its parameters, and those blocks.

    The trailing blocks are those whose inverse is non-causal (``needs_preview``); each
    is ``{"block": name, "parameters": {...}}``.
    """
    blocks = list(model.blocks) if isinstance(model, Composite) else []
    k = len(blocks)
    while k and blocks[k - 1].needs_preview:
        k -= 1
    head, head_theta = leading_part(model, k, theta)
    names = block_namespaces(blocks)
    dynamics = [{"block": b.name, "parameters": {
        key: np.asarray(v, float).tolist()
        for key, v in ParamSpace.sub_theta(theta, names[i]).items()}}
        for i, b in enumerate(blocks[k:], start=k)]
    return head, head_theta, dynamics


def export_inverse(fit: SavedFit, *, method: str = "auto",
                   u_margin: float = U_MARGIN) -> InverseExport:
    """The inverse of ``fit``'s model at its MAP (module docstring).

    Parameters
    ----------
    fit : SavedFit
    method : {"auto", "play_pi", "table"}
        ``auto``: the closed form where the hysteresis is a play-PI, else the tables.
    u_margin : float
        Tables span the fit's input range widened by this fraction of its span.

    Raises
    ------
    ModelError
        If the model's hysteresis part is rate-dependent and not a play-PI (no closed
        form and no branch table), or its branches are not monotone.
    """
    if method not in ("auto", "play_pi", "mbw", "table"):
        raise ParameterError(f"method must be auto, play_pi, mbw or table, got {method!r}")
    post = fit.posterior
    model = post.model
    theta, offset = post.model_draws(fit.map_z[None, :])
    theta1 = {k: np.asarray(v)[0] for k, v in theta.items()}
    off = float(offset[0])
    head, head_theta, dynamics = _split_dynamics(model, theta1)
    limits = command_limits(post.data, u_margin)
    units = {"u": post.data[0].units.get("u", ""), "y": post.data[0].units.get("y", "")}
    notes = []
    if not fit.converged:
        notes.append("the fit did NOT converge: this inverse is from an unreliable posterior")
    if post.discrepancy is not None:
        notes.append("the fit's model discrepancy is not in the exported inverse (it is "
                     "the model's alone); bayeshyst invert designs with it")
    if method == "mbw" and not (isinstance(head, ModifiedBoucWen) and head.order <= 2):
        raise ModelError(f"{model_spec(model)}: its hysteresis part ({head.name}) is not a "
                         "modified Bouc-Wen of order <= 2; no closed-form inverse to export "
                         "(use method='table')")
    if method == "play_pi" and not isinstance(head, PrandtlIshlinskii):
        raise ModelError(f"{model_spec(model)}: its hysteresis part ({head.name}) is not a "
                         "play-PI; no closed-form inverse to export (use method='table')")
    if isinstance(head, PrandtlIshlinskii) and method != "table":
        inv = play_pi_inverse(head_theta["p0"], head_theta["w"], head_theta["r"])
        params = {"p0": float(inv.p0), "w": np.asarray(inv.w, float),
                  "r": np.asarray(inv.r, float), "offset": off}
        return InverseExport(model_spec(model), "play_pi", params, tuple(dynamics), limits,
                             units, fit.converged, tuple(notes))
    if isinstance(head, ModifiedBoucWen) and head.order <= 2 and method != "table":
        params = {"c1": float(head_theta["c1"]),
                  "c2": float(head_theta["c2"]) if head.order == 2 else 0.0,
                  "rho": float(head_theta["rho"]), "lam": float(head_theta["lam"]),
                  "offset": off}
        if not (params["c1"] > 0 and 0 < params["rho"] < 2 and params["lam"] > 0):
            raise ModelError(f"{model_spec(model)}: the MAP has c1 = {params['c1']:.4g}, "
                             f"rho = {params['rho']:.4g}, lam = {params['lam']:.4g}: the "
                             "inverse needs c1 > 0, 0 < rho < 2, lam > 0")
        return InverseExport(model_spec(model), "mbw", params, tuple(dynamics), limits,
                             units, fit.converged, tuple(notes))
    if head.rate_dependent:
        raise ModelError(f"{model_spec(model)}: its hysteresis part ({head.name}) is "
                         "rate-dependent: no closed-form inverse and no branch table exist; "
                         "use bayeshyst invert for a command per reference")
    params = _branch_tables(head, head_theta, off, limits)
    notes.append("branch tables of the major loop: exact on it, approximate inside it "
                 "(reversals blended); bayeshyst export --reference reports the error")
    return InverseExport(model_spec(model), "table", params, tuple(dynamics), limits, units,
                         fit.converged, tuple(notes))


def _branch_tables(model: Any, theta: Mapping[str, Any], offset: float,
                   limits: tuple[float, float]) -> dict[str, np.ndarray]:
    lo, hi = limits
    n = TABLE_POINTS
    ramp = np.linspace(lo, hi, n)
    # two full cycles from the bottom (off the virgin curve), then the branches
    u = np.concatenate([ramp, ramp[::-1][1:], ramp[1:], ramp[::-1][1:]])
    t = np.arange(u.size) * 1e-3
    y = np.asarray(model.simulate(u, t, theta), float) + offset
    if not np.all(np.isfinite(y)):
        raise ModelError(f"{model.name}: the MAP model fails to simulate over the command "
                         f"range [{lo:.4g}, {hi:.4g}]")
    up_start = 2 * (n - 1)
    y_up, u_up = y[up_start:up_start + n], u[up_start:up_start + n]
    y_down, u_down = y[up_start + n - 1:][::-1], u[up_start + n - 1:][::-1]
    for name, ys in (("ascending", y_up), ("descending", y_down)):
        if not np.all(np.diff(ys) > 0):
            raise ModelError(f"{model.name}: its {name} branch is not strictly increasing "
                             "in the input over the command range: no monotone table")
    return {"y_up": y_up, "u_up": u_up, "y_down": y_down, "u_down": u_down}


def replay_error(export: InverseExport, exact_u: np.ndarray, y_d: np.ndarray) -> float:
    """Largest ``|u_export - u_exact|`` over ``y_d``, in % of the exact command's span."""
    u = export.apply(y_d)
    span = float(np.ptp(exact_u)) or 1.0
    return 100.0 * float(np.max(np.abs(u - np.asarray(exact_u, float)))) / span
