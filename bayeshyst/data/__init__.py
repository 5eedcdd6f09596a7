"""Measurement data: validated records, file formats, segmentation, measured sets.

* :class:`Record` / :class:`Dataset` -- validated once at construction
  (:mod:`bayeshyst.data.record`, :mod:`bayeshyst.data.dataset`);
* :func:`load`, ``read_*`` / ``write_*`` -- CSV/text, ``.npz``, ``.mat`` with JSON
  sidecars (:mod:`bayeshyst.data.io`, :mod:`bayeshyst.data.writers`, parser in
  :mod:`bayeshyst.data.parsing`);
* :func:`find_reversals`, :func:`split_cycles`, :func:`estimate_frequency`,
  :func:`split_by_frequency`, :func:`label_frequencies` -- cycles and frequency blocks
  (:mod:`bayeshyst.data.segment`); :func:`classify_excitation` -- periodic, stepped,
  multisine or broadband input (:mod:`bayeshyst.data.classify`);
* ``load_*`` -- the measured sets in the shared data folder
  (:mod:`bayeshyst.data.measured`);
* :class:`VirtualActuator`, :func:`bundle` -- the documented simulator with known
  truth and the bundled datasets (:mod:`bayeshyst.data.virtual`), excitation signals
  (:mod:`bayeshyst.data.excitation`);
* :class:`BipolarActuator`, :func:`bipolar_records` -- its bipolar mode: butterfly
  strain loops with a known coercive field (:mod:`bayeshyst.data.virtual_bipolar`).
"""

from __future__ import annotations

from bayeshyst.data import excitation
from bayeshyst.data.classify import Excitation, classify_excitation
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.groups import Band, group_key, group_label
from bayeshyst.data.hdf5 import read_hdf5
from bayeshyst.data.io import load, read_csv, read_mat, read_npz
from bayeshyst.data.measured import (
    load_bouc_wen_benchmark,
    load_micromanipulator_reference,
    load_mr_damper,
    load_piezo_actuator_150v,
    load_piezo_micromanipulator,
    shared_data_root,
)
from bayeshyst.data.parsing import Table, read_table, sidecar_path
from bayeshyst.data.record import DEFAULT_UNITS, MIN_SAMPLES, Record, frequency_key
from bayeshyst.data.segment import (
    CycleSplit,
    cycle_labels,
    default_prominence,
    estimate_frequency,
    find_reversals,
    input_noise_sd,
    label_frequencies,
    split_by_frequency,
    split_cycles,
)
from bayeshyst.data.virtual import (
    BUNDLE_FREQUENCIES_HZ,
    BUNDLE_SEED,
    STROKE_UM,
    VirtualActuator,
    bundle,
    creep_per_decade,
    hysteresis_only,
    hysteresis_percent,
    loop_width,
)
from bayeshyst.data.virtual_bipolar import BIPOLAR_UNITS, BipolarActuator, bipolar_records
from bayeshyst.data.writers import write_csv, write_npz

__all__ = [
    "BIPOLAR_UNITS",
    "BUNDLE_FREQUENCIES_HZ",
    "BUNDLE_SEED",
    "DEFAULT_UNITS",
    "MIN_SAMPLES",
    "STROKE_UM",
    "Band",
    "BipolarActuator",
    "CycleSplit",
    "Dataset",
    "Excitation",
    "Record",
    "Table",
    "VirtualActuator",
    "bipolar_records",
    "bundle",
    "classify_excitation",
    "creep_per_decade",
    "cycle_labels",
    "default_prominence",
    "estimate_frequency",
    "excitation",
    "find_reversals",
    "frequency_key",
    "group_key",
    "group_label",
    "hysteresis_only",
    "hysteresis_percent",
    "input_noise_sd",
    "label_frequencies",
    "load",
    "load_bouc_wen_benchmark",
    "load_micromanipulator_reference",
    "load_mr_damper",
    "load_piezo_actuator_150v",
    "load_piezo_micromanipulator",
    "loop_width",
    "read_csv",
    "read_hdf5",
    "read_mat",
    "read_npz",
    "read_table",
    "shared_data_root",
    "sidecar_path",
    "split_by_frequency",
    "split_cycles",
    "write_csv",
    "write_npz",
]
