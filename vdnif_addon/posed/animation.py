"""Animation: the passes of a range of frames in one run, the model loaded once and the
device cells built once, written as image sequences named like Blender's own
(``steps.frame_number``).

``render_frames`` touches no Blender data: it reads every frame through a PoseSource (a live
``PoseReader`` in batch runs, a ``PoseFeed`` filled on Blender's main thread in the UI). The
frame-range helpers import nothing heavy, for the command-line parser."""

from .. import limits
from ..errors import VDNIFError


def parse_frames(text):
    """The frames of ``A:B[:STEP]``: A to B included, every STEP (default 1), as Blender's
    render range takes them; a malformed range raises a one-line VDNIFError."""
    parts = text.split(":")
    try:
        numbers = [int(part) for part in parts]
    except ValueError:
        numbers = None
    if numbers is None or len(numbers) not in (2, 3):
        raise VDNIFError(f"--frames '{text}' must be START:END or START:END:STEP in whole "
                         "frames, e.g. 1:250 or 1:250:5")
    return frame_range(*numbers)


def frame_range(start, end, step=1):
    """Frames ``start`` to ``end`` included, every ``step``: at most ``limits.MAX_FRAMES``
    of them, within Blender's timeline (counted before the list is built)."""
    if step < 1:
        raise VDNIFError(f"the frame step {step} must be at least 1")
    if end < start:
        raise VDNIFError(f"the frame range {start}:{end} ends before it starts")
    for frame in (start, end):
        if abs(frame) > limits.MAX_FRAME:
            raise VDNIFError(f"the frame {frame} is outside Blender's frames "
                             f"{-limits.MAX_FRAME}..{limits.MAX_FRAME}")
    count = (end - start) // step + 1
    if count > limits.MAX_FRAMES:
        raise VDNIFError(f"the frame range {start}:{end}:{step} has {count:,} frames, more "
                         f"than the limit {limits.MAX_FRAMES:,} (vdnif_addon/limits.py): "
                         "render a shorter range or a larger step")
    return list(range(start, end + 1, step))


def frame_pose(frame):
    return {"frame": float(frame)}


def render_frames(source, captured, model, frames, width, height, view=None,
                  references=False, each=None, progress=None, secondary=None):
    """Renders the passes of every frame of ``frames`` with the network (and the references
    with ``references``; the AO and shadow passes with ``secondary``, a function of a frame
    giving its ``SecondarySettings``, called before the frame renders); calls
    ``each(frame, RenderResult)`` and ``progress(done, total)`` after each frame, and returns
    the per-frame figures.

    The view of a frame: the camera's, when ``source`` reads one in each pose (a camera
    animates with the scene); else the fixed pinhole ``view`` (world matrix, horizontal
    field of view in degrees: the 3D Viewport's); else an orbit viewpoint around the first
    frame's bounds, kept for the whole range so that the images line up."""
    from ..inference.shading import settings_lighting
    from ..kernels import runtime
    from ..tracing.rays import orbit_viewpoints
    from .geometry import PosedObject
    from .render import orbit_view, render_orbit_rays, render_view

    runtime.load_all(runtime.device(model.device))      # a first compile is in no rays/s
    figures, orbit = [], None
    with PosedObject(source, captured, model.device) as posed_object:
        for index, frame in enumerate(frames):
            geometry = posed_object.geometry(frame_pose(frame))
            chosen = geometry.view if geometry.view is not None else view
            settings = None if secondary is None else secondary(frame)
            if chosen is not None:
                result = render_view(model, posed_object, geometry, chosen, width, height,
                                     references, settings)
            else:
                if orbit is None:
                    orbit = orbit_view(geometry, orbit_viewpoints(1)[0], width, height)
                result = render_orbit_rays(model, posed_object, geometry, *orbit, references,
                                           settings)
            timings = result.timings
            figures.append({"frame": frame, "hit_pixels": int(result.predicted.hit.sum()),
                            "rays_per_s": timings["rays"] / timings["render_s"],
                            "timings": timings})
            if settings is not None:
                size = captured.mesh.size
                figures[-1]["secondary"] = dict(
                    settings.describe(model.secondary_offset(size), size),
                    **settings_lighting(settings).describe())
            if each is not None:
                each(frame, result)
            if progress is not None:
                progress(index + 1, len(frames))
    return figures
