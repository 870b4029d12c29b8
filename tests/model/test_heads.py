"""Model only what the scene requires (DESIGN section 7): a material head over the material
slots that faces use, the material pass still in the slots the user knows, and the static
variant for a scene that nothing deforms, in the CLI and the UI."""

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest
import scene_builders as sb
from batch_runner import error_lines, run_batch
from blender_exr import read_multilayer

COLORS = {0: (1, 1, 0, 1), 1: (1, 0, 0, 1), 2: (0, 1, 0, 1), 3: (0, 0, 1, 1)}
TINY = dict(steps=5, batch_size=256, log2_table_size=10, device="cpu")


def four_slot_box():
    """A box with 4 material slots whose faces use slots 1 (x < middle) and 3 only."""
    import bpy

    box = sb.lattice_box((2, 2, 2), 0.5)
    for slot, color in COLORS.items():
        material = bpy.data.materials.new(f"Slot{slot}")
        material.use_nodes = True
        material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = color
        box.data.materials.append(material)
    for polygon in box.data.polygons:
        polygon.material_index = 1 if polygon.center.x < 0.5 else 3
    return box


@pytest.mark.slow
def test_material_head_counts_the_slots_faces_use(empty_scene, core, tmp_path):
    import bpy
    from mathutils import Vector

    box = four_slot_box()
    box.rotation_euler.z = 0.4          # world normals differ from the object's own
    box.scale.z = 1.5
    bpy.context.view_layer.update()
    mesh = core("blender.read_mesh").read_rest_mesh(box)
    assert mesh.material_count == 2 and mesh.material_slots.tolist() == [1, 3]
    assert sorted(np.unique(mesh.material_index)) == [0, 1]
    np.testing.assert_allclose(mesh.albedo_table(), [COLORS[1][:3], COLORS[3][:3]])
    heads = mesh.heads()
    assert heads["material"] and heads["material_count"] == 2
    assert heads["material_slots"] == [1, 3]

    captured = core("blender.capture_scene").capture(box, 8)
    header = core("posed.generate").generate_dataset(box, captured, tmp_path / "data", 512)
    assert header.heads.material_slots == (1, 3)
    _, [shard] = core("training.dataset").read_dataset(tmp_path / "data")
    assert set(np.unique(shard["material"][shard["hit"] == 1])) == {0, 1}
    model = tmp_path / "box.vdnif"
    core("training.fit").fit_model(tmp_path / "data", "lsnif", model, TINY)
    network, metadata = core("model.model_file").load_model(model)
    assert network.config.heads.sizes()["material"] == 2       # not 4 slots
    assert metadata.material_slots == (1, 3)

    evaluation = core("inference.evaluation")
    evaluation.check_model_fits(model, metadata, captured.mesh, captured.grid)
    stale = dataclasses.replace(metadata, material_slots=(0, 1))
    with pytest.raises(core("errors").VDNIFError,
                       match=r"knows the materials of slots \[0, 1\], 'Box' uses slots "
                             r"\[1, 3\]: train it again"):
        evaluation.check_model_fits(model, stale, captured.mesh, captured.grid)

    # The material pass in the slots of Blender's own faces, through an exact network.
    from oracle_network import OracleNetwork

    neural = core("posed.render")
    oracle = neural.SceneModel(network=OracleNetwork(captured.mesh, captured.grid),
                               metadata=metadata, grid=captured.grid, path="oracle",
                               device="cpu")
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.5, -4.0, 1.7), (1.3, 0.0, 0.0)
    bpy.context.view_layer.update()
    origins, directions = neural.camera_rays(camera, 24, 16)
    result = neural.render_rays(box, captured, oracle, {"frame": 1.0}, origins, directions)
    core("blender.steps").write_passes(tmp_path / "r", result.predicted, 16, 24,
                                      slots=captured.mesh.material_slots,
                                      world_matrix=box.matrix_world)
    _, read = read_multilayer(tmp_path / "r" / "passes.exr", 24, 16)
    material = read["IndexMA"][..., 0].ravel()
    normal = read["Normal"][..., :3].reshape(-1, 3)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    casts = [empty_scene.ray_cast(depsgraph, Vector(o), Vector(d))
             for o, d in zip(origins, directions)]
    hit = np.array([c[0] for c in casts])
    slots = np.array([box.data.polygons[c[3]].material_index for c in casts if c[0]])
    assert set(slots.tolist()) == {1, 3}
    np.testing.assert_array_equal(result.predicted.hit, hit)
    np.testing.assert_array_equal(material[hit], slots)
    # Blender's world-space normals, as the Cycles Normal pass holds them
    np.testing.assert_allclose(normal[hit], [c[2] for c in casts if c[0]], atol=1e-5)


def test_choose_variant(core):
    choose = core("model.variants").choose_variant
    assert choose(None, False) == ("proposed", None)
    variant, note = choose(None, True)
    assert variant == "lsnif" and "static variant lsnif" in note
    assert choose("lsnif", True) == ("lsnif", None) and choose("deformed", False) == (
        "deformed", None)
    variant, note = choose("proposed", True)
    assert variant == "proposed" and "gains nothing over the static variant lsnif" in note


@pytest.fixture(scope="module")
def static_blend(tmp_path_factory):
    """A .blend with a tetrahedron that nothing deforms."""
    folder = tmp_path_factory.mktemp("static")
    mesh, blend = folder / "tri.obj", folder / "static.blend"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    script = (f"import bpy; bpy.ops.wm.read_homefile(use_empty=True); "
              f"bpy.ops.wm.obj_import(filepath={str(mesh)!r}); "
              f"bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r})")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True)
    return blend


@pytest.mark.slow
@pytest.mark.parametrize("asked, trained, note", [
    ([], "lsnif", "'tri': no armature or lattice deforms it: training the static variant "
                  "lsnif"),
    (["--variant", "proposed"], "proposed", "'tri': no armature or lattice deforms it: the "
     "deformation-aware variant proposed gains nothing over the static variant lsnif here"),
])
def test_train_picks_the_static_variant_unless_asked(static_blend, tmp_path, asked, trained,
                                                     note):
    code, printed, err = run_batch(
        "train", "--blend", static_blend, "--object", "tri", "--resolution", 8,
        "--rays-per-pose", 64, "--steps", 5, "--batch", 256, "--log2-table-size", 10,
        "--out", tmp_path / "m.vdnif", "--json", tmp_path / "t.json", *asked)
    assert code == 0 and not error_lines(err), err
    assert note in err and f"trained {trained} on 'tri'" in printed
    summary = json.loads((tmp_path / "t.json").read_text())
    assert summary["variant"] == trained
    assert summary["network_config"]["pe_bands"] == (0 if trained == "lsnif" else 3)


def test_ui_trains_the_static_variant_automatically(empty_scene, extension):
    import bpy

    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    settings = cube.vdnif
    assert settings.variant == "auto"
    for name, value in dict(resolution=8, rays_per_pose=64, steps=5, batch_size=256,
                            log2_table_size=10, base_resolution=16, width=16,
                            depth=1).items():
        setattr(settings, name, value)
    bpy.ops.vdnif.generate_dataset()
    assert settings.parsed("dataset_info")["variant"] == "lsnif"
    bpy.ops.vdnif.train()
    assert settings.parsed("model_info")["variant"] == "lsnif"
    storage = extension.storage
    _, metadata = extension.vdnif_addon.model.model_file.load_model(storage.model_path(cube))
    assert metadata.network_config.pe_bands == 0          # the variant's own bands
    settings.variant = "proposed"                             # asked: it wins
    assert settings.chosen_variant() == ("proposed", "no armature or lattice deforms it: "
                                         "the deformation-aware variant proposed gains "
                                         "nothing over the static variant lsnif here")
