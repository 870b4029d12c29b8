"""The occlusion threshold's calibration, threshold by threshold: a trained model's holes and
extras on the calibration views of its held-out poses (the rays training calibrates on,
DESIGN section 8) at every threshold the calibration may choose, as shares of the views'
rays that the reference hits, with the threshold each rule picks: the larger of the two
least (training's rule, ``training.validation.calibrate_threshold``) and, beside it, their
sum least (the rule before it).

    python vdnif_addon/batch.py -- dataset --mesh DIR/text.obj --rig armature \\
        --resolution 96 --seed 1 --out out/text-data
    python tools/calibration_curve.py --model M.vdnif --data out/text-data --json OUT.json

``--model`` and ``--data`` repeat in pairs; the JSON holds one record per model under
``curves``, in their order. It refuses to replace a file it did not write, or one it reads.

The dataset must be made with the options the model was trained with (scene, rig,
resolution, seed): its rays depend only on them, so it holds the rows training held out.
The held-out poses are the model's own (``training.val_poses``), checked against the split
that training makes.
"""

import argparse
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402

FORMAT = "vdnif-calibration-curves"
"""The JSON's format mark: the output rule lets the tool replace only its own files."""


def curve(model_path, data_folder):
    """The record of ``model_path``'s calibration curve on ``data_folder`` (``main`` writes
    the records together with their provenance)."""
    import torch

    from vdnif_addon.model.model_file import load_model
    from vdnif_addon.settings import TrainConfig
    from vdnif_addon.training.data import split_data
    from vdnif_addon.training.dataset import read_dataset
    from vdnif_addon.training.distributed import ProcessGroup
    from vdnif_addon.training.validation import (
        THRESHOLD_BINS,
        THRESHOLD_RANGE,
        head_outputs,
        least_threshold,
        threshold_errors,
    )

    started = time.perf_counter()
    network, meta = load_model(model_path)
    network.eval()
    dataset, shards = read_dataset(data_folder)
    header = dataset.header
    if not header.view_rays:
        raise VDNIFError(f"dataset '{data_folder}' has no calibration views")
    if abs(header.voxel_size - meta.grid.voxel_size) > 1e-9 * meta.grid.voxel_size:
        raise VDNIFError(f"dataset '{data_folder}' has voxels of {header.voxel_size}, model "
                         f"'{model_path}' of {meta.grid.voxel_size}: make it with the "
                         "model's resolution")
    if [dict(pose) for pose in dataset.poses] != [dict(pose) for pose in meta.train_poses]:
        raise VDNIFError(f"dataset '{data_folder}' holds other poses than model "
                         f"'{model_path}' was trained on: make it with the model's options "
                         "(scene, rig, poses, seed)")
    config = TrainConfig(**{key: value for key, value in meta.training.config.items()
                            if key in TrainConfig.__dataclass_fields__})
    _, _, views, held_out = split_data(shards, config, header.heads.network_heads(),
                                       torch.device("cpu"), ProcessGroup(),
                                       header.rays_per_pose)
    if tuple(held_out) != tuple(meta.training.val_poses):
        raise VDNIFError(f"dataset '{data_folder}' holds out the poses {held_out}, model "
                         f"'{model_path}' held out {list(meta.training.val_poses)}: the model was "
                         "trained with another seed")
    outputs = head_outputs(network, views)
    holes, extras = threshold_errors(outputs, views)
    hits = holes[-1]                    # at threshold 1 every hit ray is a hole
    misses = extras[0]                  # at threshold 0 every missed ray is an extra
    low, high = (round(edge * THRESHOLD_BINS) for edge in THRESHOLD_RANGE)
    return {
        "what": "holes and extras (shares of the reference's hit rays) of one model on its "
                "held-out poses' calibration views at each occlusion threshold, and the "
                "threshold each calibration rule picks (tools/calibration_curve.py)",
        "model": str(model_path), "data": str(data_folder),
        "stored_thresholds": {"occlusion": meta.thresholds.occlusion,
                              "candidate": meta.thresholds.candidate},
        "held_out_poses": list(held_out), "rays_in_cells": int(hits + misses),
        "hit_rays": int(hits),
        # training's rule (calibrate_threshold) and the one before it, on the same counts
        "larger_least": least_threshold([max(h, e) for h, e in zip(holes, extras)]),
        "sum_least": least_threshold([h + e for h, e in zip(holes, extras)]),
        "rows": [{"occlusion": k / THRESHOLD_BINS, "holes": holes[k] / hits,
                  "extras": extras[k] / hits} for k in range(low, high + 1)],
        "seconds": time.perf_counter() - started,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=pathlib.Path, action="append", required=True,
                        help="a trained model (repeatable, each with its --data)")
    parser.add_argument("--data", type=pathlib.Path, action="append", required=True,
                        help="its dataset folder, made with the model's options")
    parser.add_argument("--json", type=pathlib.Path, required=True, metavar="OUT",
                        help="where to write the curves, in the models' order")
    args = parser.parse_args(argv)
    if len(args.model) != len(args.data):
        raise VDNIFError(f"{len(args.model)} --model but {len(args.data)} --data: give each "
                         "model its dataset")
    from vdnif_addon.model.provenance import stamp
    from vdnif_addon.output_rule import run_inputs
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    inputs = [(model, "the model file") for model in args.model] + [
        (path, "a dataset file") for data in args.data if data.is_dir()
        for path in data.iterdir()]
    with run_inputs(inputs):            # the output rule, before any work
        check_output_file(args.json, "--json", "json")
    records = []
    for model, data in zip(args.model, args.data):
        record = curve(model, data)
        records.append(record)
        print(f"{model}: stored {record['stored_thresholds']['occlusion']}, larger least "
              f"{record['larger_least']}, sum least {record['sum_least']} "
              f"({record['hit_rays']:,} hit rays of the {record['rays_in_cells']:,} that "
              "cross occupied cells)")
        for row in record["rows"]:
            print(f"  {row['occlusion']:.2f}: holes {100 * row['holes']:.3f} %, extras "
                  f"{100 * row['extras']:.3f} %")
    write_json_atomic(args.json, stamp({"format": FORMAT, "curves": records}), "--json",
                      indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="calibration_curve: error: ")
