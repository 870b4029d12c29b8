"""Regression: on a small deforming scene the proposed variant beats the deformed baseline on
the common pixel set (DESIGN section 10), through the experiments' own code path
(``experiment_runs.run_scene``: same data, same steps, evaluation on unseen poses).

The size (``SIZE``) is small enough for the suite (about 25 s on a loaded 2-core machine)
and large enough that the baseline predicts hits (at 1,500 steps it often predicts almost
none, and then there are no common pixels to compare on). The tolerance comes from the
measured spread: with this size, seeds 0-4 (torch on one thread; ``python
tests/test_proposed_beats_deformed.py`` prints them; measured after the uncertainty
weighting came to start every task at weight 1, ``TrainConfig.weighting_start``) gave,
against the true reference,

| seed | common pixels | distance MAE ratio | normal error ratio | hit IoU deformed / proposed |
| --- | --- | --- | --- | --- |
| 0 | 404 | 0.403 | 0.417 | 0.693 / 0.920 |
| 1 | 368 | 0.203 | 0.270 | 0.642 / 0.936 |
| 2 | 298 | 0.186 | 0.211 | 0.566 / 0.906 |
| 3 | 303 | 0.275 | 0.292 | 0.554 / 0.890 |
| 4 | 336 | 0.380 | 0.434 | 0.625 / 0.825 |

(ratio: proposed / deformed on the common pixels). The test trains seed 0 and asks, against
both references, for ratios at most ``MAX_RATIO`` (above the largest measured, 0.43; with
the error in log space it was 0.59 and the bound 0.85) and a hit IoU gain of at least
``MIN_IOU_GAIN`` (seed 0 gains 0.227; the smallest measured, seed 4's 0.200, sits at the
bound, which was set below the 0.23 that the earlier start, occlusion at twice a regression
task's weight, gave at worst) and at least ``MIN_COMMON_PIXELS`` common pixels (below the
fewest measured, 298).
"""

import sys

import pytest
import torch

SIZE = dict(resolution=12, poses=8, rays_per_pose=4096, steps=2000, eval_poses=2, width=48,
            height=48, seeds=(0,),
            # val_fraction 0: every pose trains (the evaluation poses are unseen anyway),
            # and no validation passes cost time.
            # lr_mlp 1e-3: the MLP rate these bounds were measured at (the recipe's is 2e-2;
            # at it the IoU gain measured 0.19996, on the bound, not yet remeasured).
            overrides=dict(batch_size=512, log2_table_size=12, width=32, val_fraction=0.0,
                           log_interval=2000, lr_mlp=1e-3))
MAX_RATIO = {"distance_mae": 0.6, "normal_error_deg": 0.6}
MIN_IOU_GAIN = 0.2
MIN_COMMON_PIXELS = 100


def compare(experiment_runs, tmp_path, seed):
    """(proposed, deformed) medians on their common pixel set, trained with ``seed``."""
    size = dict(SIZE, seeds=(seed,))
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


@pytest.mark.slow
def test_proposed_beats_deformed_on_the_common_pixels(empty_scene, core, tmp_path):
    proposed, deformed = compare(core("studies.experiment_runs"), tmp_path, seed=0)
    for reference in ("vs_true", "vs_embedded"):
        p, d = proposed[reference], deformed[reference]
        assert p["compared_rays"] == d["compared_rays"] >= MIN_COMMON_PIXELS
        for key, ratio in MAX_RATIO.items():
            assert p[key] <= ratio * d[key], (reference, key, p[key], d[key])
        assert p["hit_iou"] >= d["hit_iou"] + MIN_IOU_GAIN
        assert p["false_negative_rate"] < d["false_negative_rate"]


if __name__ == "__main__":      # the spread over seeds behind the tolerance
    import importlib
    import pathlib
    import tempfile

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    experiment_runs = importlib.import_module("vdnif_addon.studies.experiment_runs")
    for seed in map(int, sys.argv[1:] or range(5)):
        with tempfile.TemporaryDirectory() as folder:
            proposed, deformed = compare(experiment_runs, pathlib.Path(folder), seed)
        p, d = proposed["vs_true"], deformed["vs_true"]
        print(f"seed {seed}: common pixels {p['compared_rays']}, ratio distance MAE "
              f"{p['distance_mae'] / d['distance_mae']:.3f}, normal error "
              f"{p['normal_error_deg'] / d['normal_error_deg']:.3f}; hit IoU deformed "
              f"{d['hit_iou']:.3f}, proposed {p['hit_iou']:.3f}", flush=True)
