"""Bad input to `kitbench record` and `kitbench eval` is refused before anything is written, with one line that
names the bad value and what is valid, and exit status 2; plus the options that go with those checks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import kitbench
from kitbench import cli
from kitbench.errors import KitbenchError
from kitbench.evaluation.suite import adhoc_suite, load_suite
from kitbench.recording.config import RecordConfig, load_recipe
from kitbench.registration import task_entry

os.environ.setdefault("HF_HUB_OFFLINE", "1")

TASK = "LiftPegUpright-v1"
GYM_ID = f"kitbench/{TASK}"
# cheap settings: a test that fails on a regression should not record for long before it does
RECORD = ["record", "--task", TASK, "--episodes", "2", "--policy", "zero", "--no-mcap"]
EVAL = ["eval", "--task", TASK, "--episodes", "2", "--policy", "zero"]


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    """An empty folder that is also the working directory, so that a default output path lands in it too."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _error(capsys, argv: list[str]) -> str:
    """The one error line the command prints (exit status 2, nothing on stdout), without its prefix."""
    assert cli.main(argv) == 2
    printed = capsys.readouterr()
    prefix = f"kitbench {argv[0]}: error: "
    assert printed.out == "" and printed.err.startswith(prefix) and printed.err.count("\n") == 1, printed.err
    return printed.err[len(prefix) : -1]


def _tree(root: Path) -> list[str]:
    """Everything under `root`, dot files included (a session, journal or mcap temp folder would show)."""
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


# -- 1: seeds are non-negative integers ------------------------------------------------------------
def test_record_refuses_a_negative_seed(workdir, capsys):
    out = workdir / "ds"
    assert _error(capsys, [*RECORD, "--seed", "-5", "--out", str(out)]) == "seed must be a non-negative integer, got -5"
    assert _tree(workdir) == []


def test_eval_refuses_a_negative_seed_on_the_command_line_and_in_a_suite(workdir, capsys):
    out = workdir / "report"
    assert _error(capsys, [*EVAL, "--seed", "-5", "--out", str(out)]) == "seed must be a non-negative integer, got -5"
    suite = workdir / "suite.toml"
    suite.write_text(f'[suite]\ntask = "{TASK}"\nseeds = [3, -5]\n')
    assert (
        _error(capsys, ["eval", "--suite", str(suite), "--out", str(out)])
        == f"suite {suite}: seeds must be non-negative integers, got -5"
    )
    assert _tree(workdir) == ["suite.toml"]


# -- 2: --resume needs something to resume ---------------------------------------------------------
def test_resume_without_a_recording_is_refused(workdir, capsys):
    out = workdir / "ds"
    assert _error(capsys, [*RECORD, "--resume", "--out", str(out)]) == (
        f"nothing to resume at {out} (drop --resume to start one)"
    )
    assert _tree(workdir) == []


def test_a_recording_killed_before_its_first_commit_is_resumed_or_replaced_never_reused(workdir, capsys):
    """Such a run leaves only its journal: --resume compares its settings, a plain run refuses to mix in its
    episodes."""
    from kitbench.recording.journal import SETTINGS_FILE, journal_root

    out = workdir / "ds"
    journal = journal_root(out)
    journal.mkdir()
    settings = {**RecordConfig.of(task=TASK, episodes=2, out=out, policy="random").info().to_json(), "fps": 20}
    (journal / SETTINGS_FILE).write_text(json.dumps(settings))
    before = _tree(workdir)
    assert _error(capsys, [*RECORD, "--out", str(out)]) == (
        f"an unfinished recording of {out} exists ({journal}); pass --resume to continue it or --overwrite to "
        "replace it"
    )
    assert _error(capsys, [*RECORD, "--resume", "--out", str(out)]) == (
        f"cannot resume {out} with different settings (policy: recorded 'random', asked 'zero')"
    )
    assert _tree(workdir) == before


# -- 3: --out must be a folder ---------------------------------------------------------------------
@pytest.mark.parametrize("flags", [[], ["--overwrite"], ["--resume"]])
def test_an_output_that_is_a_file_is_refused_and_left_alone(workdir, capsys, flags):
    out = workdir / "notes.txt"
    out.write_text("keep me\n")
    assert _error(capsys, [*RECORD, *flags, "--out", str(out)]) == (
        f"output {out} is not a folder; give --out a folder path"
    )
    assert _error(capsys, [*RECORD, *flags, "--out", str(out / "ds")]) == (
        f"output {out / 'ds'} is not a folder ({out} is a file); give --out a folder path"
    )
    assert _tree(workdir) == ["notes.txt"] and out.read_text() == "keep me\n"


# -- 4: a mistyped table is named ------------------------------------------------------------------
def test_mistyped_tables_in_suites_and_recipes_are_named(workdir, capsys):
    suite = workdir / "suite.toml"
    suite.write_text(f'[sutie]\ntask = "{TASK}"\nseeds = [1000000]\n')
    assert _error(capsys, ["eval", "--suite", str(suite), "--out", str(workdir / "report")]) == (
        f"suite {suite}: unknown table [sutie]; the valid table is [suite] (or put the keys at the top level)"
    )
    recipe = workdir / "recipe.toml"
    recipe.write_text(f'[recrd]\ntask = "{TASK}"\nepisodes = 2\nout = "ds"\n')
    assert _error(capsys, ["record", str(recipe)]) == (
        f"recipe {recipe}: unknown table [recrd]; the valid table is [record] (or put the keys at the top level)"
    )
    recipe.write_text(f'task = "{TASK}"\n[record]\nepisodes = 2\nout = "ds"\n')
    assert _error(capsys, ["record", str(recipe)]) == (
        f"recipe {recipe}: key(s) task outside the [record] table; move them into it"
    )
    assert _tree(workdir) == ["recipe.toml", "suite.toml"]


# -- 5: --commit-interval is a finite number >= 0 -------------------------------------------------
@pytest.mark.parametrize("value,shown", [("nan", "nan"), ("-1", "-1.0"), ("inf", "inf")])
def test_commit_interval_must_be_finite_and_not_negative(workdir, capsys, value, shown):
    out = workdir / "ds"
    assert _error(capsys, [*RECORD, "--commit-interval", value, "--out", str(out)]) == (
        f"commit_interval must be a finite number of seconds >= 0, got {shown}"
    )
    assert _tree(workdir) == []


# -- 6: --repo-id as the Hub accepts it ------------------------------------------------------------
@pytest.mark.parametrize(
    "repo_id,reason",
    [
        ("a/b/c", "repo id must be in the form 'repo_name' or 'namespace/repo_name'."),
        ("bad id", "repo id must use alphanumeric chars, '-', '_' or '.'."),
        ("", "repo id must use alphanumeric chars, '-', '_' or '.'."),
        ("me/x--y", "cannot have -- or .. in repo_id."),
    ],
)
def test_repo_id_is_checked_like_the_hub_does(workdir, capsys, repo_id, reason):
    out = workdir / "ds"
    message = _error(capsys, [*RECORD, "--repo-id", repo_id, "--out", str(out)])
    assert message.startswith(f"invalid repo_id {repo_id!r}: {reason}"), message
    assert _tree(workdir) == []


# -- 7: a task may be named by its gym id ----------------------------------------------------------
def test_the_gym_id_names_a_task_and_the_short_name_is_stored(workdir, capsys, monkeypatch):
    import kitbench.evaluation.runner as runner
    import kitbench.recording.recorder as recorder

    assert task_entry(GYM_ID) is task_entry(TASK)
    assert RecordConfig.of(task=GYM_ID, episodes=1, out=Path("x")).task == TASK
    assert adhoc_suite(GYM_ID, 2, seed=5).name == f"{TASK}-seeds-5-6"
    recipe, suite = workdir / "recipe.toml", workdir / "suite.toml"
    recipe.write_text(f'[record]\ntask = "{GYM_ID}"\nepisodes = 2\nout = "ds"\n')
    suite.write_text(f'[suite]\ntask = "{GYM_ID}"\nseeds = [1000000, 1000001]\n')
    assert load_recipe(recipe).task == TASK and load_suite(suite).task == TASK

    seen = []

    def checked_record(config, progress=True):
        recorder.validate(config)  # the real checks, without recording
        seen.append(config)
        return recorder.Summary()

    def checked_eval(config, progress=True):
        runner.validate(config)
        seen.append(config)
        return _report()

    monkeypatch.setattr(recorder, "record", checked_record)
    monkeypatch.setattr(runner, "run_eval", checked_eval)
    assert cli.main(["record", "--task", GYM_ID, "--episodes", "2", "--policy", "zero", "--out", "ds"]) == 0
    assert cli.main(["eval", "--task", GYM_ID, "--episodes", "2", "--policy", "zero", "--out", "report"]) == 0
    assert cli.main(["eval", "--suite", str(suite), "--task", GYM_ID, "--policy", "zero", "--out", "report"]) == 0
    assert [c.task for c in seen[:1]] + [c.suite.task for c in seen[1:]] == [TASK] * 3
    assert capsys.readouterr().err == ""
    assert _tree(workdir) == ["recipe.toml", "suite.toml"]


# -- 8: --version ----------------------------------------------------------------------------------
def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out == f"kitbench {kitbench.__version__}\n"


# -- 9: camera images need a Vulkan device ---------------------------------------------------------
def test_recording_images_without_a_vulkan_device_says_so_and_writes_nothing(tmp_path):
    no_device = {**os.environ, "VK_ICD_FILENAMES": "/nonexistent.json", "VK_DRIVER_FILES": "/nonexistent.json"}
    doctor = subprocess.run(
        [sys.executable, "-c", "from kitbench.doctor import vulkan_error; print(vulkan_error())"],
        env=no_device,
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    line = doctor.stdout.strip().splitlines()[-1]
    assert line != "None" and "no usable Vulkan device" in line
    for obs_mode in ("rgb", "rgbd", "segmentation", "pointcloud"):
        out = tmp_path / "ds"
        result = subprocess.run(
            [sys.executable, "-m", "kitbench.cli", *RECORD, "--obs-mode", obs_mode, "--out", str(out)],
            env=no_device,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 2 and result.stdout == ""
        assert result.stderr.splitlines()[-1] == (
            f"kitbench record: error: obs_mode {obs_mode!r} needs camera images: {line}"
        ), result.stderr
        assert _tree(tmp_path) == []


# -- 10 and 12: --max-attempts, and the recording's exit status -----------------------------------
@pytest.mark.parametrize("value", ["0", "1", "-3"])
def test_max_attempts_must_cover_the_episodes(workdir, capsys, value):
    out = workdir / "ds"
    assert _error(capsys, [*RECORD, "--max-attempts", value, "--out", str(out)]) == (
        f"max_attempts must be a positive integer >= episodes (2), got {value}"
    )
    recipe = workdir / "recipe.toml"
    recipe.write_text(f'[record]\ntask = "{TASK}"\nepisodes = 2\nout = "ds"\nmax_attempts = {value}\n')
    assert _error(capsys, ["record", str(recipe)]) == (
        f"max_attempts must be a positive integer >= episodes (2), got {value}"
    )
    assert _tree(workdir) == ["recipe.toml"]


def test_noise_phases_come_comma_separated_and_are_checked_against_the_expert(workdir, capsys, monkeypatch):
    import kitbench.recording.recorder as recorder

    expert = ["record", "--task", "AssemblingKits-v1", "--episodes", "2", "--no-mcap", "--out", "ds"]
    assert _error(capsys, [*expert, "--action-noise", "0.5", "--noise-phases", "transport,seat"]) == (
        "unknown noise phase 'seat' for the AssemblingKits-v1 expert; valid choices: approach, descend, grasp, "
        "regrasp, lift, transport, align, insert, release, retreat, failed"
    )
    assert _tree(workdir) == []
    seen = []
    monkeypatch.setattr(recorder, "record", lambda config, progress=True: seen.append(config) or recorder.Summary())
    assert cli.main([*expert, "--action-noise", "0.5", "--noise-phases", "transport,align"]) == 0
    assert [c.demo.noise_phases for c in seen] == [("transport", "align")]


@pytest.mark.parametrize("summary,status", [({"gave_up": True}, 3), ({"interrupted": True, "signal": 15}, 143)])
def test_record_passes_max_attempts_on_and_exits_with_the_summary_status(workdir, monkeypatch, summary, status):
    import kitbench.recording.recorder as recorder

    seen = []

    def fake_record(config, progress=True):
        seen.append(config)
        return recorder.Summary(**summary)

    monkeypatch.setattr(recorder, "record", fake_record)
    assert cli.main([*RECORD, "--max-attempts", "20", "--out", "ds"]) == status
    assert [c.demo.max_attempts for c in seen] == [20]
    assert RecordConfig.of(task=TASK, episodes=2, out=Path("ds")).demo.max_attempts is None  # 10 x episodes
    assert _tree(workdir) == []


# -- 11: eval --overwrite, and videos that could not be written -------------------------------------
def _report(**output) -> dict:
    """The parts of a report the command line prints."""
    return {
        "task": TASK,
        "policy": "zero",
        "episodes": 2,
        "success": {"rate": 0.0, "ci95": [0.0, 0.66]},
        "criteria": {},
        "failure_categories": {},
        "output": {"videos": [], "plots": [], **output},
    }


def test_eval_passes_overwrite_on_and_fails_when_its_videos_failed(workdir, capsys, monkeypatch):
    import kitbench.evaluation.runner as runner

    seen = []

    def fake_eval(config, progress=True):
        seen.append(config)
        return _report(video_error="ffmpeg not found") if config.output.videos else _report()

    monkeypatch.setattr(runner, "run_eval", fake_eval)
    assert cli.main([*EVAL, "--out", "report"]) == 0
    assert cli.main([*EVAL, "--out", "report", "--overwrite", "--videos", "1"]) == 1
    assert [c.output.overwrite for c in seen] == [False, True]
    printed = capsys.readouterr()
    assert printed.out.count("success 0.0%") == 2  # the summary is printed either way
    assert printed.err == "kitbench eval: videos failed: ffmpeg not found\n"
    assert _tree(workdir) == []


@pytest.mark.parametrize(
    "seeds", ['{ start = "x", count = 3 }', "{ start = 5, count = 0 }", "{ start = -1, count = 2 }"]
)
def test_a_bad_seed_range_in_a_suite_is_one_line(tmp_path, seeds):
    from kitbench.evaluation.suite import load_suite

    path = tmp_path / "s.toml"
    path.write_text(f'[suite]\ntask = "LiftPegUpright-v1"\nseeds = {seeds}\n')
    with pytest.raises(KitbenchError, match=r"seeds must be a list of integers or \{ start = S, count = N \}"):
        load_suite(path)
