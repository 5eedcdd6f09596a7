"""Synthetic records with a known truth, shared by the inference tests."""

from __future__ import annotations

import numpy as np

import bayeshyst.models as M
from bayeshyst.data import Record
from bayeshyst.models.base import DataScales

__all__ = ["pi_data"]


def pi_data(n_ops=3, n=1500, sigma=0.05, seed=0, warmup=150, offset=0.4):
    model = M.get("pi_play", n_operators=n_ops)
    t = np.arange(n) * 1e-3
    u = 75 + 70 * np.sin(2 * np.pi * 3 * t) * np.exp(-0.5 * t)
    r = model.param_space(DataScales(float(u.min()), float(u.max()), 0.0, 20.0)).fixed["r"]
    theta = {"p0": 0.1, "w": np.linspace(0.05, 0.02, n_ops), "r": r}
    y = model.simulate(u, t, theta) + offset
    y = y + np.random.default_rng(seed).normal(0.0, sigma, n)
    rec = Record(t=t, u=u, y=y, name="pi", warmup=warmup, metadata={"frequency_hz": 3.0})
    return model, rec, theta
