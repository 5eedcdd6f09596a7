"""The study file: which datasets, models, likelihoods, sampler settings and seeds.

A study is a TOML file (read with the standard library's :mod:`tomllib`)::

    name = "actuators at three temperatures"     # optional; default: the file's stem
    models = ["pi_play(n_operators=8)", "bouc_wen", "gp_memory"]
    likelihoods = ["gaussian"]                   # or likelihood = "gaussian"
    seeds = [0, 1]                               # or seed = 0; each fit once per seed
    frequencies_hz = [1, 10, 100]                # optional: fit only these

    [sampler]                                    # optional; every key optional
    moves = "structured"                         # or "de", "stretch"
    max_steps = 4000
    first_chunk = 100
    n_walkers = 32
    draws_per_chain = 30
    n_predictive_draws = 400
    max_refits = 5
    gp_n_train = 1000

    [[datasets]]
    path = "runs/actuator-*.csv"                 # a path or a glob, relative to this file
    warmup = 400                                 # options of bayeshyst.data.load
    columns = { t = "time_s", u = "voltage_V", y = "disp_um" }

    [[datasets]]
    measured = "mr_damper"                       # a measured set of ../shared/data
    name = "mr-damper-0.5A"
    options = { current_a = 0.5 }

Everything is checked here, once, before any fit starts: unknown keys (with the
closest known one), wrong types, model specs that do not build, unknown likelihoods and
loader options. A dataset that cannot be *read* is not an error of the study file: it
becomes failed rows of the study's table, and the other datasets go on.
"""

from __future__ import annotations

import difflib
import glob
import inspect
import math
import os
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bayeshyst.errors import DataError, ModelError, ParameterError
from bayeshyst.inference.settings import MOVES, SamplerSettings
from bayeshyst.selection.tasks import CompareSettings

__all__ = ["MEASURED_LOADERS", "DatasetSpec", "Study", "load_dataset", "read_study"]

_TOP_KEYS = ("name", "models", "likelihood", "likelihoods", "seed", "seeds", "frequencies_hz",
             "sampler", "datasets")
_DATASET_KEYS = ("path", "measured", "name", "options", "columns", "delimiter", "warmup",
                 "units", "metadata")
# the [sampler] keys that set a SamplerSettings field (every fit samples with it) ...
_SAMPLING_KEYS = {"moves": "moves", "n_walkers": "n_walkers", "max_steps": "max_steps",
                  "first_chunk": "first_chunk"}
# ... and those that set a CompareSettings field (how each fit is scored)
_SCORING_KEYS = {"draws_per_chain": "draws_per_chain", "n_predictive_draws": "n_lofo_draws",
                 "max_refits": "max_refits", "gp_n_train": "gp_n_train"}
_SAMPLER_KEYS = {**_SAMPLING_KEYS, **_SCORING_KEYS}
_SAMPLER_MIN = {"n_walkers": 4, "max_steps": 10, "first_chunk": 10, "draws_per_chain": 1,
                "n_predictive_draws": 1, "max_refits": 0, "gp_n_train": 10}


def _measured_loaders() -> dict[str, Callable[..., Any]]:
    from bayeshyst.data import measured

    return {"piezo_actuator_150v": measured.load_piezo_actuator_150v,
            "piezo_micromanipulator": measured.load_piezo_micromanipulator,
            "mr_damper": measured.load_mr_damper}


MEASURED_LOADERS = ("piezo_actuator_150v", "piezo_micromanipulator", "mr_damper")
"""Names a dataset's ``measured`` key accepts (the loaders of
:mod:`bayeshyst.data.measured`, reading ``../shared/data`` or ``BAYESHYST_SHARED_DATA``)."""


@dataclass(frozen=True)
class DatasetSpec:
    """One dataset of a study: a file, or a measured set of the shared data folder.

    Attributes
    ----------
    label : str
        Unique within the study; names the dataset in tables, figures and file names.
    path : str or None
        Absolute path of the file (``measured`` is None).
    measured : str or None
        One of :data:`MEASURED_LOADERS` (``path`` is None).
    options : tuple of (str, object)
        Keyword options of the reader or loader, validated against its signature.
    source : str
        Where in the study file the entry is (``datasets[2] (path = "runs/*.csv")``).
    error : str or None
        Why the entry gives no data although the study file is valid (a glob that
        matches nothing): the dataset becomes failed rows.
    """

    label: str
    path: str | None
    measured: str | None
    options: tuple[tuple[str, Any], ...]
    source: str
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description."""
        return {"label": self.label, "path": self.path, "measured": self.measured,
                "options": dict(self.options), "source": self.source, "error": self.error}


@dataclass(frozen=True)
class Study:
    """A parsed, validated study file (see the module docstring for the format).

    Attributes
    ----------
    name : str
    path : str
        The study file.
    datasets : tuple of DatasetSpec
        One per file (a glob expands to one entry per match, sorted).
    models : tuple of str
        Model spec strings, ``"gp"``/``"gp_memory"`` included.
    likelihoods : tuple of str
    seeds : tuple of int
    frequencies_hz : tuple of float or None
        Only these excitation frequencies are fitted (None: every one in the data).
    settings : CompareSettings
        Sampler (``settings.sampler``) and scoring settings of every fit (the likelihood
        field is set per task; the sampler's seed is not used: each fit derives its own
        from the study's seeds).
    """

    name: str
    path: str
    datasets: tuple[DatasetSpec, ...]
    models: tuple[str, ...]
    likelihoods: tuple[str, ...]
    seeds: tuple[int, ...]
    frequencies_hz: tuple[float, ...] | None
    settings: CompareSettings

    def to_dict(self) -> dict[str, Any]:
        """The study as it was understood (``study.json`` of the outputs)."""
        sampler = {k: getattr(self.settings.sampler, f) for k, f in _SAMPLING_KEYS.items()}
        sampler.update({k: getattr(self.settings, f) for k, f in _SCORING_KEYS.items()})
        return {"name": self.name, "path": self.path, "models": list(self.models),
                "likelihoods": list(self.likelihoods), "seeds": list(self.seeds),
                "frequencies_hz": None if self.frequencies_hz is None
                else list(self.frequencies_hz),
                "sampler": sampler, "datasets": [d.to_dict() for d in self.datasets]}

    def __str__(self) -> str:
        n_fail = sum(d.error is not None for d in self.datasets)
        return (f"study {self.name!r}: {len(self.datasets)} dataset(s)"
                + (f" ({n_fail} unreadable)" if n_fail else "")
                + f" × {len(self.models)} model(s) × {len(self.likelihoods)} likelihood(s)"
                + f" × {len(self.seeds)} seed(s), per excitation frequency")


def _unknown(where: str, keys: Mapping[str, Any], known: tuple[str, ...]) -> None:
    for k in keys:
        if k not in known:
            close = difflib.get_close_matches(k, known, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ParameterError(f"{where}: unknown key {k!r}{hint}; expected one of "
                                 f"{', '.join(known)}")


def _one_or_many(where: str, doc: Mapping[str, Any], one: str, many: str, kind: type,
                 default: Any) -> tuple[Any, ...]:
    if one in doc and many in doc:
        raise ParameterError(f"{where}: give {one!r} or {many!r}, not both")
    if many in doc:
        values = doc[many]
        if not isinstance(values, list) or not values:
            raise ParameterError(f"{where}: {many!r} must be a non-empty list, got "
                                 f"{values!r}")
    else:
        values = [doc.get(one, default)]
    for v in values:
        # bool is an int in Python; a seed of `true` is a mistake, not 1
        if not isinstance(v, kind) or isinstance(v, bool):
            raise ParameterError(f"{where}: {many!r} entries must be {kind.__name__}, got "
                                 f"{v!r}")
    if len(set(values)) != len(values):
        raise ParameterError(f"{where}: {many!r} lists a value twice: {values!r}")
    return tuple(values)


def _settings(where: str, sampler: Any) -> CompareSettings:
    if not isinstance(sampler, dict):
        raise ParameterError(f"{where}: [sampler] must be a table, got {sampler!r}")
    _unknown(f"{where} [sampler]", sampler, tuple(_SAMPLER_KEYS))
    sampling, scoring = {}, {}
    for key, value in sampler.items():
        if key == "moves":
            if value not in MOVES:
                close = difflib.get_close_matches(str(value), MOVES, n=1)
                raise ParameterError(f"{where} [sampler]: unknown moves {value!r}"
                                     + (f" (did you mean {close[0]!r}?)" if close else "")
                                     + f"; expected one of {', '.join(MOVES)}")
        elif not isinstance(value, int) or isinstance(value, bool) \
                or value < _SAMPLER_MIN[key]:
            raise ParameterError(f"{where} [sampler]: {key} must be an integer >= "
                                 f"{_SAMPLER_MIN[key]}, got {value!r}")
        if key in _SAMPLING_KEYS:
            sampling[_SAMPLING_KEYS[key]] = value
        else:
            scoring[_SCORING_KEYS[key]] = value
    try:
        record = SamplerSettings(**sampling)
    except ParameterError as exc:
        raise ParameterError(f"{where} [sampler]: {exc}") from None
    return CompareSettings(sampler=record, **scoring)


def _reader_options(where: str, fn: Callable[..., Any], options: Mapping[str, Any],
                    skip: tuple[str, ...]) -> None:
    allowed = tuple(p for p in inspect.signature(fn).parameters if p not in skip)
    _unknown(f"{where} options", options, allowed)


def _expand(where: str, entry: Mapping[str, Any], base: Path) -> list[DatasetSpec]:
    _unknown(where, entry, _DATASET_KEYS)
    has_path, has_measured = "path" in entry, "measured" in entry
    if has_path == has_measured:
        raise ParameterError(f"{where}: give exactly one of 'path' (a file or glob) or "
                             f"'measured' ({', '.join(MEASURED_LOADERS)})")
    name = entry.get("name")
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise ParameterError(f"{where}: 'name' must be a non-empty string, got {name!r}")
    if has_measured:
        key = entry["measured"]
        if key not in MEASURED_LOADERS:
            close = difflib.get_close_matches(str(key), MEASURED_LOADERS, n=1)
            raise ParameterError(f"{where}: unknown measured set {key!r}"
                                 + (f" (did you mean {close[0]!r}?)" if close else "")
                                 + f"; expected one of {', '.join(MEASURED_LOADERS)}")
        extra = [k for k in entry if k not in ("measured", "name", "options")]
        if extra:
            raise ParameterError(f"{where}: a measured set takes its loader's settings "
                                 f"under 'options', not {extra}")
        options = entry.get("options", {})
        if not isinstance(options, dict):
            raise ParameterError(f"{where}: 'options' must be a table, got {options!r}")
        _reader_options(where, _measured_loaders()[key], options, ("root",))
        return [DatasetSpec(name or key, None, key, tuple(sorted(options.items())),
                            f"{where} (measured = {key!r})")]
    if "options" in entry:
        raise ParameterError(f"{where}: file datasets take columns, delimiter, warmup, "
                             f"units and metadata directly, not under 'options'")
    from bayeshyst.data.io import read_csv

    options = {k: v for k, v in entry.items() if k not in ("path", "name")}
    _reader_options(where, read_csv, options, ("path", "name"))
    pattern = entry["path"]
    if not isinstance(pattern, str) or not pattern.strip():
        raise ParameterError(f"{where}: 'path' must be a non-empty string, got {pattern!r}")
    full = Path(os.path.expanduser(pattern))
    full = full if full.is_absolute() else base / full
    source = f"{where} (path = {pattern!r})"
    opts = tuple(sorted(options.items()))
    if not glob.has_magic(pattern):
        return [DatasetSpec(name or full.stem, str(full), None, opts, source)]
    matches = sorted(glob.glob(str(full)))
    if not matches:
        return [DatasetSpec(name or pattern, str(full), None, opts, source,
                            error=f"{source}: the pattern matches no file")]
    if name is not None and len(matches) > 1:
        raise ParameterError(f"{where}: 'name' names one dataset, but {pattern!r} matches "
                             f"{len(matches)} files; drop 'name' (each file is named by "
                             f"its stem)")
    return [DatasetSpec(name or Path(m).stem, m, None, opts, source) for m in matches]


def read_study(path: str | os.PathLike[str]) -> Study:
    """Read and validate a study file.

    Parameters
    ----------
    path : path-like
        A TOML file (format in the module docstring). Relative dataset paths are
        resolved against its folder.

    Returns
    -------
    Study

    Raises
    ------
    DataError
        The file is missing or is not valid TOML.
    ParameterError, ModelError
        A key, value, model spec or likelihood that is not valid (the message names it).
    """
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.selection import check_models

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: study file not found" if not p.exists()
                        else f"{p}: is not a file")
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise DataError(f"{p}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise DataError(f"{p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    where = str(p)
    _unknown(where, doc, _TOP_KEYS)
    name = doc.get("name", p.stem)
    if not isinstance(name, str) or not name.strip():
        raise ParameterError(f"{where}: 'name' must be a non-empty string, got {name!r}")
    if "models" not in doc:
        raise ParameterError(f"{where}: 'models' is missing (a list of model specs)")
    models = doc["models"]
    if not isinstance(models, list) or not all(isinstance(m, str) for m in models):
        raise ParameterError(f"{where}: 'models' must be a list of strings, got {models!r}")
    try:
        models = check_models(models)
    except ModelError as exc:
        raise ModelError(f"{where}: {exc}") from None
    likelihoods = _one_or_many(where, doc, "likelihood", "likelihoods", str, "gaussian")
    for lik in likelihoods:
        try:
            get_likelihood(lik)
        except (ModelError, ParameterError, KeyError) as exc:
            raise ParameterError(f"{where}: likelihood {lik!r}: {exc}") from None
    seeds = _one_or_many(where, doc, "seed", "seeds", int, 0)
    if any(s < 0 for s in seeds):
        raise ParameterError(f"{where}: seeds must be >= 0, got {list(seeds)}")
    freqs = doc.get("frequencies_hz")
    if freqs is not None:
        if (not isinstance(freqs, list) or not freqs
                or not all(isinstance(f, int | float) and not isinstance(f, bool)
                           and math.isfinite(f) and f > 0 for f in freqs)):
            raise ParameterError(f"{where}: 'frequencies_hz' must be a non-empty list of "
                                 f"positive numbers [Hz], got {freqs!r}")
        freqs = tuple(sorted({float(f) for f in freqs}))
    settings = _settings(where, doc.get("sampler", {}))
    entries = doc.get("datasets")
    if not isinstance(entries, list) or not entries or not all(
            isinstance(e, dict) for e in entries):
        raise ParameterError(f"{where}: expected at least one [[datasets]] table")
    datasets: list[DatasetSpec] = []
    for i, entry in enumerate(entries):
        datasets += _expand(f"{where}: datasets[{i}]", entry, p.parent.resolve())
    labels = [d.label for d in datasets]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise ParameterError(f"{where}: dataset names {dup} are used twice; give each "
                             f"[[datasets]] entry its own 'name'")
    return Study(name.strip(), str(p), tuple(datasets), models, likelihoods, seeds, freqs,
                 settings)


def load_dataset(spec: DatasetSpec) -> Any:
    """Read one dataset of a study.

    Returns
    -------
    Dataset
        Named after ``spec.label``.

    Raises
    ------
    DataError
        The file cannot be read or the measured set is not there (the message names it).
    """
    from bayeshyst.data import load
    from bayeshyst.data.dataset import Dataset

    if spec.error is not None:
        raise DataError(spec.error)
    options = dict(spec.options)
    try:
        if spec.measured is not None:
            data = _measured_loaders()[spec.measured](**options)
        else:
            data = load(spec.path, **options)
    except (DataError, ParameterError, OSError, ValueError, TypeError) as exc:
        raise DataError(f"{spec.source}: {exc}") from None
    if isinstance(data, Dataset):
        return Dataset(data.records, name=spec.label)
    return Dataset((data,), name=spec.label)
