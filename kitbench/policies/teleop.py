"""`teleop:<device>`: a person drives the robot with a LeRobot teleoperator (`kitbench.teleop`), e.g.
`kitbench record datasets/lift_peg_upright_so101_state.toml --policy teleop:so101_leader --policy-option
port=/dev/ttyACM0 --policy-option id=my_leader`. The device's options are its LeRobot config's fields; the source's
own (`kitbench.teleop.options`) choose the live view, real-time pacing and the end-effector devices' scales.

The recorder connects the device before anything is written (`connect`), runs each episode with the source's hook
(`episode_hooks`: pacing, the episode keys, the view) and lets go of it at the end (`disconnect`, which reports the
values clipped to the joint limits and the pacing kept). A leader arm first waits, each episode, until it is within
`align` degrees of the simulated arm's start pose, so the episode does not start with a jump.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

import numpy as np

from kitbench.envs.interface import KitbenchEnv, as_kitbench
from kitbench.errors import KitbenchError
from kitbench.policies.joint_targets import joint_target_to_action
from kitbench.policies.registry import policy_source
from kitbench.rollout import Control, Hook
from kitbench.teleop.devices import action_keys, label, make_config, make_device, reason
from kitbench.teleop.hooks import TeleopHook, say
from kitbench.teleop.keys import EpisodeKeys
from kitbench.teleop.mapping import JointMapping, Mapping, make_mapping
from kitbench.teleop.operated import OperatorStop
from kitbench.teleop.options import NAMES, split_options
from kitbench.teleop.pacing import Pacer
from kitbench.teleop.servo import ServoLimit
from kitbench.teleop.view import make_view

ALIGN_SAY_EVERY = 2.0  # seconds between the start-pose wait's lines


def _is_keyboard(device) -> bool:
    from lerobot.teleoperators.keyboard import KeyboardTeleop

    return isinstance(device, KeyboardTeleop)


class TeleopPolicy:
    """A LeRobot teleoperator as a policy: each `act` reads the device and maps its action onto the env's."""

    def __init__(self, device_type: str, options: dict[str, Any]):
        self.options, device_options = split_options(options)
        self.config = make_config(device_type, device_options, more=NAMES)
        self.device_label = label(device_type, self.config)
        if vars(self.config).get("use_degrees") is False:
            raise KitbenchError(
                f"teleop:{self.device_label}: use_degrees=false reports joints from -100 to 100; the simulated arm "
                "takes degrees (drop use_degrees=false)"
            )
        self.device = make_device(device_type, self.config)
        self.name = f"teleop:{device_type}"
        o = self.options
        self.keys = EpisodeKeys(arrows=not _is_keyboard(self.device))
        self.view = make_view(o.display, o.display_ip, o.display_port, o.save_path, o.display_scene)
        self.connected = False
        self.env: KitbenchEnv | None = None
        self.mapping: Mapping | None = None
        self.servo: ServoLimit | None = None
        self.pacer: Pacer | None = None
        self.seed: int | None = None
        self.obs: Any = None
        self.last: np.ndarray | None = None
        self.reads = 0  # the device's values read so far: none yet, and a failure is a device not found

    # -- what the recorder asks (`kitbench.teleop.operated.Operated`) ------------------------------------------
    @property
    def renders(self) -> bool:
        return self.options.display != "none"

    def connect(self) -> None:
        try:
            self.device.connect()
        except Exception as exc:  # noqa: BLE001  (whatever a driver raises, the device is missing: one line)
            raise KitbenchError(f"teleop:{self.device_label}: cannot connect: {reason(exc)}") from None
        if not self.device.is_connected:
            raise KitbenchError(
                f"teleop:{self.device_label}: not connected after connecting (a keyboard needs pynput and an X11 "
                "desktop: pip install 'lerobot[hardware]'; a gamepad needs 'lerobot[gamepad]')"
            )
        self.connected = True
        self.keys.start()
        self.view.open()
        say(f"{self.device_label} connected; {self.keys.help}")

    @property
    def task_step_limit(self) -> bool:
        return False  # time is the person's: they end the episode, or success does, or `max_seconds`

    def episode_hooks(self) -> list[Hook]:
        return [TeleopHook(self.paced, self.keys, self.view, self.clipped, self.limited, self.options.max_seconds)]

    def paced(self) -> Pacer | None:
        """The pacer of the episode about to run (None without real-time pacing)."""
        return self.pacer if self.options.realtime else None

    def disconnect(self) -> None:
        self.keys.stop()
        self.view.close()
        if self.connected:
            self.connected = False
            with contextlib.suppress(Exception):  # a device that failed may fail again to let go: nothing to keep
                self.device.disconnect()
        if isinstance(self.mapping, JointMapping) and self.mapping.clips.values:
            say(f"{self.device_label}: {self.mapping.clips.line()}")
        if self.pacer is not None and self.pacer.intervals.seconds:
            say(f"{self.device_label}: {self.pacer.intervals.line()}")

    # -- a policy ----------------------------------------------------------------------------------------------
    def check(self, env) -> None:
        """The device can drive `env` in its control mode (a leader arm the robot with its motors, end-effector
        devices the end-effector modes)."""
        self._mapping(as_kitbench(env))

    def _mapping(self, env: KitbenchEnv) -> Mapping:
        o = self.options
        keys = action_keys(self.device)
        label = f"teleop:{self.device_label}"
        return make_mapping(
            label, keys, env, self.config, joint_target_to_action, o.ee_speed, o.phone_scale, o.gripper_speed
        )

    def reset(self, env, seed, obs, info) -> None:
        env = as_kitbench(env)
        if not self.connected:
            self.connect()
        if self.mapping is None or env is not self.env:
            self.env, self.mapping = env, self._mapping(env)
            self.servo = ServoLimit(env, joint_target_to_action)
            self.pacer = Pacer(env.control_timestep)
        self.mapping.reset(env)
        assert self.servo is not None
        self.servo.reset(env)
        self.seed, self.obs, self.last = seed, obs, None
        self.keys.clear()
        self.view.episode(env, seed)
        if isinstance(self.mapping, JointMapping) and self.options.align > 0:
            self._align(env, self.mapping)

    def act(self, obs) -> np.ndarray:
        assert self.env is not None and self.mapping is not None and self.servo is not None, "reset() first"
        try:
            device_action = self.device.get_action()
        except Exception as exc:  # noqa: BLE001  (whatever a driver raises, the device is gone: one line)
            if self.keys.stopping and self.last is not None:
                return self._hold()  # escape also lets go of a keyboard device: the episode stops at this step
            raise self._lost(exc, f"while recording seed {self.seed}", "the episode in flight is discarded and "
                             "every finished one kept") from None  # fmt: skip
        self.reads += 1
        self.buttons()
        self.last = self.servo(self.env, self.mapping.action(self.env, device_action))
        return self.last

    def buttons(self) -> None:
        """The device's own episode buttons (lerobot's `get_teleop_events`: a gamepad's), as the episode keys."""
        events = getattr(self.device, "get_teleop_events", None)
        if events is not None:
            self.keys.device_events(events())

    def _lost(self, exc: BaseException, when: str, kept: str) -> KitbenchError:
        """The device failing: not found when it never gave a value (nothing to resume), else disconnected."""
        if not self.reads:
            return KitbenchError(f"teleop:{self.device_label}: not found: {reason(exc)}")
        return KitbenchError(
            f"teleop:{self.device_label} disconnected {when}: {reason(exc)}; {kept}: continue with --resume"
        )

    def _hold(self) -> np.ndarray:
        """The arm held where the device last put it: a leader's last targets, no end-effector motion."""
        assert self.env is not None and self.mapping is not None and self.last is not None
        return self.last if isinstance(self.mapping, JointMapping) else self.mapping.action(self.env, {})

    def clipped(self) -> int:
        return self.mapping.clips.total if isinstance(self.mapping, JointMapping) else 0

    def limited(self) -> int:
        """Steps of the episode in flight where the follower's joint speeds held the device back."""
        return 0 if self.servo is None else self.servo.limited_steps

    def _read(self) -> dict[str, Any]:
        try:
            read = self.device.get_action()
        except Exception as exc:  # noqa: BLE001  (whatever a driver raises, the device is gone: one line)
            when = f"while waiting for the start pose of seed {self.seed}"
            raise self._lost(exc, when, "every finished episode is kept") from None
        self.reads += 1
        return read

    def _align(self, env: KitbenchEnv, mapping: JointMapping) -> None:
        """Wait until the leader is within `align` of the simulated arm's start pose (right arrow: start now;
        escape: stop before this episode), showing the scene."""
        tolerance = self.options.align
        period = env.control_timestep
        said = -ALIGN_SAY_EVERY
        waited = False
        while True:
            offsets = mapping.offsets(env, self._read())
            off = {k: v for k, v in offsets.items() if abs(v) > tolerance}
            if not off:
                if waited:
                    say(f"seed {self.seed}: at the start pose, recording")
                return
            control = Control.STOP if self.view.closed else self.keys.take()
            if control is Control.STOP:
                raise OperatorStop()
            if control is Control.NEXT:
                say(f"seed {self.seed}: starting away from the start pose, as asked")
                return
            now = time.monotonic()
            if now - said >= ALIGN_SAY_EVERY:
                far = ", ".join(f"{k} {v:+.0f}" for k, v in off.items())
                keys = "" if waited else f"; {self.keys.start_help}"
                say(f"seed {self.seed}: bring the leader to the simulated arm's start pose ({far}){keys}")
                said = now
            self.view.show(env, self.obs, None)
            waited = True
            time.sleep(period)


@policy_source("teleop", "teleop:<device>", takes_options=True)
def _teleop(argument: str | None, device: str, options: dict) -> TeleopPolicy:
    assert argument is not None, "registered with an argument"
    return TeleopPolicy(argument, options)
