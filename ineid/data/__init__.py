"""Datasets: ground-truth sampling, measurement noise, the HDF5 format, CSV import.

Data flow: :class:`DatasetSpec` -> :func:`generate_dataset` (in memory) or
:func:`write_dataset` (streamed to a file) -> :func:`load_dataset` -> identify / learn.
A recording from a real arm enters through :func:`read_recording_csv`.
"""

from __future__ import annotations

from ineid.data.dataset.read import iter_dataset, load_dataset, read_meta
from ineid.data.dataset.schema import FORMAT, VERSION, Dataset, DatasetMeta, assemble_theta, model_from_meta
from ineid.data.dataset.write import DatasetWriter, save_dataset
from ineid.data.recordings.csv_import import csv_columns, write_recording_csv
from ineid.data.recordings.pipeline import read_recording_csv
from ineid.data.synthesis.generate import DatasetSpec, generate_dataset, write_dataset
from ineid.data.synthesis.noise import NoiseModel
from ineid.data.synthesis.sampling import (
    Combination,
    FrameSampling,
    ParameterSampling,
    sample_configurations,
    sample_frames,
    sample_link_parameters,
)

__all__ = [
    "FORMAT",
    "VERSION",
    "Combination",
    "Dataset",
    "DatasetMeta",
    "DatasetSpec",
    "DatasetWriter",
    "FrameSampling",
    "NoiseModel",
    "ParameterSampling",
    "assemble_theta",
    "csv_columns",
    "generate_dataset",
    "iter_dataset",
    "load_dataset",
    "model_from_meta",
    "read_meta",
    "read_recording_csv",
    "sample_configurations",
    "sample_frames",
    "sample_link_parameters",
    "save_dataset",
    "write_dataset",
    "write_recording_csv",
]
