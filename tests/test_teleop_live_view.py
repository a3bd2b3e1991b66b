"""The Rerun live view shows what the person does from the first frame (`kitbench.teleop.layout`): each camera, and per
motor its state beside the action commanding it, whether the first frame logged has an action (lerobot's own loops)
or not (`kitbench record`'s view, which shows the scene at the reset). Read back from a saved .rrd with the Rerun
SDK, offline."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitbench.envs.features import STATE, observation_frame
from kitbench.registration import make_env
from kitbench.teleop.view import RerunView
from tests.lerobot_scripted import play
from tests.test_lerobot_record_plugin import LIFT, MOTORS, RECORD_OVERRIDES, doc_commands, leader, replaced

PLOTS = {f"{m}.pos": (f"observation.{m}.pos", f"action.{m}.pos") for m in MOTORS}


def views(rrd: Path) -> list[tuple[str, str, tuple[str, ...]]]:
    """The views of the layout saved in `rrd`: (kind, name, what it shows), the last layout sent."""
    import rerun.experimental as rrx

    reader = rrx.RrdReader(rrd)
    store, *_ = reversed(reader.blueprints())
    found: dict[str, dict] = {}
    for chunk in reader.store(store=store).stream():
        rows = chunk.to_record_batch().to_pydict()
        path = str(chunk.entity_path).split("/")
        if len(path) > 2 and path[1] == "view":
            found.setdefault(path[2], {}).update({k.split(":")[-1]: v[-1] for k, v in rows.items() if ":" in k})
    shown = []
    for view in found.values():
        contents = view["query"] if view["class_identifier"] == ["TimeSeries"] else view["space_origin"]
        shown.append((view["class_identifier"][0], view["display_name"][0], tuple(contents)))
    return shown


def entities(rrd: Path) -> set[str]:
    import rerun.experimental as rrx

    return {path.lstrip("/") for path in rrx.RrdReader(rrd).store().schema().entity_paths()}


def test_kitbench_records_view_lays_out_the_actions_before_the_first_one(tmp_path):
    rrd = tmp_path / "view.rrd"
    env = make_env(LIFT, obs_mode="state", control_mode="pd_joint_pos", robot_uids="so101")
    view = RerunView(None, None, rrd, scene_size=0)
    view.open()
    try:
        obs, _ = env.reset(seed=0)
        view.episode(env, 0)
        view.show(env, obs, None)  # the scene at the reset: no action yet
        action = np.asarray(observation_frame(env, obs)[STATE], dtype=np.float32)  # hold where it stands
        obs = env.step(action)[0]
        view.show(env, obs, action)
    finally:
        view.close()
        env.close()
    plots = {name: contents for kind, name, contents in views(rrd) if kind == "TimeSeries"}
    assert plots == PLOTS
    assert set(sum(PLOTS.values(), ())) <= entities(rrd)


def test_lerobot_records_view_of_the_simulated_arm_has_its_cameras_and_actions(tmp_path, needs_vulkan, monkeypatch):
    """The documented lerobot-record line with `--display_data=true`, its viewer's stream written to a file."""
    import rerun as rr

    rrd = tmp_path / "record.rrd"
    monkeypatch.setattr(rr, "spawn", lambda **_: rr.save(str(rrd)))
    settings = {**RECORD_OVERRIDES, "dataset.num_episodes": "1", "dataset.episode_time_s": "1"}
    argv = replaced(doc_commands()["lerobot-record"], {**settings, "dataset.root": str(tmp_path / "sim")})
    start = make_env(LIFT, obs_mode="state", control_mode="pd_joint_pos", robot_uids="so101")
    try:
        pose = observation_frame(start, start.reset(seed=0)[0])[STATE]
    finally:
        start.close()
    play([*argv, "--display_data=true"], [leader(pose)], monkeypatch)
    shown = views(rrd)
    assert {name: contents for kind, name, contents in shown if kind == "TimeSeries"} == PLOTS
    assert sorted((name, contents) for kind, name, contents in shown if kind == "2D") == [
        ("front", ("observation.front",)),
        ("wrist", ("observation.wrist",)),
    ]
    assert {"observation.front", "observation.wrist", "action.shoulder_pan.pos"} <= entities(rrd)


def _shown_entities(tmp_path: Path, obs_mode: str, scene_size: int | None) -> set[str]:
    rrd = tmp_path / f"{obs_mode}-{scene_size}.rrd"
    env = make_env(LIFT, obs_mode=obs_mode, control_mode="pd_joint_pos", robot_uids="so101", render_mode="rgb_array")
    view = RerunView(None, None, rrd, scene_size=scene_size)
    view.open()
    try:
        obs, _ = env.reset(seed=0)
        view.episode(env, 0)
        view.show(env, obs, None)
    finally:
        view.close()
        env.close()
    return {e for e in entities(rrd) if e.startswith("observation.images.")}


def test_the_third_person_view_is_shown_by_default_only_where_no_camera_is(tmp_path, needs_vulkan):
    """A third render a step would break the 20 Hz pacing of a camera recording on 2 cores (docs/teleoperation.md):
    by default a state recording gets the scene, a camera recording its cameras; asked for, both."""
    scene = "observation.images.scene"
    assert _shown_entities(tmp_path, "state", None) == {scene}
    assert _shown_entities(tmp_path, "rgb", None) == {"observation.images.front", "observation.images.wrist"}
    assert scene in _shown_entities(tmp_path, "rgb", 64)
    assert _shown_entities(tmp_path, "state", 0) == set()
