"""The live preview: while an object's Live Preview is on, a frame change re-renders its
predicted passes at the preview size into the images "VDNIF Preview <Pass>" (AO and Shadow
too while the pass viewer shows one of them, as Render Passes casts them).

The frame-change handler only notes the frame (``preview.LatestFrame``: at most one render
runs and one frame waits, a newer frame replaces it), so scrubbing the timeline never waits;
a timer on the main thread then reads the pose the scene is in (Blender's data is read only
there, and not inside a depsgraph handler, where evaluating it again is unsafe) and starts
the render in a worker thread (``preview.PreviewRenderer``).
"""

from dataclasses import dataclass, field

import bpy

from .. import storage, viewer
from ..vdnif_addon.passes import SECONDARY_PASSES
from .common import JOBS

TICK_S = 0.03
IMAGE = "VDNIF Preview {}"
_sessions = {}        # object name -> Session (runtime only)


@dataclass
class Session:
    frames: object                      # preview.LatestFrame
    renderer: object = None             # preview.PreviewRenderer, made by the first tick
    key: tuple = ()
    error: str = ""
    shown: list = field(default_factory=list)    # frames whose images were shown


def preview_size(settings, scene=None):
    """The preview's (width, height): the render size (``viewer.render_size`` in ``scene``,
    default the context's) scaled by the preview percentage."""
    width, height = viewer.render_size(scene or bpy.context.scene, settings)
    scale = settings.preview_percent / 100
    return max(1, round(width * scale)), max(1, round(height * scale))


def previewed(scene):
    """The scene's objects whose live preview is on and can render (a model, no job)."""
    return [obj for obj in scene.objects if obj.type == "MESH" and obj.vdnif.live_preview
            and obj.name not in JOBS and storage.has_model(obj)]


@bpy.app.handlers.persistent
def on_frame_change(scene, _depsgraph=None):
    """frame_change_post: notes the new frame for every previewed object; returns at once."""
    from ..vdnif_addon.blender.poses import posing

    if posing():                 # a job setting a pose, not the user
        return
    for obj in previewed(scene):
        session = _sessions.get(obj.name)
        if session is None:
            from ..vdnif_addon.posed.preview import LatestFrame

            session = _sessions[obj.name] = Session(LatestFrame())
        session.frames.request(scene.frame_current)
    if _sessions and not bpy.app.background and not bpy.app.timers.is_registered(tick):
        bpy.app.timers.register(tick, first_interval=TICK_S)


def tick():
    """Main thread: shows finished renders and starts the next; returns the timer's next
    interval, or None when nothing runs or waits (the timer stops)."""
    scene = bpy.context.scene
    for name, session in list(_sessions.items()):
        obj = bpy.data.objects.get(name)
        if obj is None or not obj.vdnif.live_preview:
            stop(name)
            continue
        outcome = session.renderer.finished() if session.renderer is not None else None
        if outcome is not None:
            _show(obj, session, *outcome)
            session.frames.finished()
        if session.frames.running is not None and not (session.renderer and
                                                       session.renderer.busy):
            _start(obj, scene, session)
    busy = any(s.frames.running is not None for s in _sessions.values())
    return TICK_S if busy else None


def _renderer(obj, scene, session):
    """The session's renderer, made again when the model or the preview settings changed
    (the capture, at the model's resolution, is read here on the main thread)."""
    from ..vdnif_addon.blender.capture_scene import capture
    from ..vdnif_addon.blender.steps import model_follow
    from ..vdnif_addon.posed.preview import PreviewRenderer

    settings = obj.vdnif
    width, height = preview_size(settings, scene)
    device = settings.device_name(bpy.context)
    key = (settings.model_info, settings.model_path, width, height, device, settings.precision)
    if session.renderer is None or session.key != key:
        info = settings.parsed("model_info")
        # the corners follow as the model's did (a summary kept before that was recorded
        # lets the capture choose, as it chose then)
        captured = capture(obj, info["resolution"], settings.pose_spec(1), deform_corners=False,
                           follow=model_follow(obj, info.get("corners_follow")))
        session.renderer = PreviewRenderer(storage.model_path(obj), captured, device, width,
                                           height, precision=settings.precision)
        session.key = key
    return session.renderer


def _start(obj, scene, session):
    """Reads the pose the scene is in now (the newest frame) and starts its render."""
    from ..vdnif_addon.blender.pose_reader import PoseReader
    from ..vdnif_addon.posed.render import camera_view
    from .passes import secondary_settings

    try:
        renderer = _renderer(obj, scene, session)
        width, height = renderer.width, renderer.height
        if obj.vdnif.view == "CAMERA" and scene.camera is not None:
            read_view = lambda: camera_view(scene.camera, width, height)   # noqa: E731
        elif obj.vdnif.view == "VIEWPORT":
            from .passes import region_3d

            fixed = viewer.viewport_view(region_3d(bpy.context))
            read_view = lambda: fixed                                       # noqa: E731
        else:
            read_view = None
        reader = PoseReader(obj, renderer.captured, read_view)
        try:
            snapshot = reader.read_current({"frame": float(scene.frame_current)})
        finally:
            reader.close()
        secondary = secondary_settings(bpy.context, obj)
    except Exception as exc:     # shown under the toggle; the next frame change tries again
        session.error = f"'{obj.name}': live preview failed: {exc}"
        session.frames.running = session.frames.waiting = None
        return
    renderer.start(snapshot, secondary)


def _show(obj, session, frame, images):
    if isinstance(images, Exception):
        session.error = f"'{obj.name}': live preview failed at frame {frame:g}: {images}"
        return
    session.error = ""
    session.shown.append(frame)
    for name, image in images.items():
        viewer.write_image(IMAGE.format(title(name)), image,
                           viewer.COLORSPACES.get(name, "Non-Color"))


def title(name):
    """A pass's title in its preview image's name: Normal, Albedo, ..., AO, Shadow."""
    return viewer.PASS_TITLES[name] if name in SECONDARY_PASSES else name.title()


def error(obj):
    """The live preview's last failure for ``obj``, or ''."""
    session = _sessions.get(obj.name)
    return session.error if session is not None else ""


def toggled(settings, context):
    """The Live Preview property changed: render the current frame at once, or stop."""
    if settings.live_preview:
        on_frame_change(context.scene)
    else:
        stop(settings.id_data.name)


def stop(name):
    """Ends an object's preview, waiting for its render."""
    session = _sessions.pop(name, None)
    if session is not None and session.renderer is not None:
        session.renderer.finished(wait=60)


@bpy.app.handlers.persistent
def forget(*_):
    """load_post: the sessions belong to the file they were made in."""
    for name in list(_sessions):
        stop(name)


def register():
    bpy.app.handlers.frame_change_post.append(on_frame_change)
    bpy.app.handlers.load_post.append(forget)


def unregister():
    bpy.app.handlers.frame_change_post.remove(on_frame_change)
    bpy.app.handlers.load_post.remove(forget)
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
    for name in list(_sessions):
        stop(name)
