"""The catalogue of bad inputs, continued (``tests/cli/test_bad_inputs.py`` holds the first part
and the rules): work bounded before it starts (memory, disk, shard rows, frame ranges), a
distributed run that never waits forever, and inputs that were silently wrong. Each case
ends with exit code 1 and one ``vdnif: error:`` line, no traceback, and leaves every file
that existed before byte-identical and no temporary file.

Each row of ``CASES`` is (id, arguments, expected message). Arguments name fixtures in
braces as the first part does, plus {port} (a free TCP port) and {blend:NAME}; leading
``NAME=VALUE`` words set environment variables (``VDNIF_MEMORY_LIMIT`` makes a memory
refusal the same on a machine with more memory free than this one).
"""

import dataclasses
import datetime
import json
import os
import re
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import torch
from conftest import REPO
from model_metadata import capture_metadata
from oracle_network import OracleNetwork
from test_bad_inputs import (
    BATCH,
    TIME_LIMIT_S,
    _case_folder,
    _snapshot,
    check_failure,
    trained,  # noqa: F401 - the module's fixture: the arm's dataset and model
)

TRAIN = "train --data {data} --steps 2 --batch 256 --device cpu"
JOIN = "WORLD_SIZE=2 RANK=0 LOCAL_RANK=0 MASTER_ADDR=127.0.0.1 MASTER_PORT={port}"

CASES = [
    # --- frame ranges share the poses' bound
    ("render-frames-a-million", "render --model {model} --out {tmp}/r --frames 1:1048574",
     r"the frame range 1:1048574:1 has 1,048,574 frames, more than the limit 4,096"),
    ("render-frames-beyond-blender", "render --model {model} --out {tmp}/r "
     "--frames 1:99999999999:100000000", r"the frame 99999999999 is outside Blender's frames"),
    # --- memory and disk computed before the work
    ("capture-corners-beyond-memory",
     "VDNIF_MEMORY_LIMIT=8G capture --scene spot --resolution 256 --poses 4096",
     r"capturing 4,096 poses of 'Spot' at resolution 256 \([\d,]+ voxel corners a pose\) "
     r"needs about [\d.]+ GiB of memory, more than the [\d.]+ [GM]iB available here: "
     r"lower --poses "
     r"or --resolution"),
    ("dataset-shard-beyond-limit",
     "dataset --poses 32 --rays-per-pose 4194304 --resolution 8 --out {tmp}/d",
     r"dataset shard 'shard-000000-000032' would hold about [\d,]+ segments, more than the "
     r"limit 268,435,456 \(vdnif_addon/limits.py\): lower --rays-per-pose or --poses"),
    ("dataset-beyond-memory",
     "VDNIF_MEMORY_LIMIT=256M dataset --poses 2 --rays-per-pose 1048576 --resolution 8 "
     "--out {tmp}/d", r"dataset shard 'shard-000000-000002' \([\d,]+ segments\) needs about "
     r"[\d.]+ GiB of memory, more than the 256 MiB available here: lower --rays-per-pose"),
    ("train-scene-dataset-beyond-memory",
     "VDNIF_MEMORY_LIMIT=64M train --scene arm --resolution 8 --poses 2 "
     "--rays-per-pose 262144 --data {tmp}/d --out {tmp}/m.vdnif --steps 2",
     r"dataset shard 'shard-000000-000002' \([\d,]+ segments\) needs about [\d.]+ MiB of "
     r"memory, more than the 64 MiB available here"),
    ("train-dataset-beyond-memory", f"VDNIF_MEMORY_LIMIT=10K {TRAIN} --out {{tmp}}/m.vdnif",
     r"training on the [\d,]+ segments of '.*' needs about [\d.]+ KiB of memory, more than "
     r"the 10 KiB available here: train on a smaller dataset"),
    ("dataset-memory-limit-text", "VDNIF_MEMORY_LIMIT=lots dataset --resolution 8 --poses 2 "
     "--rays-per-pose 64 --out {tmp}/d",
     r"environment variable VDNIF_MEMORY_LIMIT 'lots' is not a number of bytes"),
    # --- distributed training says what it waits for, and for how long
    ("train-second-rank-never-starts", f"{JOIN} {TRAIN} --group-timeout 2 --out {{tmp}}/m.vdnif",
     r"process 0 waited 2 s for the other 1 process\(es\) of WORLD_SIZE=2 to join at "
     r"127.0.0.1:\d+ and they did not: start every rank, or raise --group-timeout"),
    ("train-group-timeout-zero", f"{TRAIN} --group-timeout 0",
     r"--group-timeout 0.0 must be a number in 1..86400"),
    ("train-group-timeout-nan", f"{TRAIN} --group-timeout nan",
     r"--group-timeout nan must be a number in"),
    # --- silently wrong before: refused by name
    ("evaluate-model-of-other-textures", "evaluate --model {bad_model:other_textures} --scene "
     "arm --poses 1 --width 16 --height 16 --json {tmp}/e.json",
     r"was trained on other textures of 'Arm' \(now no image texture in its materials\): "
     r"train it again"),
    ("capture-udim-tile-missing", "capture --blend {blend:udim} --object Plane --resolution 8",
     r"image 'tex.<UDIM>.png' of material 'Tiled' lacks its UDIM tile 1002 \(file "
     r"'.*tex.1002.png'\), which faces of 'Plane' use: it would read as black"),
    ("capture-udim-two-tiles", "capture --blend {blend:udim_both} --object Plane --resolution 8",
     r"image 'tex.<UDIM>.png' of material 'Tiled' is a UDIM image and faces of 'Plane' use its "
     r"tiles 1001, 1002: VDNIF reads one tile \(1001\)"),
]

BLEND_SCRIPT = r"""
import bpy, sys
out = sys.argv[-1]

def arrayed(offset_moves):
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    offset = bpy.data.objects.new("Offset", None)
    bpy.context.scene.collection.objects.link(offset)
    offset.location = (2.5, 0.0, 0.0)
    array = cube.modifiers.new("Array", "ARRAY")
    array.use_relative_offset, array.use_object_offset = False, True
    array.offset_object = offset
    lattice = bpy.data.objects.new("Lattice", bpy.data.lattices.new("Lattice"))
    bpy.context.scene.collection.objects.link(lattice)
    lattice.scale = (8.0, 3.0, 3.0)
    cube.modifiers.new("Lattice", "LATTICE").object = lattice
    offset_moves(offset)
    bpy.ops.wm.save_as_mainfile(filepath=f"{out}/array_{offset_moves.__name__}.blend")

def animated(offset):
    offset.keyframe_insert("location", frame=1)
    offset.location.x = 4.0
    offset.keyframe_insert("location", frame=20)

def on_bone(offset):
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    offset.parent = rig

def still(offset):
    pass

for moves in (animated, on_bone, still):
    arrayed(moves)

bpy.ops.wm.read_homefile(use_empty=True)   # a ball and one loose vertex 1,000 units away
bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0)
ball = bpy.context.active_object
ball.name = "Ball"
ball.data.vertices.add(1)
ball.data.vertices[-1].co = (1000.0, 0.0, 0.0)
bpy.ops.wm.save_as_mainfile(filepath=f"{out}/loose_vertex.blend")

import os                                   # a plane textured by a UDIM image of two tiles
import numpy as np

def udim_plane(name, moved):
    os.makedirs(f"{out}/{name}")
    for number, colour in ((1001, (1, 0, 0, 1)), (1002, (0, 0, 1, 1))):
        tile = bpy.data.images.new(f"t{number}", 4, 4)
        tile.pixels.foreach_set(np.tile(colour, 16).astype(np.float32))
        tile.filepath_raw, tile.file_format = f"{out}/{name}/tex.{number}.png", "PNG"
        tile.save()
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_plane_add()
    plane = bpy.context.active_object
    uv = plane.data.uv_layers.active.data
    for loop in plane.data.polygons[0].loop_indices[:moved]:
        uv[loop].uv.x += 1.0
    image = bpy.data.images.load(f"{out}/{name}/tex.1001.png")
    image.source, image.filepath = "TILED", f"{out}/{name}/tex.<UDIM>.png"
    image.name = "tex.<UDIM>.png"
    material = bpy.data.materials.new("Tiled")
    material.use_nodes = True
    texture = material.node_tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    material.node_tree.links.new(
        texture.outputs["Color"],
        material.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    plane.data.materials.append(material)
    bpy.ops.wm.save_as_mainfile(filepath=f"{out}/{name}.blend")

udim_plane("udim_both", 2)        # two corners moved right: the triangles straddle 1001, 1002
udim_plane("udim", 4)             # every corner in tile 1002, whose file is then missing
os.remove(f"{out}/udim/tex.1002.png")
"""


def _free_port():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def files(trained, tmp_path_factory):  # noqa: F811 - the imported fixture
    data, model = trained
    blends = tmp_path_factory.mktemp("blends")
    subprocess.run([sys.executable, "-c", BLEND_SCRIPT, str(blends)], check=True,
                   capture_output=True, timeout=120)
    from test_bad_inputs_files import _payload, _pickled, _repack

    archive = torch.load(model, weights_only=True)
    inner = _payload(archive)
    inner["metadata"]["grid"]["texture_fingerprint"] = "0" * 64
    other = _repack(archive, _pickled(inner), blends / "other_textures.vdnif")
    inner = _payload(archive)
    assert inner["metadata"]["grid"].pop("texture_fingerprint")
    older = _repack(archive, _pickled(inner), blends / "older.vdnif")
    return {"data": data, "model": model,
            "bad_model:other_textures": other, "model:older": older,
            **{f"blend:{path.stem}": path for path in blends.glob("*.blend")}}


def _command(text, tmp, files):
    """(argv words, environment) of a case's arguments with its placeholders filled."""
    words = text.split()
    for key, value in files.items():
        words = [word.replace("{" + key + "}", str(value)) for word in words]
    words = [word.replace("{tmp}", str(tmp)).replace("{port}", str(_free_port()))
             for word in words]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    while words and re.fullmatch(r"[A-Z_]+=.*", words[0]):
        name, _, value = words.pop(0).partition("=")
        env[name] = value
    return words, env


@pytest.mark.parametrize("case, text, message", CASES, ids=[case[0] for case in CASES])
def test_bad_input_fails_on_one_line_and_changes_nothing(case, text, message, files,
                                                         tmp_path):
    tmp = _case_folder(tmp_path)
    words, env = _command(text, tmp, files)
    watched = [tmp, *(path for key, path in files.items() if "{" + key + "}" in text)]
    before = _snapshot(*watched)
    start = time.monotonic()
    result = subprocess.run([sys.executable, str(BATCH), "--", *words], capture_output=True,
                            text=True, errors="replace", timeout=TIME_LIMIT_S, cwd=REPO,
                            env=env)
    check_failure(result.returncode, result.stderr, message, time.monotonic() - start)
    after = _snapshot(*watched)
    assert {path: digest for path, digest in after.items() if path in before} == before
    left = [path for path in after if path not in before]
    assert not [path for path in left if os.path.basename(path).startswith(".")], left
    assert not (tmp / "d").exists() and not (tmp / "m.vdnif").exists()


def test_the_catalogue_grew_by_the_cases_of_this_file():
    import test_bad_inputs
    import test_bad_inputs_files

    names = [case[0] for case in CASES]
    assert len(set(names)) == len(names)
    assert not set(names) & {case[0] for case in test_bad_inputs.CASES}
    assert not set(names) & {case[0] for case in test_bad_inputs_files.CASES}


STALLED_RANK = """
import datetime, sys, time
import torch.distributed as dist
dist.init_process_group("gloo", timeout=datetime.timedelta(seconds=60))
print("joined", flush=True)
time.sleep(float(sys.argv[1]))
"""


@pytest.mark.slow
def test_a_rank_that_stops_answering_is_named_within_the_timeout(files, tmp_path):
    """The second rank joins and then never reaches a collective (as one stopped with
    SIGSTOP does): the first stops within its --group-timeout, saying what it waited for."""
    port = _free_port()
    env = dict(os.environ, OMP_NUM_THREADS="1", WORLD_SIZE="2", MASTER_ADDR="127.0.0.1",
               MASTER_PORT=str(port))
    stalled = subprocess.Popen([sys.executable, "-c", STALLED_RANK, "60"],
                               env=dict(env, RANK="1"), stdout=subprocess.PIPE, text=True)
    try:
        start = time.monotonic()
        words, _ = _command(f"{TRAIN} --group-timeout 3 --out {{tmp}}/m.vdnif", tmp_path, files)
        result = subprocess.run([sys.executable, str(BATCH), "--", *words], capture_output=True,
                                text=True, timeout=TIME_LIMIT_S, cwd=REPO,
                                env=dict(env, RANK="0", LOCAL_RANK="0"))
        seconds = time.monotonic() - start
    finally:
        stalled.kill()
        stalled.wait()
    check_failure(result.returncode, result.stderr,
                  r"process 0 waited 3 s for the other 1 process\(es\) of the group to reach "
                  r"the same step .*--group-timeout", seconds)
    assert seconds < 60          # the stalled rank's own wait, and torch's default 30 minutes
    assert not (tmp_path / "m.vdnif").exists()


def test_memory_and_disk_refusals_compare_with_what_is_free(tmp_path, monkeypatch, core):
    memory = core("memory")
    errors = core("errors")
    memory.check_memory("a job", 10 << 20, "lower it", available=20 << 20)
    with pytest.raises(errors.VDNIFError, match=r"a job needs about 30 MiB of memory, more "
                       r"than the 20 MiB available here: lower it"):
        memory.check_memory("a job", 30 << 20, "lower it", available=20 << 20)
    monkeypatch.setenv("VDNIF_MEMORY_LIMIT", "1.5G")
    assert memory.available_bytes() <= 1.5 * (1 << 30)
    free = __import__("shutil").disk_usage(tmp_path).free
    memory.check_disk("a shard", free // 2, tmp_path / "new" / "folder", "lower it")
    with pytest.raises(errors.VDNIFError, match=r"a shard needs about .* on disk, more than "
                       r"the .* free at '.*': lower it"):
        memory.check_disk("a shard", free * 2, tmp_path / "new" / "folder", "lower it")
    assert not (tmp_path / "new").exists()


def test_a_frame_range_is_counted_before_it_is_built(core):
    animation = core("posed.animation")
    limits = core("limits")
    assert animation.parse_frames("1:4096") == list(range(1, 4097))
    assert animation.parse_frames("-1048574:1048574:1024") == list(
        range(-1048574, 1048575, 1024))
    started = datetime.datetime.now()
    with pytest.raises(core("errors").VDNIFError, match="more than the limit 4,096"):
        animation.parse_frames("1:4097")
    with pytest.raises(core("errors").VDNIFError, match="outside Blender's frames"):
        animation.parse_frames(f"0:{10**30}:{10**27}")
    assert (datetime.datetime.now() - started).total_seconds() < 1
    assert limits.MAX_FRAMES == limits.MAX_POSES


def test_an_array_of_an_object_that_stays_put_still_captures(files, tmp_path):
    """The control of the refused arrays: the same array before the lattice, its offset
    object still, captures; so does one whose offset object is animated but unread."""
    result = subprocess.run([sys.executable, str(BATCH), "--", "capture", "--blend",
                             str(files["blend:array_still"]), "--object", "Cube",
                             "--resolution", "8", "--poses", "2"], capture_output=True,
                            text=True, timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "captured 'Cube' (lattice)" in result.stdout


@pytest.mark.parametrize("blend", ["blend:array_animated", "blend:array_on_bone"])
def test_an_array_of_a_moving_object_is_followed_by_the_evaluated_surface(files, blend,
                                                                         tmp_path):
    """An array before the rig whose offset object moves with the pose is more than the
    copied modifiers follow (``uncaptured.check_captured`` names it, the test below): the
    capture binds the corners to the evaluated surface instead, and says so."""
    out = tmp_path / "capture.json"
    result = subprocess.run([sys.executable, str(BATCH), "--", "capture", "--blend",
                             str(files[blend]), "--object", "Cube", "--resolution", "8",
                             "--poses", "2", "--json", str(out)], capture_output=True,
                            text=True, timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert json.loads(out.read_text())["corners_follow"] == "evaluated surface"


def test_an_offset_object_the_array_does_not_read_is_not_refused(files, core, extension):
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(files["blend:array_animated"]))
    cube = bpy.data.objects["Cube"]
    cube.modifiers["Array"].use_object_offset = False
    cube.modifiers["Array"].use_relative_offset = True
    core("blender.uncaptured").check_captured(cube)
    cube.modifiers["Array"].use_object_offset = True
    with pytest.raises(core("errors").VDNIFError, match="of object 'Offset', which is animated"):
        core("blender.uncaptured").check_captured(cube)


@pytest.mark.parametrize("fit, width, height", [("AUTO", 40, 30), ("AUTO", 30, 40),
                                                ("HORIZONTAL", 30, 40), ("VERTICAL", 40, 30)])
def test_a_shifted_camera_renders_the_pixels_blender_projects_to(empty_scene, core, fit, width,
                                                                 height):
    """Lens shift moves the image as Blender's own projection of a point does, for every
    sensor fit (it was ignored: the passes did not line up with Blender's render)."""
    import bpy
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (3.0, -4.0, 2.0), (1.1, 0.1, 0.6)
    camera.data.lens, camera.data.sensor_fit = 35.0, fit
    camera.data.shift_x, camera.data.shift_y = 0.31, -0.17
    empty_scene.render.resolution_x, empty_scene.render.resolution_y = width, height
    bpy.context.view_layer.update()
    neural = core("posed.render")
    origins, directions = neural.view_rays(neural.camera_view(camera, width, height), width,
                                           height)
    projected = np.array([world_to_camera_view(empty_scene, camera, Vector(o + 5 * d))[:2]
                          for o, d in zip(origins, directions)])
    column, row = np.meshgrid(np.arange(width), np.arange(height))
    expected = np.stack([(column.ravel() + 0.5) / width, 1 - (row.ravel() + 0.5) / height], 1)
    np.testing.assert_allclose(projected, expected, atol=1e-6)


def test_a_camera_clip_range_hides_what_blender_clips(empty_scene, core):
    """An oracle network (the mesh itself) seen through a camera whose clip start cuts into
    the sphere's near side and whose clip end cuts off its far side: each pixel shows the
    first of Blender's own ray-cast hits whose depth (Blender's projection) lies within the
    clip range, at its distance from the camera."""
    import bpy
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=2.0)
    obj = bpy.context.active_object
    capture = core("blender.capture_scene").capture(obj, 12)
    neural = core("posed.render")
    model = neural.SceneModel(network=OracleNetwork(capture.mesh, capture.grid),
                              metadata=capture_metadata(core, capture), grid=capture.grid,
                              path="oracle", device="cpu")
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.0, -12.0, 0.0), (np.pi / 2, 0.0, 0.0)
    camera.data.lens = 60.0
    camera.data.clip_start, camera.data.clip_end = 10.6, 13.2
    empty_scene.render.resolution_x, empty_scene.render.resolution_y = 24, 24
    bpy.context.view_layer.update()
    view = neural.camera_view(camera, 24, 24)
    origins, directions = neural.view_rays(view, 24, 24)
    with core("posed.geometry").PosedObject(obj, capture, "cpu") as posed_object:
        result = neural.render_view(model, posed_object, posed_object.geometry({"frame": 1.0}),
                                    view, 24, 24, references=True)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    hit, distance = np.zeros(len(origins), bool), np.zeros(len(origins))
    for index, (origin, direction) in enumerate(zip(origins, directions)):
        start = Vector(origin)
        for _ in range(4):                      # each surface crossing, near to far
            found, location, *_ = empty_scene.ray_cast(depsgraph, start, Vector(direction))
            if not found:
                break
            depth = world_to_camera_view(empty_scene, camera, location)[2]
            if depth > camera.data.clip_end:
                break
            if depth >= camera.data.clip_start:
                hit[index], distance[index] = True, (location - Vector(origin)).length
                break
            start = location + Vector(direction) * 1e-4
    assert 20 < hit.sum() < len(hit) - 20        # some pixels clipped away, some seen inside
    for passes in (result.predicted, result.true):
        assert (passes.hit != hit).sum() <= 2, (passes.hit != hit).sum()  # rays on the rim
        both = passes.hit & hit
        np.testing.assert_allclose(passes.distance[both] / result.world_scale[both],
                                   distance[both], atol=2e-3)


def test_a_far_loose_vertex_neither_sizes_nor_frames_the_object(files, tmp_path):
    """One loose vertex 1,000 units from a ball of diameter 2: the ball alone sizes and
    frames it (with a warning naming what was left out), and the references compare its
    rays (they compared none and said "n/a" with success)."""
    blend = str(files["blend:loose_vertex"])
    result = subprocess.run([sys.executable, str(BATCH), "--", "references", "--blend", blend,
                             "--object", "Ball", "--resolution", "8", "--poses", "1",
                             "--width", "16", "--height", "16", "--json",
                             str(tmp_path / "r.json")], capture_output=True, text=True,
                            timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert re.search(r"vdnif: warning: 'Ball': left out 1 loose vertex more than 1 x the main "
                     r"body's size \(2\) away", result.stderr), result.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    error = report["embedded_vs_true"]
    assert error["compared_rays"] > 16 * 16 / 8 and error["hit_iou"] > 0.9


def test_the_framing_rule_keeps_near_pieces_and_leaves_far_ones(core):
    framing = core("geometry.framing")
    box = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    tetra = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    near, far = box + [1.9, 0, 0], box + [2.1 + 1, 0, 0]       # 0.9 and 1.1 sizes apart
    vertices = np.vstack([box, near, far, [[0.5, 0.5, 0.5], [0, -30, 0]]])
    triangles = np.vstack([tetra, tetra[:2] + 4, tetra + 8])
    kept = framing.framing(vertices, triangles, "Thing")
    assert kept.vertices.tolist() == [True] * 8 + [False] * 4 + [True, False]
    assert kept.triangles.tolist() == [True] * 6 + [False] * 4
    assert "1 loose vertex and 1 piece of 4 triangles" in kept.warning
    lo, hi = framing.framing_bounds(vertices, triangles)
    np.testing.assert_allclose([lo, hi], [[0, 0, 0], [2.9, 1, 1]])
    whole = framing.framing(box, tetra)
    assert whole.complete and whole.vertices.all()


def test_nothing_compared_is_an_error_that_says_why(core):
    metrics = core("inference.metrics")
    errors = core("errors")
    metrics.check_compared({"compared_rays": 3, "false_negative_rate": 0.1}, "Arm")
    metrics.check_compared({"compared_rays": 0, "false_negative_rate": 1.0}, "Arm")  # IoU 0
    with pytest.raises(errors.VDNIFError, match="'Arm' compared 0 rays: the true reference "
                       "hits nothing in any view"):
        metrics.check_compared({"compared_rays": 0, "false_negative_rate": None}, "Arm")


def test_a_model_older_than_the_texture_fingerprint_still_evaluates(files, tmp_path):
    """A model file without the texture fingerprint (written before it existed) loads and
    evaluates as before: it is not refused as trained on an edited mesh."""
    result = subprocess.run([sys.executable, str(BATCH), "--", "evaluate", "--model",
                             str(files["model:older"]), "--scene", "arm", "--poses", "1",
                             "--width", "16", "--height", "16"], capture_output=True, text=True,
                            timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "evaluated proposed on 'Arm'" in result.stdout


def test_a_model_trained_on_one_texture_refuses_another_or_none(empty_scene, core):
    """A red-textured cube's model on the same cube textured blue, or untextured: refused
    by the texture fingerprint (the mesh's own fingerprint holds no image pixels)."""
    import bpy

    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    image = bpy.data.images.new("Paint", 4, 4)
    image.pixels.foreach_set(np.tile([1.0, 0.0, 0.0, 1.0], 16).astype(np.float32))
    material = bpy.data.materials.new("Painted")
    material.use_nodes = True
    texture = material.node_tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    base = material.node_tree.nodes["Principled BSDF"].inputs["Base Color"]
    material.node_tree.links.new(texture.outputs["Color"], base)
    cube.data.materials.append(material)
    capture = core("blender.capture_scene").capture(cube, 8)
    metadata = capture_metadata(core, capture)
    fits, errors = core("inference.evaluation").check_model_fits, core("errors")
    fits("red.vdnif", metadata, capture.mesh, capture.grid)
    image.pixels.foreach_set(np.tile([0.0, 0.0, 1.0, 1.0], 16).astype(np.float32))
    blue = core("blender.read_mesh").read_rest_mesh(cube)
    assert (core("model.model_file").mesh_fingerprint(blue)
            == metadata.grid.mesh_fingerprint)              # what let it through before
    with pytest.raises(errors.VDNIFError, match=r"trained on other textures of 'Cube' \(now "
                       r"the images 'Paint' in its materials\)"):
        fits("red.vdnif", metadata, blue, capture.grid)
    material.node_tree.links.remove(base.links[0])
    with pytest.raises(errors.VDNIFError, match="now no image texture"):
        fits("red.vdnif", metadata, core("blender.read_mesh").read_rest_mesh(cube),
             capture.grid)
    older = dataclasses.replace(metadata, grid=dataclasses.replace(metadata.grid,
                                                                  texture_fingerprint=None))
    fits("old.vdnif", older, blue, capture.grid)
