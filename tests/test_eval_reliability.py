"""`kitbench eval` keeps what it has: the report survives a failed video pass, an existing report folder is not
replaced unless asked, and episodes the simulator could not finish are counted as `physics_error`."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

import kitbench  # noqa: F401
from kitbench.errors import KitbenchError
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.episode import EpisodeResult
from kitbench.evaluation.report import build_report, markdown
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import load_suite
from kitbench.evaluation.work import EvalWork
from kitbench.tasks.lift_peg_upright import LiftPegUprightEnv
from tests import launch

ROOT = Path(__file__).resolve().parents[1]
SHORT = ROOT / "eval" / "suites" / "lift_peg_upright_short.toml"
NO_VULKAN = {"VK_ICD_FILENAMES": "/nonexistent.json", "VK_DRIVER_FILES": "/nonexistent.json"}


def _suite(n: int):
    return load_suite(SHORT).first(n)


# -- the video pass --------------------------------------------------------------------------------
def test_without_a_render_device_the_report_is_kept_and_says_why_there_are_no_videos(tmp_path):
    out = tmp_path / "report"
    code = (
        "import json, sys\n"
        "from pathlib import Path\n"
        "from kitbench.doctor import vulkan_error\n"
        "from kitbench.evaluation.config import EvalConfig\nfrom kitbench.evaluation.runner import run_eval\n"
        "from kitbench.evaluation.suite import load_suite\n"
        f"suite = load_suite({str(SHORT)!r}).first(2)\n"
        "report = run_eval(EvalConfig.of(suite, 'expert', Path(sys.argv[1]), videos=1), progress=False)\n"
        "print(json.dumps({'video_error': report['output'].get('video_error'), 'doctor': vulkan_error()}))\n"
    )
    done = launch.run(
        [sys.executable, "-c", code, str(out)],
        capture_output=True,
        text=True,
        env={**os.environ, **NO_VULKAN},
        timeout=300,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    returned = json.loads(done.stdout.strip().splitlines()[-1])
    assert returned["doctor"] and "failed to find a rendering device" in returned["doctor"]
    assert returned["video_error"] == returned["doctor"]  # the doctor's own line: what to install
    report = json.loads((out / "report.json").read_text())
    assert report["output"]["video_error"] == returned["doctor"]
    assert report["output"]["videos"] == [] and not (out / "videos").exists()
    assert report["episodes"] == 2 and report["success"]["count"] == 2  # scored in full
    assert {p.name for p in (out / "plots").iterdir()} >= {"success.png", "return.png"}
    md = (out / "report.md").read_text()
    assert "**Success: 100.0% (2/2" in md and "videos could not be made: RuntimeError" in md


def test_videos_made_before_a_failure_stay_listed(tmp_path, monkeypatch):
    calls = []

    def film_once(work, job):
        calls.append(job.seed)
        if len(calls) > 1:
            raise ValueError("encoder gave up\nat frame 3")
        return work.run(job.seed), b"not really a video"

    monkeypatch.setattr(EvalWork, "film", film_once)
    monkeypatch.setattr("kitbench.doctor.vulkan_error", lambda: None)  # this machine could render
    report = run_eval(EvalConfig.of(_suite(3), "zero", tmp_path / "report", videos=2), progress=False)
    assert report["output"]["video_error"] == "ValueError: encoder gave up"
    (video,) = report["output"]["videos"]
    assert video["seed"] == 1_000_000 and video["matches_scored_episode"]
    on_disk = json.loads((tmp_path / "report" / "report.json").read_text())
    assert on_disk["output"] == report["output"]
    assert "videos could not be made: ValueError: encoder gave up" in (tmp_path / "report" / "report.md").read_text()


# -- the report folder -----------------------------------------------------------------------------
def test_an_existing_report_folder_is_refused_and_left_alone(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "report.json").write_text("the last evaluation")
    with pytest.raises(KitbenchError) as err:
        run_eval(EvalConfig.of(_suite(1), "zero", out), progress=False)
    assert str(err.value) == f"report folder {out} exists; pass --overwrite to replace it"
    assert [p.name for p in out.iterdir()] == ["report.json"]
    assert (out / "report.json").read_text() == "the last evaluation"


def test_a_file_as_report_folder_is_refused(tmp_path):
    out = tmp_path / "report"
    out.write_text("a file")
    with pytest.raises(KitbenchError, match=rf"^report folder {out} is a file; --out must be a folder") as err:
        run_eval(EvalConfig.of(_suite(1), "zero", out, overwrite=True), progress=False)
    assert "\n" not in str(err.value)
    assert out.read_text() == "a file" and [p.name for p in tmp_path.iterdir()] == ["report"]


def test_overwrite_replaces_the_report_and_nothing_else(tmp_path):
    out = tmp_path / "report"
    (out / "plots").mkdir(parents=True)
    (out / "plots" / "stale.png").write_bytes(b"")
    (out / "report.json").write_text("the last evaluation")
    (out / "notes.txt").write_text("mine")
    report = run_eval(EvalConfig.of(_suite(1), "zero", out, overwrite=True), progress=False)
    assert json.loads((out / "report.json").read_text())["episodes"] == report["episodes"] == 1
    assert not (out / "plots" / "stale.png").exists()
    assert (out / "notes.txt").read_text() == "mine"


# -- physics errors --------------------------------------------------------------------------------
def _episode(seed: int, failure: str, error: str | None = None) -> EpisodeResult:
    criteria = {"upright": False, "at_height": False}
    return EpisodeResult(seed, False, 7, None, 0.5, criteria, failure, physics_error=error)


def test_physics_errors_are_their_own_failure_category_in_reports():
    error = "PhysX diverged at step 7: peg moves at 1e+03 m/s (limit 10)"
    results = [_episode(1, "dropped"), _episode(2, "physics_error", error), _episode(3, "never_grasped")]
    report = build_report(_suite(3), "random", results, 0.05)
    assert list(report["failure_categories"]) == [*LiftPegUprightEnv.failure_categories, "physics_error"]
    assert report["failure_categories"]["physics_error"] == 1
    assert sum(report["failure_categories"].values()) == 3
    assert report["per_episode"][1]["physics_error"] == error and report["per_episode"][0]["physics_error"] is None
    json.dumps(report, allow_nan=False)
    md = markdown(report)
    assert "| physics_error | 1 |" in md and f"- seed 2: {error}" in md


def test_reports_without_physics_errors_still_list_the_category():
    report = build_report(_suite(1), "random", [_episode(1, "dropped")], 0.05)
    assert report["failure_categories"] == {
        "never_grasped": 0,
        "dropped": 1,
        "released": 0,
        "not_upright": 0,
        "wrong_height": 0,
        "physics_error": 0,
    }
    assert "Physics errors" not in markdown(report)


def test_scoring_on_images_without_a_render_device_is_one_line(tmp_path):
    out = tmp_path / "report"
    env = {**os.environ, "VK_ICD_FILENAMES": "/nonexistent.json", "VK_DRIVER_FILES": "/nonexistent.json"}
    run = launch.run(
        [
            sys.executable,
            "-m",
            "kitbench.cli",
            "eval",
            "--task",
            "LiftPegUpright-v1",
            "--episodes",
            "1",
            "--obs-mode",
            "rgb",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert run.returncode == 2, run.stderr[-2000:]
    assert run.stderr.count("\n") == 1 and "obs_mode 'rgb' needs camera images" in run.stderr
    assert "no usable Vulkan device" in run.stderr and not out.exists()
