"""Files of rigs that are not piezo stages, read as a new user would read them.

Each file is written here the way another lab's instrument would export it (its own
column names, its own units, its own sampling) from a simulated physical record whose
truth is known: the excitation it was driven with, the units it was written in. The
oracle is that truth: the reader must keep the units (converted by their SI factors
or kept as written), classify the excitation as it was made (a random drive is never
cut into cycles, one closed loop is one cycle) and say nothing false about the data
(no "time in ms read as s?" on a quasi-static magnet).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bayeshyst.cli.commands import load_data
from bayeshyst.cli.parser import build_parser
from bayeshyst.data.dataset import Dataset
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.predict import predict_posterior


def _write(path, header, columns):
    rows = "\n".join(",".join(f"{float(v):.12g}" for v in row)
                     for row in zip(*columns, strict=True))
    path.write_text(",".join(header) + "\n" + rows + "\n")
    return path


def _read(path, capsys, *extra):
    args = build_parser().parse_args(["fit", str(path), "--model", "pi_play", *extra])
    data = load_data(args)
    return data, capsys.readouterr().err


def _band_limited(n, fs, lo, hi, seed):
    rng = np.random.default_rng(seed)
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n, 1 / fs)
    spec[(f < lo) | (f > hi)] = 0
    x = np.fft.irfft(spec, n)
    return x / np.std(x)


def _damper_force(x_mm, fs):
    # a viscous term and a smooth Coulomb-like term of the velocity (N)
    v = np.gradient(x_mm, 1 / fs)
    return 2.0 * v + 400.0 * np.tanh(v / 20.0)


@pytest.mark.parametrize("seed", range(4))
def test_a_random_drive_damper_is_read_whole_in_its_units(tmp_path, capsys, seed):
    fs, n = 500.0, 2000
    x = 5.0 * _band_limited(n, fs, 1.0, 20.0, seed)
    path = _write(tmp_path / "damper.csv", ["Time [s]", "Displacement [mm]", "Force [N]"],
                  [np.arange(n) / fs, x, _damper_force(x, fs)])
    data, err = _read(path, capsys)
    (rec,) = data  # never cut into fake cycles
    assert rec.frequency_hz is None and rec.metadata["excitation"] == "broadband"
    lo, hi = rec.metadata["band_hz"]
    assert lo <= 2.0 and 15.0 <= hi <= 40.0
    assert dict(rec.units) == {"t": "s", "u": "um", "y": "N"}
    np.testing.assert_allclose(rec.u, 1e3 * x, rtol=1e-9, atol=1e-9)
    assert "warning" not in err and "broadband" in err and "kept whole" in err


def test_a_quasi_static_magnet_is_valid_data(tmp_path, capsys):
    # a hysteresisgraph stepping H slowly: 0.34 Hz sampling, three loops, 300 points
    n, fs = 300, 0.34
    t = np.arange(n) / fs
    phase = 2 * np.pi * 3 * np.arange(n) / n
    h = 5000.0 * np.sin(phase)
    b = 1.4 * np.tanh((h - 600.0 * np.sign(np.cos(phase))) / 1500.0)
    path = _write(tmp_path / "magnet.csv", ["t [s]", "H [kA/m]", "B [mT]"],
                  [t, h / 1e3, b * 1e3])
    data, err = _read(path, capsys)
    (rec,) = data
    assert dict(rec.units) == {"t": "s", "u": "A/m", "y": "T"}
    np.testing.assert_allclose(rec.u, h, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(rec.y, b, rtol=1e-9, atol=1e-12)
    assert rec.metadata["excitation"] == "periodic"
    assert rec.frequency_hz == pytest.approx(3 / (n / fs), rel=0.02)
    assert "warning" not in err and "ms read as s" not in err


def test_one_measured_b_h_loop_is_one_cycle(tmp_path, capsys):
    n = 129
    phase = np.linspace(0, 2 * np.pi, n)
    h = 8000.0 * np.cos(phase)  # H max -> min -> max
    b = 1.2 * np.tanh((h + 800.0 * np.sign(-np.sin(phase))) / 2000.0)
    t = np.arange(n) * 2.0
    path = _write(tmp_path / "bh.csv", ["Time [s]", "H [Oe]", "BL [T]"],
                  [t, h / (1000 / (4 * np.pi)), b])
    data, err = _read(path, capsys)
    (rec,) = data
    assert dict(rec.units) == {"t": "s", "u": "A/m", "y": "T"}
    np.testing.assert_allclose(rec.u, h, rtol=1e-9, atol=1e-6)
    assert rec.metadata["excitation"] == "periodic"
    assert rec.frequency_hz == pytest.approx(1 / (t[-1] - t[0]), rel=0.01)
    assert "one closed loop" in err and "0 whole" not in err and "warning" not in err


def test_a_bipolar_pzt_disc_keeps_its_field_and_strain_units(tmp_path, capsys):
    # a butterfly: strain (%) against a bipolar field (kV/mm), 1 Hz, two cycles, 1 kHz
    t = np.arange(2000) / 1000.0
    e = 2.0 * np.sin(2 * np.pi * t)
    s = 0.12 * np.abs(np.tanh((e - 0.9 * np.sign(np.cos(2 * np.pi * t))) / 0.5)) * np.abs(e)
    path = _write(tmp_path / "pzt.csv", ["t [ms]", "E [kV/mm]", "S [%]"], [1e3 * t, e, s])
    data, err = _read(path, capsys)
    (rec,) = data
    assert dict(rec.units) == {"t": "s", "u": "kV/mm", "y": "%"}
    np.testing.assert_allclose(rec.t, t, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(rec.y, np.array([float(f"{v:.12g}") for v in s]))
    assert rec.metadata["excitation"] == "periodic" and rec.frequency_hz == pytest.approx(1.0)
    assert "warning" not in err


def test_a_long_creep_hold_is_kept_whole_without_warnings(tmp_path, capsys):
    # steps with holds over 1 400 s sampled at 3.6 Hz: creep data, not a cycle in sight
    fs = 3.6
    t = np.arange(int(1400 * fs)) / fs
    u = np.where(t < 200, 0.0, np.where(t < 900, 100.0, 40.0))
    y = 0.1 * u + 0.8 * np.log1p(np.clip(t - 200, 0, None) / 5.0) * (t >= 200)
    path = _write(tmp_path / "creep.csv", ["Time [min]", "Voltage [V]", "Position [nm]"],
                  [t / 60.0, u, 1e3 * y])
    data, err = _read(path, capsys)
    (rec,) = data
    assert dict(rec.units) == {"t": "s", "u": "V", "y": "um"}
    np.testing.assert_allclose(rec.t, t, rtol=1e-9, atol=1e-6)
    assert rec.frequency_hz is None and rec.metadata["excitation"] == "broadband"
    assert "warning" not in err


def test_a_fit_on_one_random_drive_predicts_another_of_the_same_rig(tmp_path, capsys):
    fs, n = 500.0, 1500
    recs = []
    for seed in (11, 12):
        x = 5.0 * _band_limited(n, fs, 1.0, 10.0, seed)
        f = _damper_force(x, fs) + np.random.default_rng(seed).normal(0, 5.0, n)
        path = _write(tmp_path / f"d{seed}.csv", ["t [s]", "x [mm]", "F [N]"],
                      [np.arange(n) / fs, x, f])
        (rec,) = _read(path, capsys)[0]
        recs.append(rec)
    post = Posterior(Dataset([recs[0]], name="train"), "pi_play(n_operators=4)")
    z = find_map(post, seed=0, global_search=False, n_screen=32, n_starts=1).z[None, :]
    got = predict_posterior(post, np.repeat(z, 3, axis=0), recs[1])
    # the record predicted is the other drive, in the fit's units, kept whole
    assert [r.name for r in got.records] == ["d12"] and got.units["y"] == "N"
    assert got.records[0].group.startswith("band ") and got.records[0].scored.all()
    theta = post.space.unpack(z)
    one = {k: np.asarray(theta[k])[0] for k in post.model_space.all_names}
    sim = post.model.simulate(recs[1].u, recs[1].t, one) + float(
        np.asarray(theta["obs.offset"])[0])
    e = recs[1].y - sim
    assert abs(got.overall.rmse - np.sqrt(np.mean(e**2))) <= 1e-9 * np.ptp(recs[1].y)


def test_a_fit_of_a_random_drive_says_its_held_out_units_are_time_blocks(tmp_path, capsys):
    import json

    from bayeshyst.cli import main
    from bayeshyst.inference.posterior import cycle_units

    fs, n = 500.0, 2000
    x = 5.0 * _band_limited(n, fs, 1.0, 20.0, 3)
    path = _write(tmp_path / "damper.csv", ["Time [s]", "Displacement [mm]", "Force [N]"],
                  [np.arange(n) / fs, x, _damper_force(x, fs)])
    (rec,) = _read(path, capsys)[0]
    spans = cycle_units(rec)
    # contiguous blocks that partition the scored samples, none a fake cycle
    assert len(spans) >= 2 and spans[0][0] == rec.warmup and spans[-1][1] == rec.n
    assert all(a[1] == b[0] for a, b in itertools.pairwise(spans))
    out = tmp_path / "fit"
    assert main(["fit", str(path), "--model", "pi_play(n_operators=3)", "--steps", "200",
                 "--no-figures", "--quiet", "--out", str(out)]) == 0
    (saved,) = json.loads((out / "summary.json").read_text())["data"]["records"]
    assert saved["excitation"] == "broadband" and saved["frequency_hz"] is None
    assert saved["loo_units"] == f"{len(spans)} time blocks"
    assert saved["group"] == rec.group and saved["group"].startswith("band ")
