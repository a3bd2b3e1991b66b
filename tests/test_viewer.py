"""`kitbench view`: a recorded episode through LeRobot's viewer, written to a .rrd file off a display; bad
datasets and episodes are one-line errors."""

from __future__ import annotations

import os

from kitbench.cli import main
from kitbench.recording.recorder import RecordConfig, record

os.environ.setdefault("HF_HUB_OFFLINE", "1")


def test_view_writes_a_rerun_recording_and_refuses_bad_input(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    dataset = tmp_path / "lpu"
    record(RecordConfig.of(task="LiftPegUpright-v1", episodes=2, out=dataset, mcap=False), progress=False)
    assert main(["view", str(dataset), "--episode", "1", "--save", str(tmp_path / "view")]) == 0
    (rrd,) = (tmp_path / "view").glob("*.rrd")
    assert rrd.name.endswith("_episode_1.rrd") and rrd.stat().st_size > 1000
    assert capsys.readouterr().out.strip() == f"wrote {rrd}; open it with: rerun {rrd}"
    for argv, message in [
        ([str(dataset), "--episode", "2"], f"episode 2 is not in {dataset}: it has 2 (valid: 0 to 1)"),
        ([str(tmp_path)], f"{tmp_path} is not a LeRobot dataset (no meta/info.json)"),
    ]:
        assert main(["view", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"kitbench view: error: {message}"), err
