"""Training's history as users get it: the records of ``train --json`` and their plot."""

import numpy as np
import pytest

from vdnif_addon.training import history

TASKS = ("occlusion", "distance", "normal")


def progress_records(steps=range(100, 3001, 100), validate_every=3):
    """Records as ``ProgressLog.record`` writes them: the distance loss falls, the occlusion
    loss rises, the weighted total is negative."""
    records = []
    for index, step in enumerate(steps):
        losses = {"occlusion": 0.01 * (1 + step / 1000), "distance": 0.1 * np.exp(-step / 800),
                  "normal": 0.05}
        validation = ({f"loss/{task}": 1.5 * value for task, value in losses.items()}
                      | {"distance_mae": 0.01} if index % validate_every == 0 else None)
        records.append({"step": step, "steps": 3000, "total": -1.38, "losses": losses,
                        "log_variances": {}, "samples_per_s": 1e5, "eta_s": 1.0,
                        "validation": validation})
    return records


def test_records_keep_step_task_losses_and_validation():
    raw = progress_records()
    kept = history.records(raw)
    assert [set(r) for r in kept] == [{"step", "losses", "validation"}] * len(raw)
    assert kept[3]["losses"] == raw[3]["losses"] and kept[3]["validation"] == raw[3]["validation"]
    assert kept[1]["validation"] is None


def _rows_of(image, color):
    """{column: mean row} of the pixels of exactly ``color``."""
    rows, columns = np.nonzero(np.all(np.isclose(image, color, atol=1e-6), axis=2))
    return {c: rows[columns == c].mean() for c in np.unique(columns)}


def test_plot_draws_each_task_where_its_loss_goes():
    image = history.plot(progress_records())
    width, height = history.PLOT_SIZE
    assert image.shape == (height, width, 3) and image.min() >= 0 and image.max() <= 1
    middle = slice(width // 4, width // 2)                      # inside the plot, no legend
    for task, falls in (("distance", True), ("occlusion", False)):
        rows = _rows_of(image[:, middle], history.COLORS[task])
        columns = sorted(rows)
        assert len(columns) > 50, task
        # image rows grow downwards: a falling loss goes down the picture
        left = np.mean([rows[c] for c in columns[:10]])
        right = np.mean([rows[c] for c in columns[-10:]])
        assert (right > left) == falls, task
    # the held-out loss, 1.5 times the training loss, is a second line above it, dashed:
    # in some columns two runs of the colour, in the dashes' gaps one
    distance = np.all(np.isclose(image, history.COLORS["distance"], atol=1e-6), axis=2)
    runs = [np.count_nonzero(np.diff(distance[:, c].astype(int)) == 1)
            for c in range(width // 4, width // 2)]
    assert set(runs) == {1, 2} and runs.count(2) > len(runs) / 3, runs


def test_plot_of_no_records_says_so():
    image = history.plot([])
    assert image.shape[:2] == history.PLOT_SIZE[::-1] and (image < 0.5).any()


def test_font_has_distinct_glyphs_for_every_character():
    shapes = {glyph.tobytes() for glyph in history.GLYPHS.values()}
    assert len(shapes) == len(history.GLYPHS) and history.GLYPHS["0"].shape == (7, 5)
    assert not history.GLYPHS[" "].any() and history.GLYPHS["-"][3].all()


@pytest.mark.parametrize("last, ticks", [(0, [0]), (1, [0, 1]), (2, [0, 1, 2]), (7, [0, 2, 4, 6]),
                                         (3000, [0, 1000, 2000, 3000]), (450, [0, 100, 200, 300,
                                                                               400])])
def test_step_ticks_are_round_and_never_zero_apart(last, ticks):
    """A training of 2 steps (a tiny run) drew ticks 0.5 apart, rounded to 0: a crash."""
    assert history._step_ticks(last) == ticks
