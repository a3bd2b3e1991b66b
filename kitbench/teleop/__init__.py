"""A person at the controls: LeRobot's own teleoperators drive the simulated robot (`--policy teleop:<device>`).

- `devices`: the device, built from LeRobot's `TeleoperatorConfig` registry (every device LeRobot supports and every
  installed `lerobot_teleoperator_*` plugin), its connection and what it names itself;
- `mapping`: a device's action onto the env's: a leader arm joint for joint, end-effector devices (gamepad,
  keyboard, phone) onto the end-effector modes, with the turn for kitbench's own keyboard and gamepad;
- `keyboard`, `gamepad` (configs in `config_keyboard`, `config_gamepad`): kitbench's own teleoperators with the turn,
  in LeRobot's registry;
- `limits`, `servo`: a person's joint targets rate-limited to the real arm's joint speeds, in every mode;
- `pacing`: the control loop held to the task's control rate in wall-clock time;
- `keys`: lerobot-record's episode keys (right: next, left: re-record, escape: stop) and a device's own buttons;
- `view`: the live view (Rerun as lerobot's `--display_data` shows it, or a SAPIEN viewer window);
- `hooks`: the rollout hook that paces each step, reads the keys, shows the view, ends an episode at `max_seconds`
  and keeps how it ended;
- `operated`: what the recorder asks of a policy with a person behind it;
- `checks`: the recording settings a teleoperated recording refuses;
- `options`: kitbench's own options of the source, beside the device's.

docs/teleoperation.md says how to record with each kind of device.
"""
