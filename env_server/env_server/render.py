"""Frames of Task instances: the Render request's limits, and the shared ways to draw one.

A Task that can render sets `cameras` and implements `render(width, height, camera)`
(task.py). This module holds what those implementations share: `MujocoView`, an
offscreen MuJoCo renderer over a model and its data (Shadow Hand, Sawyer), and
`resize`, which fits a frame an env draws at its own size (gymnasium's) to the size
asked for. The service checks every request against the limits here before any Task
draws.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from env_server import gl
from env_server.errors import InvalidArgument, ResourceExhausted

DEFAULT_WIDTH, DEFAULT_HEIGHT = 320, 240
#: Frames one Render call may ask for.
MAX_FRAMES = 64
#: Pixels per side and per frame (a 1080p frame; software OpenGL draws one in about 0.1 s).
MAX_SIDE = 4096
MAX_PIXELS = 1920 * 1080
#: Room for a RenderResponse's framing and camera names besides the pixels.
_RESPONSE_OVERHEAD = 64 * 1024


@dataclasses.dataclass(frozen=True)
class FrameSize:
    width: int
    height: int


def frame_size(width: int, height: int, num_frames: int, max_message_bytes: int) -> FrameSize:
    """The frame size a request asks for (0 = default), checked against the limits.

    Negative sizes are INVALID_ARGUMENT; sizes and frame counts beyond a limit, and
    responses larger than the server's message limit, RESOURCE_EXHAUSTED.
    """
    for field, value in (("width", width), ("height", height)):
        if value < 0:
            raise InvalidArgument(f"{field}: expected 0 (the default) or a positive number of pixels, got {value}")
        if value > MAX_SIDE:
            raise ResourceExhausted(f"{field}: at most {MAX_SIDE} pixels per side, asked for {value}")
    size = FrameSize(width or DEFAULT_WIDTH, height or DEFAULT_HEIGHT)
    pixels = size.width * size.height
    if pixels > MAX_PIXELS:
        raise ResourceExhausted(
            f"width x height: at most {MAX_PIXELS} pixels per frame (1920 x 1080), "
            f"asked for {size.width} x {size.height} = {pixels}"
        )
    if num_frames > MAX_FRAMES:
        raise ResourceExhausted(
            f"env_indices: at most {MAX_FRAMES} frames per Render call, asked for {num_frames}; "
            "render the instances in several calls"
        )
    response_bytes = num_frames * pixels * 3 + _RESPONSE_OVERHEAD
    if response_bytes > max_message_bytes:
        raise ResourceExhausted(
            f"{num_frames} frames of {size.width} x {size.height} make a {response_bytes} byte response, "
            f"over this server's message limit of {max_message_bytes} bytes (--max-message-mb); "
            "ask for fewer or smaller frames"
        )
    return size


def resize(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """An RGB frame [h, w, 3+] as uint8 [height, width, 3], by nearest-neighbour sampling."""
    frame = np.asarray(frame)[..., :3]
    h, w = frame.shape[:2]
    if (h, w) != (height, width):
        rows = (np.arange(height) * h // height).clip(0, h - 1)
        cols = (np.arange(width) * w // width).clip(0, w - 1)
        frame = frame[rows[:, None], cols[None, :]]
    return np.ascontiguousarray(frame, np.uint8)


@dataclasses.dataclass(frozen=True)
class FreeCamera:
    """A MuJoCo free camera: where it looks, from how far, from which direction (degrees)."""

    lookat: tuple[float, float, float]
    distance: float
    azimuth: float
    elevation: float


class MujocoView:
    """Offscreen frames of one MuJoCo model and data, from a free camera or a named one.

    The renderer is made on the first frame (so Tasks that never render pay nothing) and
    again when the size changes; rendering runs on the thread that made it (the
    server's loop, or a worker's main thread), as OpenGL contexts require.

    Every MuJoCo task in the server draws through this one OpenGL stack (mujoco's
    GLContext), dm_control's included: after dm_control's own `physics.render` had made
    its context in the server process, mujoco.Renderer's frames in the same process came
    back stale (measured with Mesa's EGL).
    """

    def __init__(self, model: Any, data: Any, default: FreeCamera | str) -> None:
        import mujoco

        self._mujoco = mujoco
        self.model = model
        self.data = data
        self.default = default
        self.cameras = tuple(
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) or f"camera{i}" for i in range(model.ncam)
        )
        self._renderer: Any = None
        # Sites mark sensors and frames for the simulation, not for the viewer.
        self._option = mujoco.MjvOption()
        self._option.sitegroup[:] = 0

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        mujoco = self._mujoco
        gl.require()
        renderer = self._renderer
        if renderer is None or (renderer.width, renderer.height) != (width, height):
            self.close()
            visual = self.model.vis.global_
            visual.offwidth = max(visual.offwidth, width)
            visual.offheight = max(visual.offheight, height)
            renderer = self._renderer = mujoco.Renderer(self.model, height, width)
        camera = camera or (self.default if isinstance(self.default, str) else "")
        if camera:
            view: Any = self.cameras.index(camera)
        else:
            view = mujoco.MjvCamera()
            view.type = mujoco.mjtCamera.mjCAMERA_FREE
            view.lookat[:] = self.default.lookat
            view.distance = self.default.distance
            view.azimuth = self.default.azimuth
            view.elevation = self.default.elevation
        renderer.update_scene(self.data, view, self._option)
        return renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
