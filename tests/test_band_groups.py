"""Band groups: model selection groups multisine and broadband records by their band.

A record with an excitation frequency is compared in its frequency's group; one
classified multisine or broadband (``metadata["band_hz"]``, no frequency) in its band's
group; only a record with neither in the "unknown" group. Each band group's error is
shown as an octave spectrum (:func:`bayeshyst.inference.error_spectrum.error_spectrum`),
checked here against Parseval on a sum of sines.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bayeshyst.data import Band, Dataset, Record, group_key, group_label
from bayeshyst.inference.error_spectrum import error_spectrum, group_error_spectrum, octave_edges
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.compare_outputs import comparison_summary
from bayeshyst.selection import compare_models
from bayeshyst.selection.compare import _tasks
from bayeshyst.selection.tasks import TaskSpec

MODELS = ("pi_play(n_operators=3)", "pi_play(n_operators=5)")
SAMPLER = SamplerSettings(max_steps=300, first_chunk=100, seed=3)


def _play(u: np.ndarray, r: float) -> np.ndarray:
    """A play operator of half-width ``r`` (the plant's hysteresis)."""
    out = np.empty_like(u)
    z = u[0]
    for i, x in enumerate(u):
        z = min(max(z, x - r), x + r)
        out[i] = z
    return out


def _plant(u: np.ndarray, seed: int) -> np.ndarray:
    y = 0.15 * u + 0.05 * _play(u, 20.0)
    return y + np.random.default_rng(seed).normal(0.0, 0.05, u.size)


def _broadband(name: str, band: tuple[float, float], seed: int, fs: float = 1000.0,
               n: int = 1200) -> Record:
    """Band-limited noise over ``band`` (FFT-masked), 0..150 V."""
    rng = np.random.default_rng(seed)
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n, 1.0 / fs)
    spec[(f < band[0]) | (f > band[1])] = 0.0
    x = np.fft.irfft(spec, n)
    u = 75.0 + 70.0 * x / np.max(np.abs(x))
    t = np.arange(n) / fs
    return Record(t=t, u=u, y=_plant(u, seed + 100), name=name, warmup=50,
                  metadata={"band_hz": band, "excitation": "broadband"})


def _sine(name: str, f: float, fs: float = 1000.0, cycles: int = 6) -> Record:
    t = np.arange(int(cycles * fs / f)) / fs
    u = 75.0 - 70.0 * np.cos(2 * np.pi * f * t)
    return Record(t=t, u=u, y=_plant(u, 7), name=name, warmup=int(fs / f),
                  metadata={"frequency_hz": f})


def _band_data() -> Dataset:
    # the band records first and out of order: groups are sorted, not taken as met
    return Dataset((_broadband("b2", (20.0, 400.0), 2), _broadband("a1", (5.0, 150.0), 0),
                    _sine("s10", 10.0), _broadband("a2", (5.0, 150.0), 1)), name="bands")


# ------------------------------------------------------------------ group identity
def test_group_keys_labels_and_order():
    data = _band_data()
    keys = list(data.by_group())
    assert keys == [10.0, Band(5.0, 150.0), Band(20.0, 400.0)]
    assert [group_label(k) for k in keys] == ["10 Hz", "band 5-150 Hz", "band 20-400 Hz"]
    assert {r.name: r.group for r in data} == {"a1": "band 5-150 Hz", "a2": "band 5-150 Hz",
                                               "b2": "band 20-400 Hz", "s10": "10 Hz"}
    # a band is the same group exactly when the label is the same
    near = _broadband("a3", (5.0004, 150.2), 4)
    assert group_key(near) == Band(5.0, 150.0) and near.group == "band 5-150 Hz"
    plain = Record(t=np.arange(8.0), u=np.arange(8.0), y=np.arange(8.0), name="x")
    assert group_key(plain) is None and list(Dataset((plain,)).by_group()) == [None]


def test_frequency_only_data_keeps_its_groups_and_task_keys():
    recs = tuple(_sine(f"s{f:g}", f) for f in (20.0, 2.0, 7.5))
    other = Record(t=np.arange(8.0), u=np.sin(np.arange(8.0)), y=np.arange(8.0), name="u")
    data = Dataset((*recs, other), name="freqs")
    assert list(data.by_group()) == list(data.by_frequency()) == [2.0, 7.5, 20.0, None]
    assert [d.name for d in data.by_group().values()] == [
        d.name for d in data.by_frequency().values()]
    specs = _tasks(MODELS[:1], list(data.by_group()), True)
    # the same tasks, keys and so seeds as a frequency-only comparison always made
    legacy = [TaskSpec(MODELS[0], "joint")] + [
        TaskSpec(MODELS[0], scope, f, True) for scope in ("frequency", "lofo")
        for f in (2.0, 7.5, 20.0, None)]
    assert specs == legacy and [s.key for s in specs] == [s.key for s in legacy]
    assert [s.key.split("__")[1] for s in specs[1:5]] == [
        "frequency_2Hz", "frequency_7.5Hz", "frequency_20Hz", "frequency_unknown"]


# ------------------------------------------------------------------ error spectrum
def test_error_spectrum_gives_the_rms_of_sines_in_their_octaves():
    fs, n = 1024.0, 4096
    t = np.arange(n) / fs
    # octaves from 4 Hz: [4, 8), [8, 16), [16, 32), ... up to 512 Hz (Nyquist)
    amps = {5.0: 2.0, 12.0: 0.5, 100.0: 1.5}  # on bins of the record (df = 0.25 Hz)
    err = sum(a * np.sin(2 * np.pi * f * t + f) for f, a in amps.items())
    u = 3.0 * np.sin(2 * np.pi * 40.0 * t)
    y = 0.7 + err  # the offset is DC: below the first octave, left out
    rec = Record(t=t, u=u, y=y, name="r", metadata={"band_hz": (4.0, 200.0)})
    rows = error_spectrum(rec, np.zeros(n))
    assert [r.lo_hz for r in rows] == [4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0]
    assert rows[-1].hi_hz == 512.0
    want_err = {4.0: 2.0, 8.0: 0.5, 64.0: 1.5}
    for r in rows:
        assert r.error_rms == pytest.approx(want_err.get(r.lo_hz, 0.0) / math.sqrt(2),
                                            abs=1e-9)
        assert r.input_rms == pytest.approx(3.0 / math.sqrt(2) if r.lo_hz == 32.0 else 0.0,
                                            abs=1e-9)
    # pooled over two records: the sample-weighted mean square in each octave
    pooled = group_error_spectrum([rec, rec], [np.zeros(n), np.zeros(n)], 4.0)
    assert [p.error_rms for p in pooled] == pytest.approx([r.error_rms for r in rows])
    assert pooled[0].n_samples == 2 * n
    assert octave_edges(5.0, 30.0).tolist() == [5.0, 10.0, 20.0, 30.0]


# -------------------------------------------------------------------- comparison
@pytest.fixture(scope="module")
def band_comparison():
    return compare_models(_band_data(), list(MODELS), sampler=SAMPLER, lofo=True,
                          max_refits=0, draws_per_chain=10, n_lofo_draws=50, n_jobs=1)


def test_band_groups_are_compared_like_frequencies(band_comparison):
    res = band_comparison
    assert [fc.label for fc in res.per_frequency] == ["10 Hz", "band 5-150 Hz",
                                                      "band 20-400 Hz"]
    assert [fc.key for fc in res.per_frequency] == [10.0, Band(5.0, 150.0),
                                                    Band(20.0, 400.0)]
    assert [fc.frequency_hz for fc in res.per_frequency] == [10.0, None, None]
    members = {10.0: {"s10"}, Band(5.0, 150.0): {"a1", "a2"},
               Band(20.0, 400.0): {"b2"}}
    every = {"s10", "a1", "a2", "b2"}
    seen = set()
    for t in res.tasks:
        assert t.ok, t.error
        names = {label.split("#")[0] for label in t.unit_labels}
        if t.spec.scope == "joint":
            assert names == every
            continue
        seen.add((t.spec.scope, t.spec.group_key))
        # a group's fit scores exactly its records; its held-out fit scores them too
        assert names == members[t.spec.group_key], t.spec.key
    assert seen == {(s, k) for s in ("frequency", "lofo") for k in members}
    for fc in res.per_frequency:
        assert fc.best in MODELS
        for s in fc.scores:
            assert s.n_cycles > 0 and math.isfinite(s.elpd_joint)
            assert math.isfinite(s.elpd_lofo) and math.isfinite(s.nrmse_percent)
    # every cycle of the joint fit is in exactly one group
    joint = res.fit_of(MODELS[0], joint=True)
    assert sum(fc.score(MODELS[0]).n_cycles for fc in res.per_frequency) == \
        joint.pointwise.size
    # the band groups' fits carry their error spectra, from the lower band edge
    fit = res.fit_of(MODELS[0], Band(20.0, 400.0))
    rows = dict(fit.error_spectra)[Band(20.0, 400.0)]
    assert rows[0].lo_hz == 20.0 and rows[-1].hi_hz == 500.0
    assert all(r.error_rms > 0 and r.input_rms >= 0 for r in rows)
    d, se = res.difference(MODELS[0], MODELS[1], Band(5.0, 150.0))
    assert math.isfinite(d) and se >= 0


def test_band_groups_in_the_summary(band_comparison):
    summary = json.loads(json.dumps(comparison_summary(band_comparison), default=str))
    per = summary["per_frequency"]
    assert [e["group"] for e in per] == ["10 Hz", "band 5-150 Hz", "band 20-400 Hz"]
    assert [e["frequency_hz"] for e in per] == [10.0, None, None]
    assert [e["band_hz"] for e in per] == [None, [5.0, 150.0], [20.0, 400.0]]
    assert per[1]["statement"].startswith(f"band 5-150 Hz: {per[1]['best']}")
    assert "error_spectrum" not in per[0]
    for e in per[1:]:
        spec = e["error_spectrum"]
        assert spec["model"] == e["best"] and spec["bands"][0]["lo_hz"] == e["band_hz"][0]
    assert summary["overall"]["group"] == "all"
    keys = {f["key"].split("__")[1] for f in summary["fits"]}
    assert keys == {"joint_all", "frequency_10Hz", "frequency_band5-150Hz",
                    "frequency_band20-400Hz", "lofo_10Hz", "lofo_band5-150Hz",
                    "lofo_band20-400Hz"}
    bands = {f["group"]: f["band_hz"] for f in summary["fits"]}
    assert bands == {"all": None, "10 Hz": None, "band 5-150 Hz": [5.0, 150.0],
                     "band 20-400 Hz": [20.0, 400.0]}


def test_report_section_shows_a_band_groups_error_spectrum(band_comparison, tmp_path):
    from bayeshyst.outputs.report_html import _selection_html

    summary = json.loads(json.dumps(comparison_summary(band_comparison), default=str))
    summary["per_frequency"][1]["error_spectrum"].update(y_unit="um", u_unit="V")
    page = str(_selection_html(summary, tmp_path))
    assert "<h3>band 5-150 Hz</h3>" in page and "<h3>band 20-400 Hz</h3>" in page
    assert page.count("Error spectrum of") == 2 and "octave [Hz]" in page
    summary["per_frequency"][2]["error_spectrum"] = None  # the chosen model's fit failed
    assert "No error spectrum" in str(_selection_html(summary, tmp_path))


def test_a_studys_unknown_frequency_group_fits_its_band_records_too():
    # the study groups by frequency only: its task for the records without one must fit
    # exactly the records it is handed, whatever their bands
    from bayeshyst.selection.tasks import CompareSettings, split_data
    from bayeshyst.study.tasks import StudyTask

    data = _band_data()
    unknown = Dataset([r for r in data if r.frequency_hz is None], name="u")
    assert {group_key(r) for r in unknown} - {None}  # bands among them
    task = StudyTask("d", "pi_play", "gaussian", None, 0, "x",
                     CompareSettings("gaussian", SamplerSettings()))
    fit, scored = split_data(unknown, task.spec)
    assert [r.name for r in fit] == [r.name for r in scored] == list(unknown.names)
    at = StudyTask("d", "pi_play", "gaussian", 10.0, 0, "x",
                   CompareSettings("gaussian", SamplerSettings()))
    assert at.spec == TaskSpec("pi_play", "frequency", 10.0, True)
