"""The Shaded pass toggle: the frame's EXR holds Shaded (and its PNG preview lies beside it)
only while its toggle is on; on alone, it casts the AO and shadow rays it is made of, lit by
the scene's first sun or point light and its world as Blender holds them."""

import importlib

import bpy
import numpy as np
import pytest
from blender_exr import pass_names, read_multilayer
from conftest import EXTENSION_MODULE
from test_compositor_output import HEIGHT, WIDTH, random_passes
from test_pass_toggles import random_secondary


def module(name):
    return importlib.import_module(f"{EXTENSION_MODULE}.{name}")


@pytest.mark.parametrize("names", [("shaded",), ("ao", "shadow")])
def test_the_shaded_pass_goes_into_the_frames_exr_while_toggled(empty_scene, core, tmp_path,
                                                                names):
    rng = np.random.default_rng(11)
    passes = random_passes(core, rng)
    secondary = random_secondary(core, passes, rng)
    shaded = rng.uniform(0.0, 3.0, (len(passes.hit), 3)).astype(np.float32)
    written = core("blender.steps").write_passes(tmp_path, passes, HEIGHT, WIDTH, frame=2,
                                                secondary=secondary, secondary_names=names,
                                                shaded=shaded)
    exr = tmp_path / "passes.0002.exr"
    titles = {"ao": "AO", "shadow": "Shadow", "shaded": "Shaded"}
    assert pass_names(exr) == {"Combined", "Depth", "Normal", "DiffCol", "IndexMA",
                               *(titles[name] for name in names)}
    assert ((tmp_path / "shaded.0002.png") in written) == ("shaded" in names)
    if "shaded" in names:          # linear values as they are, above 1 too
        _, read = read_multilayer(exr, WIDTH, HEIGHT)
        np.testing.assert_allclose(read["Shaded"][..., :3], shaded.reshape(HEIGHT, WIDTH, 3),
                                   rtol=1e-6)


def mesh_object(scale=1.0):
    mesh = bpy.data.meshes.new("M")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("M", mesh)
    obj.scale = (scale,) * 3
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.update()
    return obj


def add_light(kind, energy, colour, location=(0.0, 0.0, 5.0)):
    light = bpy.data.objects.new(kind, bpy.data.lights.new(kind, kind))
    light.data.energy, light.data.color, light.location = energy, colour, location
    bpy.context.scene.collection.objects.link(light)
    bpy.context.view_layer.update()
    return light


def test_shaded_alone_casts_the_rays_it_is_made_of_lit_by_the_scene(empty_scene, core):
    obj = mesh_object(scale=2.0)
    settings = obj.vdnif
    secondary_settings = module("operators.passes").secondary_settings
    assert not (settings.pass_ao or settings.pass_shadow or settings.pass_shaded)
    assert secondary_settings(bpy.context, obj) is None, "nothing toggled: no rays"
    settings.pass_shaded = True
    assert module("viewer").secondary_names(settings) == ("shaded",)
    cast = secondary_settings(bpy.context, obj)
    assert cast is not None, "Shaded needs the AO and shadow rays"
    lighting = core("inference.shading").settings_lighting(cast)
    assert lighting.world == (0.0, 0.0, 0.0), "an empty scene has no world: no ambient"
    assert cast.light.source == "the default direction"
    add_light("POINT", 250.0, (1.0, 0.5, 0.25))
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    background.inputs["Strength"].default_value = 2.0
    empty_scene.world = world
    lighting = core("inference.shading").settings_lighting(secondary_settings(bpy.context, obj))
    assert lighting.light.source == "point light 'POINT'"
    np.testing.assert_allclose(lighting.light.position, (0.0, 0.0, 2.5))    # local: / 2
    assert lighting.strength == 250.0 and lighting.unit_scale == pytest.approx(2.0)
    np.testing.assert_allclose(lighting.colour, (1.0, 0.5, 0.25))
    np.testing.assert_allclose(lighting.world, (0.2, 0.4, 0.6), rtol=1e-6)
    world.use_nodes = False
    world.color = (0.05, 0.06, 0.07)
    np.testing.assert_allclose(
        core("inference.shading").settings_lighting(secondary_settings(bpy.context, obj)).world,
        (0.05, 0.06, 0.07), rtol=1e-6)


def test_the_live_preview_shows_the_shaded_image_as_the_user_sees_it(core):
    rng = np.random.default_rng(4)
    passes = random_passes(core, rng)
    shaded = rng.uniform(0.0, 1.5, (len(passes.hit), 3))
    shown = core("posed.preview").images(passes, HEIGHT, WIDTH, shaded=shaded)["shaded"]
    codes = core("inference.shading").display_8bit(shaded).reshape(HEIGHT, WIDTH, 3)
    np.testing.assert_allclose(shown[..., :3], codes / 255.0, rtol=1e-6)
    np.testing.assert_array_equal(shown[..., 3], passes.hit.reshape(HEIGHT, WIDTH))
    assert "shaded" not in core("posed.preview").images(passes, HEIGHT, WIDTH)
