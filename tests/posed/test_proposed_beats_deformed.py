"""Regression: on a small deforming scene the proposed variant beats the deformed baseline on
the common pixel set (DESIGN section 10), through the experiments' own code path
(``experiment_runs.run_scene``: same data, same steps, evaluation on unseen poses).

The size (``SIZE``) is small enough for the suite (about 1 min on a loaded 2-core machine)
and large enough that the baseline predicts hits. Both variants train at the recipe's rates
and calibrate their thresholds on held-out poses (``val_fraction``), as every trained model
does, with the MLPs in float32. The bounds come from the measured spread: with this size,
seeds 0-4 (torch on one thread, a 2-core Zen 5 EPYC; ``python
tests/posed/test_proposed_beats_deformed.py`` prints them) gave, against the true reference,

| seed | common pixels | distance MAE ratio | normal error ratio | hit IoU deformed / proposed |
| --- | --- | --- | --- | --- |
| 0 | 414 | 0.297 | 0.359 | 0.795 / 0.948 |
| 1 | 445 | 0.255 | 0.287 | 0.818 / 0.956 |
| 2 | 450 | 0.221 | 0.261 | 0.807 / 0.960 |
| 3 | 453 | 0.372 | 0.338 | 0.813 / 0.953 |
| 4 | 435 | 0.227 | 0.235 | 0.812 / 0.958 |

(ratio: proposed / deformed on the common pixels). The test trains seed 0 and asks, against
both references, for ratios at most ``MAX_RATIO`` (0.4: the worst seed's 0.372 with room for
a platform's rounding, and still a cut of more than half), a hit IoU gain of at least
``MIN_IOU_GAIN`` (0.1; the smallest measured is 0.138), fewer holes, and at least
``MIN_COMMON_PIXELS`` common pixels (about half the fewest measured, 414). With the normal
read from a field at the hit (``normal_mode`` "hit", both variants) the baseline's hit IoU
rose from 0.57-0.74 to 0.80-0.82 and proposed's stayed at 0.95-0.97, so the gain bound, 0.2
with the normal head, is lower.

Why float32: the default precision trains the MLPs in bfloat16 where the CPU has the
instructions, and its rounding differs from one CPU's kernels to another's. On the same
machine at the default precision (AVX-512 BF16, no AMX) the five seeds' ratios were
0.245-0.327 for the distance and 0.258-0.404 for the normal, seed 0's normal the worst,
against float32's 0.221-0.372 and 0.235-0.359: no worse on the whole, but seed 0 alone
crosses the bound on one CPU and not on another. The quick test below trains at the default
precision.
"""

import sys

import pytest
import torch

SIZE = dict(resolution=12, poses=8, rays_per_pose=4096, steps=2000, eval_poses=2, width=48,
            height=48, seeds=(0,),
            # log_interval 500: four validations, too few for the stopping rule to end a
            # run early; the thresholds are calibrated on the held-out poses after training.
            overrides=dict(batch_size=512, log2_table_size=12, width=32, log_interval=500,
                           precision="float32"))
MAX_RATIO = {"distance_mae": 0.4, "normal_error_deg": 0.4}
MIN_IOU_GAIN = 0.1
MIN_COMMON_PIXELS = 225
QUICK_SIZE = dict(SIZE, rays_per_pose=2048, steps=800,     # at the default precision
                  overrides={**{key: value for key, value in SIZE["overrides"].items()
                                if key != "precision"}, "log_interval": 200})
QUICK_MIN_IOU_GAIN = 0.15
QUICK_MIN_COMMON_PIXELS = 175


def compare(experiment_runs, tmp_path, seed, size=SIZE):
    """(proposed, deformed) medians on their common pixel set, trained with ``seed``."""
    size = dict(size, seeds=(seed,))
    run = experiment_runs.Experiment(size, tmp_path, tmp_path, "cpu", None, ("arm",))
    # One torch thread: on a loaded 2-core machine two threads oversubscribe the cores
    # (7-25x slower, docs/performance.md); the figures do not depend on it beyond rounding.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        runs = experiment_runs.run_scene(run, "arm", ("deformed", "proposed"))
    finally:
        torch.set_num_threads(threads)
    return runs.medians["proposed"], runs.medians["deformed"]


def check_claim(proposed, deformed, min_common_pixels, min_iou_gain):
    for reference in ("vs_true", "vs_embedded"):
        p, d = proposed[reference], deformed[reference]
        assert p["compared_rays"] == d["compared_rays"] >= min_common_pixels
        for key, ratio in MAX_RATIO.items():
            assert p[key] <= ratio * d[key], (reference, key, p[key], d[key])
        assert p["hit_iou"] >= d["hit_iou"] + min_iou_gain
        assert p["false_negative_rate"] < d["false_negative_rate"]


@pytest.mark.slow
def test_proposed_beats_deformed_on_the_common_pixels(empty_scene, core, tmp_path):
    proposed, deformed = compare(core("studies.experiment_runs"), tmp_path, seed=0)
    check_claim(proposed, deformed, MIN_COMMON_PIXELS, MIN_IOU_GAIN)


def test_proposed_beats_deformed_quickly(empty_scene, core, tmp_path):
    """The claim at ``QUICK_SIZE``, in the quick subset."""
    proposed, deformed = compare(core("studies.experiment_runs"), tmp_path, seed=0,
                                 size=QUICK_SIZE)
    check_claim(proposed, deformed, QUICK_MIN_COMMON_PIXELS, QUICK_MIN_IOU_GAIN)


if __name__ == "__main__":      # the spread over seeds behind the tolerance
    import importlib
    import pathlib
    import tempfile

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
    experiment_runs = importlib.import_module("vdnif_addon.studies.experiment_runs")
    for seed in map(int, sys.argv[1:] or range(5)):
        with tempfile.TemporaryDirectory() as folder:
            proposed, deformed = compare(experiment_runs, pathlib.Path(folder), seed)
        p, d = proposed["vs_true"], deformed["vs_true"]
        print(f"seed {seed}: common pixels {p['compared_rays']}, ratio distance MAE "
              f"{p['distance_mae'] / d['distance_mae']:.3f}, normal error "
              f"{p['normal_error_deg'] / d['normal_error_deg']:.3f}; hit IoU deformed "
              f"{d['hit_iou']:.3f}, proposed {p['hit_iou']:.3f}", flush=True)
