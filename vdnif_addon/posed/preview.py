"""The live preview's worker side: renders the predicted passes of one pose snapshot at a
small size in a worker thread, and the rule that keeps a timeline scrub fluid.

The scene is read on Blender's main thread (the frame-change handler reads the pose the
user moved to into a PoseSnapshot, see ``pose_reader``); nothing here touches Blender data.
"""

import threading

import numpy as np

from ..inference.evaluation import DistanceScale
from ..inference.images import display, secondary_images, shaded_display
from ..passes import SHADED_PASS
from ..settings import DEFAULT_PRECISION
from ..tracing.rays import orbit_viewpoints
from .geometry import PosedObject
from .pose_source import PoseSource
from .render import (
    load_scene_model,
    orbit_view,
    render_orbit_rays,
    render_view,
)


class LatestFrame:
    """The drop-frames rule: at most one render runs and at most one frame waits; a newer
    frame replaces the waiting one (the frames in between are dropped, never queued), so a
    scrub through the timeline never waits for renders and the newest frame always wins."""

    def __init__(self):
        self.running = None        # the frame being rendered
        self.waiting = None        # the newest frame asked for since
        self.dropped = 0           # frames replaced before they were rendered

    def request(self, frame):
        """A frame change: True when its render should start now (none runs)."""
        if self.running is None:
            self.running = frame
            return True
        if self.waiting is not None:
            self.dropped += 1
        self.waiting = frame
        return False

    def finished(self):
        """The running render ended: the frame to render next (now running), or None."""
        self.running, self.waiting = self.waiting, None
        return self.running


class PreviewRenderer:
    """Renders PoseSnapshots of one object's model at ``width`` x ``height``, one at a time in
    a worker thread: the model is loaded and the device cells are built by the first."""

    def __init__(self, model_path, captured, device, width, height, view=None,
                 precision=DEFAULT_PRECISION):
        self.model_path, self.captured, self.device = model_path, captured, device
        self.precision = precision
        self.width, self.height, self.view = width, height, view
        self._model = self._posed = self._orbit = None
        self._thread, self._outcome = None, None
        self._scale = DistanceScale()     # one distance scale for every frame it renders

    @property
    def busy(self):
        return self._thread is not None

    def start(self, snapshot, secondary=None):
        """Renders ``snapshot`` in a worker thread (none may be running); the AO and shadow
        passes too with ``secondary`` (their ``SecondarySettings``, read on the main
        thread: the light may move from frame to frame)."""
        self._outcome = None
        self._thread = threading.Thread(target=self._render, args=(snapshot, secondary),
                                        name="vdnif-preview", daemon=True)
        self._thread.start()

    def finished(self, wait=None):
        """(frame, {pass: (H, W, 4) image, alpha the hit mask}) or (frame, error) of the
        render that ended, else None (still running, or none started); ``wait``: seconds to
        wait for it."""
        if self._thread is None:
            return None
        self._thread.join(wait)
        if self._thread.is_alive():
            return None
        self._thread = None
        return self._outcome

    def _render(self, snapshot, secondary):
        try:
            if self._model is None:
                self._model = load_scene_model(self.model_path, self.captured, self.device,
                                               precision=self.precision)
                self._posed = PosedObject(PoseSource(), self.captured, self._model.device)
            geometry = self._posed.place(snapshot)
            chosen = snapshot.view if snapshot.view is not None else self.view
            if chosen is not None:
                result = render_view(self._model, self._posed, geometry, chosen,
                                     self.width, self.height, secondary=secondary)
            else:
                if self._orbit is None:
                    self._orbit = orbit_view(geometry, orbit_viewpoints(1)[0], self.width,
                                             self.height)
                result = render_orbit_rays(self._model, self._posed, geometry, *self._orbit,
                                           secondary=secondary)
            predicted = None if result.secondary is None else result.secondary["predicted"]
            shaded = None if result.shaded is None else result.shaded["predicted"]
            self._outcome = (snapshot.pose["frame"], images(result.predicted, self.height,
                                                            self.width, predicted,
                                                            self._scale, shaded))
        except Exception as exc:   # shown in the panel; the preview must not stop Blender
            self._outcome = (snapshot.pose["frame"], exc)


def images(passes, height, width, secondary=None, scale=None, shaded=None):
    """{pass: (H, W, 4) display image} of predicted Passes, alpha the hit mask; "ao" and
    "shadow" too with ``secondary``, the predicted SecondaryPasses of the same rays, and
    "shaded" with ``shaded``, its shaded image (R, 3); distance on ``scale`` (a
    ``DistanceScale`` kept over the frames, default its own)."""
    alpha = passes.hit.reshape(height, width, 1).astype(np.float32)
    shown = display(passes, height, width, (scale or DistanceScale())(passes))
    if secondary is not None:
        shown.update(secondary_images(secondary, height, width)["display"])
    if shaded is not None:
        shown[SHADED_PASS] = shaded_display(shaded, height, width)
    return {name: np.concatenate([image, alpha], axis=2) for name, image in shown.items()}
