"""bayeshyst export: a saved fit's inverse as JSON, C99 and tables, replayed.

Oracles: the play-PI's closed-form inverse in Python (Kuhnen) and the MAP model driven
forward by the command; the C code compiled with the system compiler and fed the same
reference must give the Python replay's numbers; on the major loop the branch tables
are exact up to their linear interpolation.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from bayeshyst import diagnostics
from bayeshyst.cli import main
from bayeshyst.data.dataset import Dataset
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.saved import load_fit
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.export import export_inverse
from bayeshyst.models import get as get_model
from bayeshyst.models.compose import Composite
from tests.synthetic import pi_data

CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
MAIN = ('#include <stdio.h>\n#include "bh_inverse.h"\nint main(void) { bh_state s; double y; '
        'bh_reset(&s); while (scanf("%lf", &y) == 1) printf("%.17g\\n", bh_step(&s, y)); '
        'return 0; }\n')


def _saved(tmp, spec):
    tmp.mkdir(parents=True, exist_ok=True)
    _, rec, _ = pi_data(n_ops=3, n=900, warmup=100)
    post = Posterior(Dataset((rec,), name="bench"), spec)
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    res = sample_posterior(post, SamplerSettings(seed=2, max_steps=300, first_chunk=100),
                           start=start)
    diagnostics.save_netcdf(diagnostics.to_inference_data(post, res, draws_per_chain=4,
                                                          n_predictive=5), tmp / "posterior.nc")
    return load_fit(tmp)


@pytest.fixture(scope="module")
def play(tmp_path_factory):
    return _saved(tmp_path_factory.mktemp("play"), "pi_play(n_operators=3)")


@pytest.fixture(scope="module")
def stop(tmp_path_factory):
    return _saved(tmp_path_factory.mktemp("stop"), "pi_stop(n_operators=3)")


def _reference(fit, n=2400, fs=2000.0):
    # a loop with minor loops inside the fitted output range, from rest at its bottom
    lo, hi = np.quantile(fit.data[0].y, [0.15, 0.85])
    t = np.arange(n) / fs
    y = lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * 3 * t)) * (0.7 + 0.3 * np.cos(
        2 * np.pi * 0.7 * t))
    return t, y


def _compile_and_run(tmp, export, y):
    header, source = export.c_code("bh")
    (tmp / "bh_inverse.h").write_text(header)
    (tmp / "bh_inverse.c").write_text(source)
    (tmp / "main.c").write_text(MAIN)
    build = subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-pedantic", "-Werror",
                            "-o", str(tmp / "run"), str(tmp / "main.c"),
                            str(tmp / "bh_inverse.c"), "-lm"], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    run = subprocess.run([str(tmp / "run")], input="\n".join(repr(float(v)) for v in y),
                         capture_output=True, text=True, check=True)
    return np.array([float(v) for v in run.stdout.split()])


@pytest.mark.skipif(CC is None, reason="no C compiler (cc, gcc or clang) on this machine")
def test_the_c_play_pi_inverse_is_the_closed_form_inverse(play, tmp_path):
    ex = export_inverse(play)
    assert ex.method == "play_pi" and ex.dynamics == ()
    t, y = _reference(play)
    u_c = _compile_and_run(tmp_path, ex, y)
    theta, offset = play.posterior.model_draws(play.map_z[None, :])
    one = {k: np.asarray(v)[0] for k, v in theta.items()}
    u_exact = play.model.inverse(y - offset[0], t, one)  # Kuhnen's inverse in Python
    span = np.ptp(u_exact)
    assert np.max(np.abs(u_c - u_exact)) <= 1e-9 * span
    np.testing.assert_array_equal(u_c, ex.apply(y))  # the same arithmetic, bit for bit
    # and the MAP model, driven by the C command, follows the reference
    y_back = play.model.simulate(u_c, t, one) + offset[0]
    assert np.max(np.abs(y_back - y)) <= 1e-9 * np.ptp(y)


@pytest.mark.skipif(CC is None, reason="no C compiler (cc, gcc or clang) on this machine")
def test_the_c_mbw_inverse_is_the_closed_form_inverse(tmp_path):
    mbw = _saved(tmp_path / "fit", "mbw")
    ex = export_inverse(mbw)
    assert ex.method == "mbw"
    t, y = _reference(mbw)
    u_c = _compile_and_run(tmp_path, ex, y)
    theta, offset = mbw.posterior.model_draws(mbw.map_z[None, :])
    one = {k: np.asarray(v)[0] for k, v in theta.items()}
    u_exact = mbw.model.inverse(y - offset[0], t, one)  # review Eq. 55 in Python
    assert np.max(np.abs(u_c - u_exact)) <= 1e-9 * np.ptp(u_exact)
    np.testing.assert_allclose(u_c, ex.apply(y), rtol=0, atol=1e-12 * np.ptp(u_exact))


@pytest.mark.skipif(CC is None, reason="no C compiler (cc, gcc or clang) on this machine")
def test_the_c_table_inverse_replays_python_and_is_exact_on_the_major_loop(stop, tmp_path):
    ex = export_inverse(stop)
    assert ex.method == "table"
    p = ex.parameters
    # a major loop between the tables' common ends, starting at its bottom
    y_lo, y_hi = max(p["y_up"][0], p["y_down"][0]), min(p["y_up"][-1], p["y_down"][-1])
    t = np.arange(3000) / 1000.0
    y = y_lo + (y_hi - y_lo) * 0.5 * (1 - np.cos(2 * np.pi * 1.0 * t))
    u_c = _compile_and_run(tmp_path, ex, y)
    np.testing.assert_allclose(u_c, ex.apply(y), rtol=0, atol=1e-12 * np.ptp(u_c))
    # after the first rise the command runs the tabulated branches: the model driven by
    # it reproduces the reference up to the tables' linear interpolation
    theta, offset = stop.posterior.model_draws(stop.map_z[None, :])
    one = {k: np.asarray(v)[0] for k, v in theta.items()}
    y_back = stop.model.simulate(u_c, t, one) + offset[0]
    later = t >= 0.5
    assert np.max(np.abs(y_back - y)[later]) <= 2e-3 * np.ptp(y)


def test_linear_dynamics_are_split_off_and_a_bad_method_refused(play, stop):
    from bayeshyst.errors import ModelError
    from bayeshyst.inverse.export import _split_dynamics

    def prior_theta(model):
        space = model.param_space()
        return space.unpack(space.sample_prior(np.random.default_rng(0), 1)[0])

    model = get_model("pi_play+asym_output+second_order+delay")
    theta = prior_theta(model)
    head, head_theta, dyn = _split_dynamics(model, theta)
    assert isinstance(head, Composite) and [b.name for b in head.blocks] == ["asym_output"]
    assert [d["block"] for d in dyn] == ["second_order", "delay"]
    # the head keeps the full model's parameter names; each block's come without prefix
    assert set(head_theta) == {k for k in theta if k.split(".")[0] in ("static", "asym_output")}
    assert dyn[1]["parameters"] == {"d": float(theta["delay.d"])}
    bw = get_model("bouc_wen")
    head, head_theta, dyn = _split_dynamics(bw, prior_theta(bw))
    assert head.name == "bouc_wen" and dyn == []
    table = export_inverse(play, method="table")  # a play-PI tabulated, on request
    assert table.method == "table" and table.parameters["y_up"].size == 512
    with pytest.raises(ModelError, match=r"\(pi_stop\) is not a play-PI"):
        export_inverse(stop, method="play_pi")


def test_export_cli_writes_every_format_and_refuses_bad_input(play, tmp_path, capsys):
    t, y = _reference(play)
    ref = tmp_path / "ref.csv"
    ref.write_text("t,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n"
                                     for a, b in zip(t, y, strict=True)))
    for fmt, files in (("json", {"inverse.json"}),
                       ("c", {"inverse.json", "bh_inverse.h", "bh_inverse.c"}),
                       ("table", {"inverse.json", "inverse_table.csv"})):
        out = tmp_path / fmt
        assert main(["export", str(play.path), "--format", fmt, "--reference", str(ref),
                     "--out", str(out), "--quiet"]) == 0
        assert files | {"replay.csv", "summary.json"} == {p.name for p in out.iterdir()}
        s = json.loads((out / "summary.json").read_text())
        error = s["replay"]["error_percent_of_command_span"]
        if fmt == "table":  # tabulated on request: approximate inside the major loop
            assert s["method"] == "table" and 0 < error < 100
        else:
            assert s["method"] == "play_pi" and error < 1e-6
    capsys.readouterr()
    assert main(["export", str(play.path), "--prefix", "1bad", "--out",
                 str(tmp_path / "bad"), "--quiet"]) == 2
    assert "C identifier" in capsys.readouterr().err and not (tmp_path / "bad").exists()
