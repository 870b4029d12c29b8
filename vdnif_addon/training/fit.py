"""One trained model from one dataset folder: the step shared by the ``train`` and ``demo``
commands, the experiments and the UI's Train operator.

Reads the shards, builds the variant's configuration with the scene's heads, trains, and
writes the model file with everything rendering needs (grid, heads, albedo table, the
training poses), atomically.
"""

from __future__ import annotations

import pathlib
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from .. import __version__
from ..limits import GROUP_TIMEOUT_S
from ..memory import CPU_TRAINING_ADVICE, TRAINING_ADVICE, check_memory, out_of_memory
from ..model.metadata import DatasetSource, ModelMetadata, albedo_rows
from ..model.model_file import model_bytes, save_model
from ..model.variants import variant_config
from .dataset import ROW_BYTES, read_dataset
from .history import records
from .train import TrainResult, train

TRAINING_MEMORY_COPIES = 2
"""Copies of a dataset's rows in host memory while training starts: the arrays unpacked from
the shards and the tensors made of them."""


def fit_model(
    data_dir: str | pathlib.Path,
    variant: str,
    out: str | pathlib.Path,
    overrides: Mapping[str, Any] | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
    cancel: threading.Event | None = None,
    group_timeout_s: float = GROUP_TIMEOUT_S,
) -> tuple[TrainResult, dict[str, Any]]:
    """Trains ``variant`` on the dataset in ``data_dir`` and writes the model to ``out``.

    ``overrides``: NetworkConfig / TrainConfig fields (steps, batch_size, width, ...);
    ``group_timeout_s``: how long a ``torchrun`` process waits for the others.
    Running out of memory is one line that says what to lower. Returns (the TrainResult, a
    JSON-ready summary); only the main process of a ``torchrun``
    launch writes the file (the summary is then empty on the others).
    """
    chosen = variant_config(variant, **(overrides or {}))
    with out_of_memory("training", TRAINING_ADVICE, CPU_TRAINING_ADVICE):
        started = time.perf_counter()
        # the rows are checked as the training first reads them: one read of the dataset
        data, shards = read_dataset(data_dir, defer_row_check=True)
        read_s = time.perf_counter() - started
        header = data.header
        # rows unpacked from the shards and their tensors, before any is read
        check_memory(f"training on the {data.segments:,} segments of '{data_dir}'",
                     TRAINING_MEMORY_COPIES * data.segments * ROW_BYTES,
                     "train on a smaller dataset (fewer poses or rays per pose)")
        result = train(shards, header, chosen.train, chosen.network, progress=progress,
                       cancel=cancel, group_timeout_s=group_timeout_s)
    result.timings["read_s"] = read_s
    if not result.is_main:
        return result, {}
    # A dataset header that names no used-slot table or mesh fingerprint (the golden arm
    # dataset's, which the recorded loss curve trains on) has a material per slot and
    # leaves the mesh unchecked.
    slots = header.heads.material_slots
    metadata = ModelMetadata(
        object=header.object, object_size=header.object_size, variant=variant,
        network_config=result.network_config, grid=header.grid,
        material_slots=tuple(range(header.heads.material_count)) if slots is None else slots,
        albedo_table=albedo_rows(header.albedo_table), thresholds=result.thresholds,
        train_poses=tuple(dict(pose) for pose in data.poses), training=result.summary(),
        dataset=DatasetSource(folder=str(data_dir), shards=tuple(data.shards),
                              poses=len(data.poses), segments=int(data.segments)),
        vdnif_version=__version__, corners_follow=header.corners_follow)
    started = time.perf_counter()
    # the model's folder once there is a model: a training refused or cancelled leaves none
    # (the caller checked that it can be made: ``safe_io.check_output_file``)
    pathlib.Path(out).parent.mkdir(parents=True, exist_ok=True)
    save_model(out, result.network, metadata)
    result.timings["save_s"] = time.perf_counter() - started
    summary = {"variant": variant, "model": str(out), "model_bytes": model_bytes(out),
               "object": header.object, "segments": data.segments,
               "train": result.info(), "network_config": result.network_config.to_dict(),
               "history": records(result.history)}
    return result, summary
