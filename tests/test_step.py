"""One-sample steps reproduce whole-record simulation, for every family and compositions."""

from __future__ import annotations

import numpy as np
import pytest

import bayeshyst.models as M

SPECS = ["pi_play", "pi_rate", "preisach", "maxwell_slip", "bouc_wen", "duhem_improved",
         "mbw", "pi_play+second_order+creep", "bouc_wen+arx+delay"]


@pytest.mark.parametrize("spec", SPECS)
def test_stepping_sample_by_sample_equals_one_run(spec):
    model = M.get(spec)
    t = np.arange(300) * 1e-4
    u = np.sin(2 * np.pi * 50 * t) * np.exp(-5 * t)
    space = model.param_space()
    rng = np.random.default_rng(3)
    for _ in range(50):  # a draw inside the model's stable region
        theta = space.unpack(space.sample_prior(rng, 1)[0])
        traj = model.run_batch(u, t, {k: np.asarray(v)[None] for k, v in theta.items()})
        if not traj.failed[0]:
            break
    whole = model.run(u, t, theta)
    state = model.initial_state(theta, u[0])
    ys = []
    for k in range(u.size):
        out = model.step(u[k], t[k], theta, state)
        ys.append(out.y[0])
        state = out.state
    # bit for bit, except Bouc-Wen's cached |h|^n, recomputed at a piece boundary
    np.testing.assert_allclose(ys, whole.y, rtol=0, atol=1e-12 * np.ptp(whole.y))
    np.testing.assert_allclose(state, whole.state, rtol=1e-12, atol=1e-12)
