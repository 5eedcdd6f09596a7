"""HDF5 reader: roles by path or by name, time from t or a sampling rate, errors in words.

Every file is written here with h5py from known arrays, so the oracle is the arrays
themselves (a round trip) and, for errors, the file and dataset the message must name.
"""

from __future__ import annotations

import json
import re

import h5py
import numpy as np
import pytest

from bayeshyst.data import load, read_hdf5
from bayeshyst.errors import DataError

N = 64
FS = 200.0  # Hz


def _signals(n: int = N) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    t = np.arange(n) / FS
    u = np.sin(2 * np.pi * 5.0 * t) + 0.1 * rng.standard_normal(n)
    y = 0.8 * u + 0.05 * rng.standard_normal(n)
    return t, u, y


def _write(path, datasets=None, attrs=None):
    """An HDF5 file with ``{"group/name": array}`` datasets and ``{path: {k: v}}`` attributes."""
    with h5py.File(path, "w") as f:
        for name, value in (datasets or {}).items():
            f.create_dataset(name, data=value)
        for name, values in (attrs or {}).items():
            f[name].attrs.update(values)
    return path


def _raises(path, *names):
    """A DataError whose message names the file and every one of ``names`` (regexes)."""
    return pytest.raises(DataError, match=".*".join([re.escape(str(path)), *names]))


# ------------------------------------------------------------------------- round trips
def test_round_trip_with_time_dataset(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "run.h5", {"t": t, "u": u, "y": y})
    data = read_hdf5(path)
    assert data.name == "run" and len(data) == 1
    rec = data[0]
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)
    assert rec.units["t"] == "s"
    assert rec.metadata["source"] == str(path)
    assert "sampling_rate_hz" not in rec.metadata  # the time came from the file


def test_column_vectors_read_as_vectors(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "col.h5", {"t": t[:, None], "u": u[:, None], "y": y[:, None]})
    rec = read_hdf5(path)[0]
    assert rec.u.shape == (N,)
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)


def test_time_from_fs_dataset_in_the_input_group(tmp_path):
    _, u, y = _signals()
    # the benchmark's layout: (n, 1) columns and a (1, 1) fs in one group
    path = _write(tmp_path / "bench.h5", {"run/u": u[:, None], "run/y": y[:, None],
                                          "run/fs": np.array([[FS]])})
    rec = read_hdf5(path, columns={"u": "run/u", "y": "run/y"})[0]
    np.testing.assert_allclose(rec.t, np.arange(N) / FS, rtol=0, atol=0)
    assert rec.fs == pytest.approx(FS)
    assert rec.metadata["sampling_rate_hz"] == FS
    assert rec.metadata["sampling_rate_from"] == "dataset 'run/fs'"
    # the rate is used, so it is neither a covariate nor ignored
    assert "run/fs" not in rec.metadata.get("ignored_columns", ())
    assert not rec.covariates
    np.testing.assert_array_equal(rec.u, u)


def test_time_from_fs_argument(tmp_path):
    _, u, y = _signals()
    path = _write(tmp_path / "nofs.h5", {"u": u, "y": y})
    rec = read_hdf5(path, fs=50.0)[0]
    np.testing.assert_array_equal(rec.t, np.arange(N) / 50.0)
    assert rec.metadata["sampling_rate_from"] == "fs argument"
    # the argument wins over a rate stored in the file
    path = _write(tmp_path / "withfs.h5", {"u": u, "y": y, "fs": FS})
    rec = read_hdf5(path, fs=50.0)[0]
    assert rec.fs == pytest.approx(50.0)


@pytest.mark.parametrize("owner", ["g/u", "g"])
def test_time_from_fs_attribute(tmp_path, owner):
    _, u, y = _signals()
    path = _write(tmp_path / "attr.h5", {"g/u": u, "g/y": y}, {owner: {"Fs": FS}})
    rec = read_hdf5(path)[0]
    assert rec.fs == pytest.approx(FS)
    what = "dataset 'g/u'" if owner == "g/u" else "group 'g'"
    assert rec.metadata["sampling_rate_from"] == f"attribute 'Fs' of {what}"


def test_roles_found_by_name_in_the_input_group(tmp_path):
    _, u, y = _signals()
    path = _write(tmp_path / "two.h5", {
        "a/u": u, "a/y": y, "a/fs": FS, "a/temperature": np.linspace(20, 21, N),
        "b/u": u[:40], "b/y": y[:40], "b/fs": 2 * FS,
    })
    # the input placed in group b: its y and fs are b's, not a's
    rec = read_hdf5(path, columns={"u": "b/u"})[0]
    assert rec.n == 40 and rec.fs == pytest.approx(2 * FS)
    np.testing.assert_array_equal(rec.y, y[:40])
    rec = read_hdf5(path, columns={"y": "/a/y"})[0]  # a leading "/" names the same path
    np.testing.assert_array_equal(rec.u, u)
    # a vector of the record's length in the same group is a covariate; other groups
    # are other recordings
    assert list(rec.covariates) == ["a/temperature"]
    assert set(rec.metadata["ignored_columns"]) == {"b/u", "b/y", "b/fs"}


def test_load_dispatches_on_h5_and_hdf5(tmp_path):
    t, u, y = _signals()
    for suffix in (".h5", ".hdf5", ".H5"):
        path = _write(tmp_path / f"data{suffix}", {"grp/time": t, "grp/drive": u,
                                                  "grp/disp": y})
        data = load(path, columns={"u": "grp/drive", "y": "grp/disp"})
        np.testing.assert_array_equal(data[0].t, t)
        np.testing.assert_array_equal(data[0].y, y)


def test_sidecar_applies(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "side.h5", {"g/x": t, "g/v": u, "g/w": y})
    (tmp_path / "side.json").write_text(json.dumps(
        {"name": "from sidecar", "warmup": 5, "columns": {"t": "g/x", "u": "g/v", "y": "g/w"}}))
    data = read_hdf5(path)
    assert data.name == "from sidecar" and data[0].warmup == 5
    np.testing.assert_array_equal(data[0].u, u)


def test_record_column_splits_records(tmp_path):
    t, u, y = _signals()
    rec_id = (np.arange(N) >= N // 2).astype(np.int64)
    path = _write(tmp_path / "blocks.h5", {"t": t, "u": u, "y": y, "record": rec_id})
    data = read_hdf5(path)
    assert [r.n for r in data] == [N // 2, N // 2]


# ----------------------------------------------------------------------------- errors
def test_missing_dataset_names_file_and_dataset(tmp_path):
    _, u, y = _signals()
    path = _write(tmp_path / "m.h5", {"g/u": u, "g/y": y, "g/fs": FS})
    with _raises(path, "dataset 'g/disp'", "role 'y'", "missing", "g/y"):
        read_hdf5(path, columns={"u": "g/u", "y": "g/disp"})
    with _raises(path, "dataset 'g'", "is a group"):
        read_hdf5(path, columns={"u": "g", "y": "g/y"})
    path = _write(tmp_path / "noy.h5", {"u": u, "fs": FS})
    with _raises(path, "dataset 'y'", "missing"):
        read_hdf5(path)


@pytest.mark.parametrize("shape", [(N, 2), (1, N), (N, 1, 1), ()])
def test_wrong_shape_names_file_dataset_and_shape(tmp_path, shape):
    _, u, _ = _signals()
    path = _write(tmp_path / "shape.h5", {"u": u, "y": np.ones(shape), "fs": FS})
    with _raises(path, "dataset 'y'", "expected a vector", re.escape(f"shape {shape}")):
        read_hdf5(path)


def test_no_time_information_is_an_error_in_words(tmp_path):
    _, u, y = _signals()
    path = _write(tmp_path / "notime.h5", {"g/u": u, "g/y": y})
    with _raises(path, "no time information", "dataset 'g/u'", "fs"):
        read_hdf5(path)


def test_ambiguous_roles_name_the_candidates(tmp_path):
    _, u, y = _signals()
    path = _write(tmp_path / "amb.h5", {"a/u": u, "a/y": y, "a/fs": FS,
                                        "b/u": u, "b/y": y, "b/fs": FS})
    with _raises(path, "several datasets could be 'u'", "'a/u', 'b/u'"):
        read_hdf5(path)
    # names of the role in ROLE_NAMES count too: "voltage" and "u" are both inputs
    path = _write(tmp_path / "amb2.h5", {"u": u, "voltage": u, "y": y, "fs": FS})
    with _raises(path, "several datasets could be 'u'", "'u', 'voltage'"):
        read_hdf5(path)


def test_other_malformed_data_named(tmp_path):
    t, u, y = _signals()
    y_bad = y.copy()
    y_bad[7] = np.nan
    path = _write(tmp_path / "nan.h5", {"t": t, "u": u, "y": y_bad})
    with _raises(path, "index 7", "dataset 'y'", "finite"):
        read_hdf5(path)
    path = tmp_path / "text.h5"
    with h5py.File(path, "w") as f:
        f["t"], f["u"] = t, u
        f.create_dataset("y", data=np.array(["a"] * N, dtype=h5py.string_dtype()))
    with _raises(path, "dataset 'y'", "real numeric"):
        read_hdf5(path)
    path = _write(tmp_path / "badfs.h5", {"u": u, "y": y, "fs": -1.0})
    with _raises(path, "dataset 'fs'", "positive"):
        read_hdf5(path)
    path = _write(tmp_path / "short.h5", {"u": u, "y": y[:10], "fs": FS})
    with _raises(path, "dataset 'y'", f"expected {N} samples", "dataset 'u'"):
        read_hdf5(path)
    path = _write(tmp_path / "both.h5", {"t": t, "u": u, "y": y})
    with _raises(path, "fs argument", "dataset 't'"):
        read_hdf5(path, fs=FS)
    t_bad = t.copy()
    t_bad[5] = t_bad[4]
    path = _write(tmp_path / "dup.h5", {"t": t_bad, "u": u, "y": y})
    with _raises(path, "index 5", "dataset 't'", "duplicate time"):
        read_hdf5(path)
    path = tmp_path / "not.h5"
    path.write_text("t,u,y\n")
    with _raises(path, "expected an HDF5 file"):
        read_hdf5(path)
    with _raises(tmp_path / "absent.h5", "no such file"):
        read_hdf5(tmp_path / "absent.h5")


def test_constant_output_refused_unless_not_fittable(tmp_path):
    _, u, _ = _signals()
    path = _write(tmp_path / "const.h5", {"g/u": u, "g/y": np.zeros(N), "g/fs": FS})
    with _raises(path, "dataset 'y'", "constant"):
        read_hdf5(path)
    assert read_hdf5(path, fittable=False)[0].n == N
