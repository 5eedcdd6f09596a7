"""``bayeshyst.data.working_rate``: the rate a record is fitted at, against oracles.

Oracles: a record whose noise-free signal is known (a sine with harmonics up to
``F_MAX``, white noise of known sd) decimated must keep ``F_MAX`` and equal the
noise-free signal at the kept time stamps within the filtered noise's bound; white
noise only above the excitation leaves the samples-per-cycle floor; a stepped input is
subsampled exactly; a record at about 100 samples per cycle, or ``full``, is unchanged.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from bayeshyst import models
from bayeshyst.cli import main
from bayeshyst.data import Dataset, Record, write_csv
from bayeshyst.data.spectral_edge import signal_edge
from bayeshyst.data.working_rate import (
    MARGIN,
    MIN_SAMPLES_PER_CYCLE,
    WorkingRate,
    to_working_rate,
)
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.models.base import DataScales

FS = 10_000.0  # Hz, the fast sampling of the synthetic records
F0 = 1.0  # Hz, excitation
F_MAX = 40.0  # Hz, highest harmonic of the output
SIGMA = 0.05  # white output noise
SEEDS = (0, 1, 2, 3, 4)


def _harmonics(t: np.ndarray) -> np.ndarray:
    """The noise-free output: harmonics 1..F_MAX/F0 of F0, amplitudes 1/h (0.025 at F_MAX)."""
    h = np.arange(1, int(F_MAX / F0) + 1)
    phases = np.linspace(0.0, np.pi, h.size)
    return np.sum(np.sin(2 * np.pi * F0 * h[:, None] * t[None, :] + phases[:, None]) / h[:, None],
                  axis=0)


def _record(y_clean, seed, *, duration=6.0, fs=FS, sigma=SIGMA, **kw) -> Record:
    t = np.arange(round(duration * fs)) / fs
    u = 75.0 - 70.0 * np.cos(2 * np.pi * F0 * t)
    y = y_clean(t) + np.random.default_rng(seed).normal(0.0, sigma, t.size)
    return Record(t=t, u=u, y=y, metadata={"frequency_hz": F0}, **kw)


@pytest.mark.parametrize("seed", SEEDS)
def test_harmonics_are_kept_and_the_output_is_the_clean_signal_within_the_noise(seed):
    rec = _record(_harmonics, seed)
    data, info = to_working_rate(rec)
    r = info.records[0]
    k = r.factor
    # the noise-floor rule sets the rate: F_MAX needs 2 * margin * F_MAX > 100 * F0 Hz
    assert 2 * MARGIN * F_MAX > MIN_SAMPLES_PER_CYCLE * F0
    assert r.reason.startswith("noise floor of y")
    assert k >= 2 and r.band_hz[0] == 0.0 and r.band_hz[1] >= F_MAX
    assert r.fs_out_hz == pytest.approx(FS / k) and r.input_treatment == "filtered"
    out = data[0]
    # no warm-up: the samples within half the filter of the end are left off, those of
    # the start kept (the model starts where the record does) as warm-up
    assert r.dropped_at_end > 0 and out.warmup == r.edge_warmup > 0
    np.testing.assert_array_equal(out.t, rec.t[: rec.n - r.dropped_at_end: k])
    assert out.metadata["sampling_rate_hz"] == pytest.approx(FS / k)
    # white noise of sd SIGMA through the low-pass: sd SIGMA * sqrt(sum h^2), which is
    # SIGMA / sqrt(k) for a response power-complementary about the new Nyquist frequency
    assert r.noise_gain * math.sqrt(k) == pytest.approx(1.0, abs=0.005)
    err = (out.y - _harmonics(out.t))[out.scored]
    # every scored sample: the filtered noise's bound (Bonferroni over the samples at
    # 1e-3) plus the pass band's ripple (1e-4) times the sum of the amplitudes
    z = stats.norm.isf(1e-3 / (2 * out.n))
    ripple = 1e-4 * np.sum(1.0 / np.arange(1, int(F_MAX / F0) + 1))
    assert np.max(np.abs(err)) <= z * SIGMA / math.sqrt(k) + ripple
    # and the noise went down by about sqrt(k)
    assert np.std(err) <= 1.2 * SIGMA * r.noise_gain


@pytest.mark.parametrize("seed", SEEDS)
def test_white_noise_above_the_excitation_decimates_to_the_samples_per_cycle_floor(seed):
    rec = _record(lambda t: 10.0 * np.sin(2 * np.pi * F0 * t), seed)
    data, info = to_working_rate(rec)
    r = info.records[0]
    assert r.factor == math.floor(FS / (MIN_SAMPLES_PER_CYCLE * F0))
    assert r.reason.startswith(f"{MIN_SAMPLES_PER_CYCLE:g} samples per cycle of 1 Hz")
    assert r.signal_edge_y_hz < MIN_SAMPLES_PER_CYCLE * F0 / (2 * MARGIN)
    assert data[0].fs / F0 >= MIN_SAMPLES_PER_CYCLE


def test_signal_edge_of_white_noise_is_zero_at_the_stated_level():
    # the threshold is the chi-square quantile under white noise, Bonferroni at alpha:
    # over 200 records of white noise, at most a few may show an edge
    hits = sum(signal_edge(np.random.default_rng(s).normal(0, 1, 4096), 1000.0, alpha=0.05)
               > 0 for s in range(200))
    assert hits <= stats.binom.isf(1e-4, 200, 0.05)


def _stepped_record(seed: int, sigma_u: float = 0.0) -> Record:
    rng = np.random.default_rng(seed)
    fs, hold = 5000.0, 0.25  # 4 steps per second, instantaneous, held
    levels = rng.uniform(0.0, 150.0, 24)
    t = np.arange(round(levels.size * hold * fs)) / fs
    u = np.repeat(levels, round(hold * fs)) + rng.normal(0.0, sigma_u, t.size)
    # a first-order stage (10 ms) and white sensor noise
    alpha = math.exp(-1.0 / (fs * 0.01))
    y = np.empty_like(u)
    state = 0.1 * u[0]
    for i, v in enumerate(u):
        state = alpha * state + (1 - alpha) * 0.1 * v
        y[i] = state
    y = y + rng.normal(0.0, 0.02, t.size)
    return Record(t=t, u=u, y=y, name=f"steps{seed}")


@pytest.mark.parametrize("seed", SEEDS[:3])
def test_white_noise_stays_white_at_the_working_rate(seed):
    # a 1 Hz sine and white noise at 10 kHz, 200 s: decimated by 100 to 20 000 samples.
    # The sample autocorrelations of white noise at lags 1-3 are N(0, 1/n) each; the
    # bound 4.5/sqrt(n) fails a white series with probability 4e-5 per test. The
    # filter's own are about 0.002 (0.3/sqrt(n)); a low-pass with its stop band at the
    # new Nyquist frequency gave 0.23, -0.18, 0.11 (32/sqrt(n))
    rec = _record(lambda t: 10.0 * np.sin(2 * np.pi * F0 * t), seed, duration=200.0)
    data, info = to_working_rate(rec, rate=100.0)
    o, r = data[0], info.records[0]
    assert r.factor == 100
    e = (o.y - 10.0 * np.sin(2 * np.pi * F0 * o.t))[o.scored]
    e = e - e.mean()
    rho = [float(np.dot(e[:-m], e[m:]) / np.dot(e, e)) for m in (1, 2, 3)]
    assert max(map(abs, rho)) < 4.5 / math.sqrt(e.size), rho
    # and its variance is the white noise's over k (the noise gain 1/sqrt(k), to 0.5 %)
    assert r.noise_gain * math.sqrt(r.factor) == pytest.approx(1.0, abs=0.005)
    assert np.var(e) == pytest.approx(SIGMA**2 / r.factor, rel=5 * math.sqrt(2 / e.size))


@pytest.mark.parametrize("seed", SEEDS[:3])
def test_a_record_without_warm_up_is_simulated_from_its_own_start(seed):
    # a play PI from rest under a 5 Hz sine at 10 kHz, white noise 0.2 % of the stroke:
    # at the working rate the generating model with its own parameters must follow the
    # scored samples of the first cycle as closely as those of the others (the filter's
    # start is warm-up, not cut: a model started at rest 16 samples up the first rise
    # missed that cycle by 8.9 % of the stroke)
    model = models.get("pi_play(n_operators=3)")
    t = np.arange(12_001) / 10_000.0
    u = 10.0 * np.sin(2 * np.pi * 5.0 * t)
    theta = {**model.param_space(Record(t=t, u=u, y=u.copy())).fixed, "p0": 0.12,
             "w": np.array([0.05, 0.03, 0.02])}
    y = model.simulate(u, t, theta)
    y = y + 0.002 * np.ptp(y) * np.random.default_rng(seed).standard_normal(y.size)
    data, info = to_working_rate(Record(t=t, u=u, y=y, metadata={"frequency_hz": 5.0}))
    o, r = data[0], info.records[0]
    assert r.factor == 20 and o.warmup == r.edge_warmup > 0 and o.t[0] == 0.0
    err = np.abs(model.simulate(o.u, o.t, theta) - o.y)[o.scored]
    first = round(10_000 / 5.0 / r.factor) - o.warmup
    assert np.max(err[:first]) <= 0.005 * np.ptp(y)


@pytest.mark.parametrize("seed", SEEDS[:3])
def test_a_stepped_input_is_subsampled_exactly(seed):
    rec = _stepped_record(seed)
    for rate in ("auto", 250.0):
        data, info = to_working_rate(rec, rate=rate)
        r = info.records[0]
        assert r.factor >= 2, r
        assert r.input_treatment == "subsampled" and r.input_jumps >= 20
        # the kept input values are the originals (no filter, no overshoot)
        np.testing.assert_array_equal(data[0].u,
                                      rec.u[: rec.n - r.dropped_at_end: r.factor])
        assert set(np.unique(data[0].u)) <= set(np.unique(rec.u))


def test_a_smooth_input_with_one_jump_is_filtered_without_ringing():
    # the 150 V record's shape: at rest at 0, then a jump into a sine
    fs = 5000.0
    t = np.arange(30_000) / fs
    start = 10_000
    u = np.where(np.arange(t.size) >= start, 150.0 * np.sin(2 * np.pi * (t - 1.7)), 0.0)
    y = 0.13 * u + np.random.default_rng(0).normal(0, 0.05, t.size)
    # the jump and the output's step response in the warm-up, as in the 150 V record
    rec = Record(t=t, u=u, y=y, warmup=start + 2000,
                 metadata={"frequency_hz": 1.0, "excitation_start_index": start})
    data, info = to_working_rate(rec)
    r = info.records[0]
    assert r.factor >= 2 and r.input_treatment == "filtered" and r.input_jumps == 1
    out = data[0]
    # no ringing: nothing beyond the input's range, the rest exactly at rest, and the
    # sine's samples equal to the smooth input within the filter's ripple
    # (within the pass band's ripple, 1e-4 of the 150 V amplitude)
    assert out.u.min() >= u.min() - 0.015 and out.u.max() <= u.max() + 0.015
    i = out.metadata["excitation_start_index"]
    assert i == start // r.factor
    np.testing.assert_allclose(out.u[:i], 0.0, atol=1e-9)
    after = out.t >= t[start]
    np.testing.assert_allclose(out.u[after], np.interp(out.t[after], t, u), atol=0.015)


def test_a_record_at_about_100_samples_per_cycle_is_kept_whole():
    rec = _record(_harmonics, 0, fs=100.0 * F0, duration=10.0)
    data = Dataset((rec,), name="d")
    out, info = to_working_rate(data)
    assert out is data and not info.changed
    assert info.records[0].factor == 1 and info.records[0].n_out == rec.n


@pytest.mark.parametrize("rate", ["full", "auto", 20.0])
def test_full_never_changes_anything_and_metadata_are_carried(rate):
    rng = np.random.default_rng(3)
    t = np.arange(40_000) / FS
    u = 75 - 70 * np.cos(2 * np.pi * F0 * t)
    temp = 25 + 0.2 * t + rng.normal(0, 0.01, t.size)
    rec = Record(t=t, u=u, y=0.1 * u + rng.normal(0, 0.05, t.size), warmup=2001,
                 segment=(t >= 2.0).astype(int), covariates={"temperature_c": temp},
                 metadata={"frequency_hz": F0, "excitation_start_index": 3,
                           "virgin_branch_end_index": 2501}, name="r")
    data = Dataset((rec,), name="d")
    out, info = to_working_rate(data, rate=rate)
    if rate == "full":
        assert out is data and info.records[0].factor == 1
        assert info.records[0].reason == "full rate requested"
        return
    r = info.records[0]
    k = r.factor
    assert k == (100 if rate == "auto" else 500)
    # at 100 the warm-up holds the filter's start, at 500 it does not: it is made longer
    o = out[0]
    assert (r.edge_warmup == 0) is (rate == "auto")
    assert o.warmup == math.ceil(2001 / k) + r.edge_warmup
    np.testing.assert_array_equal(o.segment, rec.segment[: rec.n - r.dropped_at_end: k])
    assert o.metadata["excitation_start_index"] == 3 // k
    assert o.metadata["virgin_branch_end_index"] == 2501 // k
    assert o.metadata["working_rate"] == str(info.records[0])
    # the covariate is filtered: its trend kept, its noise (0.01) reduced; the scored
    # samples are clear of the filter's edges
    np.testing.assert_allclose(o.covariates["temperature_c"][o.scored],
                               25 + 0.2 * o.t[o.scored], atol=0.005)
    if rate == 20.0:
        assert "below what 100 samples per cycle" in info.records[0].reason


def test_result_record_prints_and_serialises():
    _, info = to_working_rate(_record(_harmonics, 0))
    assert isinstance(info, WorkingRate)
    d = json.loads(json.dumps(info.to_dict()))
    assert d["mode"] == "auto" and d["changed"] and len(d["records"]) == 1
    assert set(d["records"][0]) >= {"fs_in_hz", "fs_out_hz", "factor", "band_hz", "reason",
                                     "input_treatment"}
    assert "->" in str(info) and "->" in info.line()


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"rate": -5}, "rate: expected 'auto', 'full' or a finite rate in Hz > 0, got -5"),
    ({"rate": "fast"}, "got 'fast'"),
    ({"rate": float("nan")}, "got nan"),
    ({"rate": True}, "got True"),
    ({"min_samples_per_cycle": 1}, "min_samples_per_cycle: expected a finite number >= 2"),
    ({"margin": 1.0}, "margin: expected a finite number > 1"),
    ({"alpha": 0.0}, "alpha: expected a number in (0, 1)"),
])
def test_bad_arguments_are_refused_in_words(kwargs, words):
    with pytest.raises(ParameterError) as exc:
        to_working_rate(_record(_harmonics, 0, duration=0.5), **kwargs)
    assert words in str(exc.value)


def test_data_must_be_records():
    with pytest.raises(DataError, match="expected a Dataset or a Record, got str"):
        to_working_rate("data.csv")


# ------------------------------------------------------------------------------ CLI
MODEL = "pi_play(n_operators=3)"


@pytest.fixture(scope="module")
def fast_csv(tmp_path_factory):
    """One 2 Hz record of a 3-operator PI at 1 kHz (500 samples per cycle, 6 cycles)."""
    model = models.get(MODEL)
    r = model.param_space(DataScales(5.0, 145.0, 0.0, 20.0)).fixed["r"]
    theta = {"p0": 0.1, "w": np.array([0.05, 0.035, 0.02]), "r": r}
    t = np.arange(3000) / 1000.0
    u = 75 - 70 * np.cos(2 * np.pi * 2.0 * t)
    y = model.simulate(u, t, theta) + np.random.default_rng(1).normal(0, 0.05, t.size)
    rec = Record(t=t, u=u, y=y, name="fast", warmup=500, metadata={"frequency_hz": 2.0})
    path = tmp_path_factory.mktemp("data") / "fast.csv"
    write_csv(Dataset((rec,), name="fast"), path)
    return path


@pytest.fixture
def placed(monkeypatch):
    """Every file put in place during the test, in order.

    Every file of bayeshyst is written atomically (:func:`bayeshyst.files.atomic_paths`),
    which puts it in place with ``os.replace``: counted there, a file is counted however
    it was written.
    """
    import os

    real = os.replace
    paths: list[Path] = []

    def counted(src, dst, *args, **kwargs):
        paths.append(Path(dst))
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", counted)
    return paths


def _summaries(paths: list[Path]) -> list[Path]:
    return [p for p in paths if p.name == "summary.json"]


def test_diagnose_cli_writes_the_working_rate(fast_csv, tmp_path, capsys, placed):
    out = tmp_path / "diag"
    code = main(["diagnose", str(fast_csv), "--model", MODEL, "--steps", "300",
                 "--walkers", "16", "--effects", "drift", "--max-rounds", "1",
                 "--no-figures", "--no-checkpoint", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert _summaries(placed) == [out / "summary.json"]  # written once, with the entry
    assert "working rate auto: fast 1000 -> 200 Hz (k=5" in err
    entry = json.loads((out / "summary.json").read_text())["working_rate"]
    assert entry["mode"] == "auto" and entry["changed"]
    rec = entry["records"][0]
    assert rec["factor"] == 5 and rec["fs_out_hz"] == pytest.approx(200.0)
    check = entry["full_rate_check"]
    assert "error" not in check, check
    assert check["n_scored_full_rate"] == 2500
    assert check["n_scored_working_rate"] == rec["n_out"] - 100  # warm-up 500 / 5
    # one model, the same draws: the two RMSEs differ by the noise the filter removed
    assert 0 < check["rmse_working_rate"] < check["rmse_full_rate"] < 3 * 0.05
    # the line printed is the record's own, with the numbers written
    assert (f"final fit: {check['model']} scored at full rate: RMSE "
            f"{check['rmse_full_rate']:.4g} (working rate {check['rmse_working_rate']:.4g}; "
            f"the fit's own {check['rmse_fit']:.4g})") in err


class _Fit:
    """What :func:`check_at_full_rate` uses of a FitResult, predicting as told."""

    model = SimpleNamespace(name="stub")
    overall = None

    def __init__(self, outcome):
        self.outcome = outcome

    def predict(self, data, *, n_draws, seed):
        if isinstance(self.outcome, Exception):
            raise self.outcome
        return self.outcome


def test_a_failed_full_rate_prediction_is_a_record_and_other_errors_are_not_hidden():
    from bayeshyst.errors import SimulationError
    from bayeshyst.inference.predict import FullRateCheck, check_at_full_rate

    data = Dataset((_record(_harmonics, 0, duration=0.5),), name="d")
    check = check_at_full_rate(_Fit(SimulationError("diverged at sample 7")), data, data)
    assert isinstance(check, FullRateCheck) and check.rmse_full_rate is None
    assert check.to_dict() == {"error": "the fit could not be scored at full rate: "
                                        "diverged at sample 7"}
    assert str(check) == check.error
    none = check_at_full_rate(_Fit(SimpleNamespace(overall=None)), data, data)
    assert none.to_dict() == {"error": "no measured output to score at full rate"}
    # a bug is not a failed prediction: it is raised, not recorded
    with pytest.raises(TypeError):
        check_at_full_rate(_Fit(TypeError("a bug")), data, data)


def test_compare_cli_writes_the_working_rate(fast_csv, tmp_path):
    out = tmp_path / "cmp"
    code = main(["compare", str(fast_csv), "--models", MODEL, "--steps", "200",
                 "--walkers", "16", "--no-lofo", "--max-refits", "0", "--jobs", "1",
                 "--no-figures", "--quiet", "--working-rate", "full", "--out", str(out)])
    assert code == 0
    entry = json.loads((out / "summary.json").read_text())["working_rate"]
    assert entry["mode"] == "full" and not entry["changed"]
    assert entry["records"][0]["factor"] == 1


def test_compare_cli_writes_summary_json_once_with_the_working_rate(fast_csv, tmp_path,
                                                                   placed):
    out = tmp_path / "cmp"
    code = main(["compare", str(fast_csv), "--models", MODEL, "--steps", "200",
                 "--walkers", "16", "--no-lofo", "--max-refits", "0", "--jobs", "1",
                 "--no-figures", "--quiet", "--working-rate", "auto", "--out", str(out)])
    assert code == 0
    assert _summaries(placed) == [out / "summary.json"]
    entry = json.loads((out / "summary.json").read_text())["working_rate"]
    assert entry["mode"] == "auto" and entry["changed"]
    assert entry["records"][0]["factor"] == 5  # 1 kHz at 100 samples per cycle of 2 Hz


def _text(html: str) -> str:
    """The text a browser shows of ``html``: tags dropped, entities decoded, spaces single."""
    import html as html_module
    import re

    return " ".join(html_module.unescape(re.sub(r"<[^>]+>", " ", html)).split())


def test_report_says_the_working_rate_in_its_data_section(fast_csv, tmp_path, placed):
    out = tmp_path / "rep"
    code = main(["report", str(fast_csv), "--models", MODEL, "--steps", "100",
                 "--walkers", "16", "--no-lofo", "--max-refits", "0", "--max-rounds", "1",
                 "--effects", "drift", "--no-calibration", "--jobs", "1", "--no-figures",
                 "--quiet", "--out", str(out)])
    assert code == 0
    # every summary once: the stages' own, then the report's (last)
    written = _summaries(placed)
    assert sorted(written) == sorted(set(written)) and written[-1] == out / "summary.json"
    entry = json.loads((out / "summary.json").read_text())["working_rate"]
    assert entry["changed"] and entry["records"][0]["factor"] == 5
    # the stages' summaries do not repeat it
    for stage in ("compare", "diagnose"):
        assert "working_rate" not in json.loads((out / stage / "summary.json").read_text())
    page = (out / "report.html").read_text(encoding="utf-8")
    data = _text(page[page.index('<section id="data">'):].split("</section>")[0])
    # the record's own sentence, as the CLI printed it, and what it means for the table
    assert f"{entry['records'][0]['statement']}." in data
    assert "fast: 1000 Hz -> 200 Hz (every 5th sample, 3000 -> " in data
    assert "1 record(s) sampled faster than the fit needs were anti-aliased" in data


def test_report_data_section_says_when_every_record_was_kept_whole():
    from bayeshyst.outputs.report_html import _data_html
    from bayeshyst.outputs.report_outputs import data_overview

    rec = _record(_harmonics, 0, fs=100.0 * F0, duration=10.0).with_(name="slow")
    data = Dataset((rec,), name="d")
    _, info = to_working_rate(data)
    assert not info.changed
    section = json.loads(json.dumps(data_overview(data, "d.csv")))
    text = _text(_data_html(section, None, json.loads(json.dumps(info.to_dict()))))
    assert ("Working rate auto: every record kept at full rate (already near its working "
            "rate (100 samples per cycle of 1 Hz needs 100 Hz)).") in text
    assert "decimated" not in text
    # without an entry (the demo: no --working-rate) the section says nothing of it
    assert "working rate" not in _text(_data_html(section, None)).lower()


def test_cli_refuses_a_negative_working_rate(fast_csv, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["diagnose", str(fast_csv), "--model", MODEL, "--working-rate", "-5",
              "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --working-rate: expected auto, full or a rate in Hz > 0, got '-5'" in err
    assert "Traceback" not in err and not (tmp_path / "x").exists()
