"""Hash tables sized to the scene: a grid's table holds every vertex its finest level can read
at points of the scene's occupied voxels, and no more, up to the setting's size. Checked
against the rows the encoder's kernel reads (a dense level, one row per vertex) and the
vertices of the cells a voxel overlaps, counted by brute force."""

import itertools

import numpy as np
import pytest
import torch

from vdnif_addon.geometry.voxels import build_grid
from vdnif_addon.model.encoding import HashGrid, readable_vertices, scene_log2_table_size
from vdnif_addon.model.network import IntersectionNetwork, sized_to_scene
from vdnif_addon.settings import NetworkConfig, level_resolutions


def overlapped_vertices(cells, resolution, across):
    """Brute force: the vertices of every level cell that a voxel of ``cells`` (ijk) overlaps,
    the grid ``across`` voxels across the unit cube."""
    found = set()
    for cell in cells.tolist():
        spans = []
        for c in cell:
            low = int(np.floor(c / across * resolution))
            high = min(int(np.floor((c + 1) / across * resolution)), resolution - 1)
            spans.append(range(low, high + 2))
        found.update(itertools.product(*spans))
    return found


def rows_read(resolution, points):
    """Rows of a dense one-level grid (a row per vertex) that the encoder's kernel reads with
    a weight at ``points``: those its gradient reaches."""
    grid = HashGrid(levels=1, base_resolution=resolution, log2_table_size=22, feature_dim=1)
    assert grid.dense_levels == 1
    grid(points).sum().backward()
    return int((grid.table.grad[:, 0] != 0).sum())


@pytest.mark.parametrize("resolution, across", [(40, 7), (64, 34), (128, 34), (21, 7), (5, 9)])
def test_a_scene_reads_no_more_vertices_than_it_is_sized_for(resolution, across):
    """Random voxels of a grid ``across`` voxels wide (level cells per voxel from 0.56 to
    5.7, a whole number at 21 / 7), points inside them, on their faces and at their corners."""
    rng = np.random.default_rng(resolution + across)
    every = np.stack(np.meshgrid(*[np.arange(across)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = every[rng.choice(len(every), size=min(40, len(every) // 3), replace=False)]
    inside = (cells[:, None] + rng.uniform(0, 1, (len(cells), 400, 3))).reshape(-1, 3)
    corners = (cells[:, None] + np.array(list(itertools.product((0, 1), repeat=3)))).reshape(-1, 3)
    points = torch.tensor(np.concatenate([inside, corners]) / across, dtype=torch.float32)
    bound = readable_vertices(resolution, len(cells), across)
    brute = overlapped_vertices(cells, resolution, across)
    # float32 coordinates may round a voxel's face into the cell below: the bound allows it
    assert rows_read(resolution, points) <= bound
    assert len(brute) <= bound <= 3 * len(brute)


def test_a_table_holds_the_vertices_its_scene_reads_up_to_the_setting():
    # 100 voxels 34 across: the finest level (128 cells) reads at most 100 * 6**3 vertices
    assert readable_vertices(128, 100, 34) == 21_600
    assert scene_log2_table_size(16, 2, 64, 2.0, 100, 34) == 15          # 2**15 >= 21,600
    assert scene_log2_table_size(14, 2, 64, 2.0, 100, 34) == 14          # the setting caps it
    assert scene_log2_table_size(16, 2, 64, 2.0, 10_000, 34) == 16
    # a level has no more vertices than (res + 1)**3, and one voxel still gets rows
    assert readable_vertices(4, 10**6, 2) == 125
    assert scene_log2_table_size(16, 1, 4, 2.0, 10**6, 2) == 7
    assert scene_log2_table_size(16, 1, 1, 2.0, 1, 34) == 3               # 8 vertices


def rod(radius, length=1.0, sides=12):
    """A closed cylinder along z: (vertices, triangles)."""
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], 1)
    vertices = np.concatenate([np.c_[ring, np.zeros(sides)], np.c_[ring, np.full(sides, length)],
                               [[0, 0, 0], [0, 0, length]]])
    triangles = []
    for i in range(sides):
        j = (i + 1) % sides
        triangles += [[i, j, sides + i], [j, sides + j, sides + i],
                      [2 * sides, j, i], [2 * sides + 1, sides + i, sides + j]]
    return vertices, np.array(triangles)


def test_a_thin_rod_gets_smaller_tables_and_a_thick_one_the_setting():
    """At the recipe's 32 voxels: a rod 1/100 of its length across occupies 4 voxels a slice,
    whose encoder's finest level (128 cells) reads fewer vertices than 2**16 (a half table);
    its normal field's (256 cells) may read more than 2**16 and keeps 2**17. A rod a quarter
    of its length across reads more than the default tables hold, and keeps them."""
    config = NetworkConfig()
    thin, thick = build_grid(*rod(0.005), 32), build_grid(*rod(0.125), 32)
    assert len(thin.cells) == 4 * 34 and len(thick.cells) > 500
    small = sized_to_scene(config, len(thin.cells), int(thin.dims.max()))
    assert (small.log2_table_size, small.normal_log2_table_size) == (15, 17)
    assert sized_to_scene(config, len(thick.cells), int(thick.dims.max())) == config
    # the smaller tables still hold every vertex the thin rod's voxels can read
    for levels, log2_size in ((small.levels, small.log2_table_size),
                              (small.normal_levels, small.normal_log2_table_size)):
        finest = level_resolutions(levels, config.base_resolution, config.growth)[-1]
        assert len(overlapped_vertices(thin.cells, finest, int(thin.dims.max()))) <= 2**log2_size
    rows = {name: IntersectionNetwork(c).encoder.grid.table.shape[0]
            for name, c in (("full", config), ("sized", small))}
    assert rows == {"full": 2 * 2**16, "sized": 2 * 2**15}
