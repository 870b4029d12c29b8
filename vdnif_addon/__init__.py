"""VDNIF core: the pipeline capture -> voxels -> traverse -> dataset -> network -> train -> render.

Modules at this level use numpy/torch only and never import bpy; everything that reads or
writes a Blender scene lives in the ``blender`` subpackage. Above both sit the studies
(``studies``: demo, experiments, benchmarks) and the batch commands (``cli``); nothing below
them imports them (``tests/project/test_import_graph.py``).
"""

__version__ = "0.1.0"   # kept equal to blender_manifest.toml's version (tested)
