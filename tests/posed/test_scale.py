"""Scale: the same object-unit figures at any supported size, a clear refusal outside
(``limits.MIN_OBJECT_SIZE`` .. ``MAX_OBJECT_SIZE``, DESIGN section 2).

What runs is the references path of ``references --scale S`` (apply_scale, capture, the walk,
the embedded and true references and their metrics) on the arm (3 units) at R 8, one unseen
pose, 32 x 32: it exercises every unit-dependent step but the network (whose inputs are
normalized to the grid, so it never sees the scale).
"""

import pytest

SUPPORTED = (1e-3, 1.0, 1e3, 1e8)
REFUSED = (1e-12, 1e-8, 1e12)
FIGURES = ("distance_mae", "distance_mae_voxels", "normal_error_deg", "hit_iou")


def _references(core, scale):
    obj = core("blender.scenes").demo_scene("arm")
    core("blender.extremes").apply_scale(obj, scale)
    poses = core("blender.poses")
    spec = poses.evaluation_spec(poses.PoseSpec(count=1))
    capture = core("blender.capture_scene").capture(obj, 8, spec, deform_corners=False)
    report = core("posed.generate").reference_run(obj, capture, 32, 32)
    return report["embedded_vs_true"]


@pytest.fixture(scope="module")
def at_unit_scale(extension):
    import importlib

    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    return _references(lambda name: importlib.import_module(
        f"{extension.__name__}.vdnif_addon.{name}"), 1.0)


@pytest.mark.parametrize("scale", SUPPORTED)
def test_object_unit_figures_do_not_depend_on_scale(empty_scene, core, at_unit_scale, scale):
    figures = _references(core, scale)
    assert at_unit_scale["compared_rays"] > 100
    for name in FIGURES:
        assert figures[name] == pytest.approx(at_unit_scale[name], rel=0.05, abs=1e-9), name


@pytest.mark.parametrize("scale", REFUSED)
def test_sizes_outside_the_supported_range_are_refused(empty_scene, core, scale):
    limits = core("limits")
    with pytest.raises(core("errors").VDNIFError,
                       match=rf"'Arm' is {3 * scale:.3g} units across, outside the supported "
                             rf"{limits.MIN_OBJECT_SIZE:g}..{limits.MAX_OBJECT_SIZE:g}"
                       .replace("+", r"\+")):
        _references(core, scale)
