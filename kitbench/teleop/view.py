"""What the person at the controls sees, live: Rerun as lerobot's `--display_data` shows a robot (lerobot's own
`init_rerun` and `log_rerun_data`: each camera's image, a third-person view of the scene, the state and the action,
per motor), or a SAPIEN viewer window on the scene where a display exists. Both need the scene rendered, so a
recording with a view builds its env with rendering on (the data is the same: rendering adds visual shapes only).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Protocol

import numpy as np

from kitbench.envs.features import IMAGES, STATE, action_names, observation_features, observation_frame
from kitbench.envs.interface import KitbenchEnv
from kitbench.envs.modalities import texture_of
from kitbench.errors import KitbenchError
from kitbench.teleop import layout

DISPLAYS = ("none", "rerun", "sapien")
SCENE = f"{IMAGES}scene"  # the third-person view, beside the cameras
SHOWN_TEXTURES = ("rgb", "depth")  # what lerobot's Rerun logging draws (a segmentation is ids, not an image)
# The third-person camera: over the table's far corner, on the workspace every task keeps near the origin.
SCENE_SIZE = 192  # the third-person view's default, pixels square
SCENE_EYE, SCENE_TARGET, SCENE_FOV = (0.55, 0.55, 0.55), (-0.05, 0.0, 0.1), 1.0


class View(Protocol):
    def open(self) -> None: ...

    def episode(self, env: KitbenchEnv, seed: int) -> None:
        """A new episode (a new scene)."""

    def show(self, env: KitbenchEnv, obs, action: np.ndarray | None) -> None:
        """The state the env is in (`obs`, its last observation) and the action that led there."""

    @property
    def closed(self) -> bool:
        """The person closed the view (a window)."""

    def close(self) -> None: ...


class NoView:
    def open(self) -> None:
        """Nothing to open."""

    def episode(self, env: KitbenchEnv, seed: int) -> None:
        """Nothing shown."""

    def show(self, env: KitbenchEnv, obs, action: np.ndarray | None) -> None:
        """Nothing shown."""

    @property
    def closed(self) -> bool:
        return False

    def close(self) -> None:
        """Nothing to close."""


def has_display() -> bool:
    """Whether a window can open here (Linux: an X11 or Wayland display; elsewhere always)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _scene_camera(env: KitbenchEnv, size: int):
    from kitbench.sim.cameras import Camera, CameraSpec

    spec = CameraSpec.looking_at("teleop_view", SCENE_EYE, SCENE_TARGET, size, size, SCENE_FOV)
    return Camera(env.scene, spec, None)


class RerunView:
    """lerobot's Rerun display: a spawned viewer, a Rerun server at `ip`:`port`, or an .rrd file (`save`) for a
    machine without a display. The third-person view is `scene_size` pixels square (0: none; None: `SCENE_SIZE`
    where the observation shows no camera image, else none)."""

    def __init__(self, ip: str | None, port: int | None, save: Path | None, scene_size: int | None):
        self.ip, self.port, self.save, self.scene_size = ip, port, save, scene_size
        self.camera = None
        self.state_names: list[str] = []
        self.action_names: list[str] = []
        self.frame = 0

    def open(self) -> None:
        import rerun as rr
        from lerobot.utils.rerun_visualization import init_rerun, log_rerun_data

        if self.save is None:
            init_rerun(session_name="kitbench_teleop", ip=self.ip, port=self.port)
            return
        log_rerun_data.blueprint = None  # a new recording gets lerobot's layout again, as init_rerun resets it
        rr.init("kitbench_teleop")
        self.save.parent.mkdir(parents=True, exist_ok=True)
        rr.save(str(self.save))

    def episode(self, env: KitbenchEnv, seed: int) -> None:
        import rerun as rr

        features = observation_features(env)
        self.state_names = list(features[STATE]["names"])
        self.action_names = action_names(env)
        images = [name for name in features if (t := texture_of(name, IMAGES)) is not None and t.name in SHOWN_TEXTURES]
        size = self.scene_size if self.scene_size is not None else (0 if images else SCENE_SIZE)
        self.camera = _scene_camera(env, size) if size else None
        layout.send(self.state_names, self.action_names, images + ([SCENE] if self.camera is not None else []))
        rr.set_time("frame", sequence=self.frame)
        rr.log("episode", rr.TextLog(f"{env.task_id} seed {seed}"))

    def show(self, env: KitbenchEnv, obs, action: np.ndarray | None) -> None:
        import rerun as rr
        from lerobot.utils.rerun_visualization import log_rerun_data

        rr.set_time("frame", sequence=self.frame)
        self.frame += 1
        data = observation_frame(env, obs)
        observation: dict = {name: float(v) for name, v in zip(self.state_names, data[STATE], strict=True)}
        for name, value in data.items():
            texture = texture_of(name, IMAGES)
            if texture is not None and texture.name in SHOWN_TEXTURES:
                observation[name] = value
        if self.camera is not None:
            env.scene.update_render()
            self.camera.take_picture()
            observation[SCENE] = self.camera.rgb()
        shown = None if action is None else {n: float(v) for n, v in zip(self.action_names, action, strict=True)}
        log_rerun_data(observation=observation, action=shown)

    @property
    def closed(self) -> bool:
        return False

    def close(self) -> None:
        from lerobot.utils.rerun_visualization import shutdown_rerun

        shutdown_rerun()
        self.camera = None


class SapienView:
    """A SAPIEN viewer window on the scene (orbit it with the mouse); closing it stops the recording as escape
    does."""

    def __init__(self) -> None:
        self.viewer = None

    def open(self) -> None:
        if not has_display():
            raise KitbenchError(
                "display=sapien needs a display (DISPLAY is unset); valid choices here: rerun (with "
                "display_save=<file.rrd> on a machine without one), none"
            )
        from sapien.utils import Viewer

        self.viewer = Viewer()

    def episode(self, env: KitbenchEnv, seed: int) -> None:
        import sapien

        from kitbench.geometry import look_at

        assert self.viewer is not None, "open() first"
        self.viewer.set_scene(env.scene)
        position, quaternion = look_at(SCENE_EYE, SCENE_TARGET)
        self.viewer.set_camera_pose(sapien.Pose(position, quaternion))

    def show(self, env: KitbenchEnv, obs, action: np.ndarray | None) -> None:
        if self.viewer is not None and not self.viewer.closed:
            env.scene.update_render()
            self.viewer.render()

    @property
    def closed(self) -> bool:
        return self.viewer is not None and bool(self.viewer.closed)

    def close(self) -> None:
        if self.viewer is not None:
            if not self.viewer.closed:
                self.viewer.close()
            self.viewer = None


def make_view(display: str, ip: str | None, port: int | None, save: Path | None, scene_size: int | None) -> View:
    if display == "rerun":
        return RerunView(ip, port, save, scene_size)
    if display == "sapien":
        return SapienView()
    return NoView()
