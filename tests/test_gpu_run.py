"""studies/gpu/gpu_run.py, the lent GPU machine's prepared run: what it reads of lerobot-train's log and nvidia-smi's
samples, and its bad arguments."""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pytest

from studies.gpu.gpu_run import first_step_seconds, gpu_summary, main, slowest_imports, step_window

# lerobot-train's output as it reads in the log (tqdm's carriage returns already turned into newlines)
LOG = """INFO 2026-11-28 06:49:02 ot_train.py:447 Effective batch size: 64 x 1 = 64
Training:   0%|          | 0/300 [00:00<?, ?step/s]INFO 2026-11-28 06:49:02 ot_train.py:597 Start offline training
Training:   0%|          | 1/300 [00:25<2:04:43, 25.03s/step]
Training:   1%|▏         | 4/300 [00:25<23:31,  4.77s/step]
Training:  33%|███▎      | 100/300 [00:30<00:10, 18.90step/s]INFO 2026-11-28 06:49:32 ot_train.py:641 step:100 \
smpl:6K updt_s:0.071 data_s:0.235
Training: 100%|██████████| 300/300 [00:39<00:00, 33.47step/s]INFO 2026-11-28 06:49:41 ot_train.py:641 step:300 \
smpl:19K updt_s:0.033 data_s:0.007
"""


def _samples(start: str, busy: list[int]) -> str:
    t0 = datetime.strptime(start, "%Y/%m/%d %H:%M:%S")
    return "\n".join(
        f"{datetime.fromtimestamp(t0.timestamp() + i).strftime('%Y/%m/%d %H:%M:%S')}.250, {b}, {600 + i}"
        for i, b in enumerate(busy)
    )


def test_the_busy_share_is_taken_over_the_logged_steps_only():
    window = step_window(LOG)
    assert window == (datetime(2026, 11, 28, 6, 49, 32), datetime(2026, 11, 28, 6, 49, 41))
    # 30 idle seconds of start-up from 06:49:02, then 10 busy ones at 20% from 06:49:32, then 5 idle at exit
    samples = _samples("2026/11/28 06:49:02", [0] * 30 + [20] * 10 + [0] * 5)
    summary = gpu_summary(samples, window)
    assert summary["samples"] == 9 and summary["gpu_busy_mean"] == pytest.approx(20.0)
    assert summary["gpu_busy_mean_run"] == pytest.approx(200 / 45)
    assert summary["gpu_memory_max_mib"] == 644


def test_no_samples_or_no_window_give_no_busy_figure():
    assert gpu_summary("", None)["gpu_busy_mean"] is None
    summary = gpu_summary(_samples("2026/11/28 06:49:02", [10, 30]), None)
    assert summary["gpu_busy_mean"] is None and summary["gpu_busy_mean_run"] == pytest.approx(20.0)
    assert step_window("INFO 2026-11-28 06:49:32 ot_train.py:641 step:100 updt_s:0.1 data_s:0.1") is None


def test_the_first_steps_wait_is_read_from_the_progress_bar():
    assert first_step_seconds(LOG) == 25
    assert first_step_seconds(LOG.replace("1/300 [00:25", "1/300 [02:25")) == 145
    assert first_step_seconds("no progress bar") is None


def test_import_time_is_summed_per_package_by_its_own_modules():
    importtime = """import time: self [us] | cumulative | imported package
import time:       191 |        191 |   _io
import time:    400000 |    900000 |     torch._C
import time:    100000 |   1000000 |   torch
import time:   2000000 |   2000000 |       diffusers.schedulers
import time:     50000 |   2100000 |     diffusers
import time:     30000 |   3200000 |   lerobot.policies.factory
"""
    assert slowest_imports(importtime, count=3) == {"diffusers": 2.05, "torch": 0.5, "lerobot": 0.03}


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--plan", "loader", "--pipelines", "during"], "--pipelines: 'during' is not a list of before, after"),
        (["--plan", "score", "--score-runs", "14"], "--score-runs: '14' is not WORKERSxBATCH, e.g. 14x10"),
        (["--plan", "loader", "--extra=--batch_size=256"], "--extra needs a --tag"),
        (["--plan", "learn", "--config", "act_nothing"], "no config policies/act_nothing.json"),
        (["--plan", "fit"], "invalid choice: 'fit'"),
    ],
)
def test_bad_arguments_are_one_line(argv, needle, tmp_path, capsys):
    with pytest.raises(SystemExit) as exited:
        main([*argv, "--out", str(tmp_path / "out")])
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("gpu_run: error:") and needle in err
    assert not (tmp_path / "out").exists()


def test_a_tagged_variant_keeps_its_own_log_beside_the_shipped_configs(tmp_path, monkeypatch):
    import studies.gpu.gpu_run as gpu_run

    def fake_run(cmd, log, env=None):
        batch = next((a.split("=")[1] for a in cmd if a.startswith("--batch_size=")), "64")
        log.write_text(f"INFO 2026-11-28 06:49:02 ot_train.py:447 Effective batch size: {batch} x 1 = {batch}\n")
        return 1.0

    monkeypatch.setattr(gpu_run, "run", fake_run)
    logs = tmp_path / "logs"
    logs.mkdir()
    shipped = argparse.Namespace(extra=[], tiny=False, tag="")
    variant = argparse.Namespace(extra=["--batch_size=256"], tiny=False, tag="b256")
    out = tmp_path / "train" / "after"
    first = gpu_run.train("act_lift_peg_upright_rgb", tmp_path, out, shipped, "kitbench", logs, 10)
    second = gpu_run.train("act_lift_peg_upright_rgb", tmp_path, out, variant, "kitbench", logs, 10)
    assert (first["batch_size"], second["batch_size"]) == (64, 256)
    # the variant's run did not overwrite the shipped config's log: both can be read after the run
    assert "size: 64 x" in (logs / "train_act_lift_peg_upright_rgb_after.log").read_text()
    assert "size: 256 x" in (logs / "train_act_lift_peg_upright_rgb_after_b256.log").read_text()


LEARN_SCRIPT = Path(__file__).resolve().parents[1] / "studies" / "gpu" / "gpu_learn.sh"


def test_the_learn_script_runs_both_trainings_each_with_its_variant_as_one_argument(tmp_path):
    calls = tmp_path / "calls.jsonl"
    fake = tmp_path / "python"
    fake.write_text(
        f"#!{sys.executable}\nimport json, sys\nopen({str(calls)!r}, 'a').write(json.dumps(sys.argv[1:]) + '\\n')\n"
    )
    fake.chmod(0o755)
    env = {**os.environ, "PY": str(fake), "PATH": "/usr/bin:/bin"}
    env.pop("TINY", None)
    done = subprocess.run(
        ["bash", str(LEARN_SCRIPT), "run", str(tmp_path / "kb")], env=env, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    runs = {
        argv[argv.index("--out") + 1].rsplit("/", 1)[1]: argv
        for argv in map(json.loads, calls.read_text().splitlines())
    }
    assert set(runs) == {"ak", "diffusion"}
    ak, diffusion = runs["ak"], runs["diffusion"]
    assert ak[ak.index("--config") + 1] == "act_assembling_kits_rgb_cpu"
    assert "--extra=--policy.device=cuda --batch_size=256 --num_workers=8" in ak and ak[-2:] == ["--tag", "gpu"]
    assert diffusion[diffusion.index("--config") + 1] == "diffusion_lift_peg_upright_rgb_cpu"
    assert "--extra=--policy.device=cuda --policy.use_amp=false --num_workers=6" in diffusion
    # the recordings split the 14 workers between them
    assert int(ak[ak.index("--workers") + 1]) + int(diffusion[diffusion.index("--workers") + 1]) == 14
    assert "== all done" in (tmp_path / "kb" / "run.log").read_text()


def test_the_learn_script_names_its_commands_on_a_bad_one(tmp_path):
    done = subprocess.run(["bash", str(LEARN_SCRIPT), "train", str(tmp_path)], capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip() == "gpu_learn.sh: unknown command 'train' (choose run, collect or receive)"


def _recording(root: Path, task: str, image_shape: list[int], files: dict[str, int]) -> Path:
    """A stand-in recording: the metadata `--data` and the packing read, and files of the given sizes."""
    (root / "meta").mkdir(parents=True)
    (root / "meta" / "kitbench_recording.json").write_text(json.dumps({"task": task}))
    info = {"total_episodes": 7, "features": {"observation.images.base_camera": {"shape": image_shape}}}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    for rel, size in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(os.urandom(size))
    return root


def test_packed_recordings_come_back_whole_from_their_folders_and_a_lost_file_is_named(tmp_path):
    from studies.gpu.gpu_pack import check, pack

    kib = 1024
    files = {"videos/a.mp4": 600 * kib, "data/a.parquet": 300 * kib}
    ak = _recording(tmp_path / "ak", "AssemblingKits-v1", [64, 64, 3], files)
    lpu = _recording(tmp_path / "lpu", "LiftPegUpright-v1", [128, 128, 3], {"videos/b.mp4": 500 * kib})
    folders = pack({"ak": ak, "diffusion": lpu}, tmp_path / "carry", mib=1.0)
    sizes = [sum(p.stat().st_size for p in f.rglob("*") if p.is_file() and p.name != "gpu_pack.json") for f in folders]
    assert len(folders) == 2 and max(sizes) <= 2**20  # 1.4 MiB of files, no folder over its 1 MiB
    merged = tmp_path / "merged"
    merged.mkdir()
    for folder in folders:
        subprocess.run(["cp", "-r", f"{folder}/.", str(merged)], check=True)
    assert check(merged) == []
    assert (merged / "ak" / "videos" / "a.mp4").read_bytes() == (ak / "videos" / "a.mp4").read_bytes()
    assert (merged / "diffusion" / "meta" / "kitbench_recording.json").is_file()
    (merged / "ak" / "data" / "a.parquet").unlink()
    assert check(merged) == ["ak/data/a.parquet is missing"]


def test_a_packed_file_larger_than_a_folder_is_refused(tmp_path):
    from studies.gpu.gpu_pack import main as pack_main

    ak = _recording(tmp_path / "ak", "AssemblingKits-v1", [64, 64, 3], {"videos/a.mp4": 2 * 2**20})
    with pytest.raises(SystemExit, match=r"ak/videos/a\.mp4 is larger than --mib 1"):
        pack_main([f"ak={ak}", "--out", str(tmp_path / "carry"), "--mib", "1"])
    assert not (tmp_path / "carry").exists()
    assert pack_main([f"ak={tmp_path}", "--out", str(tmp_path / "carry")]) == 2


@pytest.mark.parametrize(
    ("task", "shape", "needle"),
    [
        ("LiftPegUpright-v1", [64, 64, 3], "records LiftPegUpright-v1; act_assembling_kits_rgb_cpu trains on"),
        ("AssemblingKits-v1", [128, 128, 3], "has observation.images.base_camera [128, 128, 3]; act_assembling_kits"),
    ],
)
def test_a_carried_recording_that_does_not_suit_the_config_is_refused_before_training(tmp_path, task, shape, needle):
    data = _recording(tmp_path / "rec", task, shape, {})
    argv = [
        "--plan",
        "learn",
        "--config",
        "act_assembling_kits_rgb_cpu",
        "--data",
        str(data),
        "--out",
        str(tmp_path / "o"),
    ]
    with pytest.raises(SystemExit, match=re.escape(needle)):
        main(argv)
    assert not (tmp_path / "o" / "learn.json").exists()


def test_the_learn_script_receives_packed_folders_and_trains_on_them_once_they_are_whole(tmp_path):
    """Each command's packed folder is copied off at once (the next command's carry removes it); the run then
    trains on the recordings with --data, after the manifest finds every file."""
    from studies.gpu.gpu_pack import pack

    ak = _recording(tmp_path / "ak", "AssemblingKits-v1", [64, 64, 3], {"videos/a.mp4": 600 * 1024})
    lpu = _recording(tmp_path / "lpu", "LiftPegUpright-v1", [128, 128, 3], {"videos/b.mp4": 500 * 1024})
    folders = pack({"ak": ak, "diffusion": lpu}, tmp_path / "carry", mib=1.0)
    kb = tmp_path / "kb"
    for folder in folders:  # one command each: only that folder came
        only = tmp_path / f"sent_{folder.name}"
        only.mkdir()
        folder.rename(only / folder.name)
        env = {**os.environ, "PACKED": str(only)}
        done = subprocess.run(["bash", str(LEARN_SCRIPT), "receive", str(kb)], env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
    calls = tmp_path / "calls.jsonl"
    fake = tmp_path / "python"
    fake.write_text(
        f"#!{sys.executable}\nimport json, subprocess, sys\n"
        f"open({str(calls)!r}, 'a').write(json.dumps(sys.argv[1:]) + '\\n')\n"
        # the manifest check runs for real; the trainings are only recorded
        f"real = 'gpu_pack' in sys.argv[1]\n"
        f"sys.exit(subprocess.run([{sys.executable!r}, *sys.argv[1:]]).returncode if real else 0)\n"
    )
    fake.chmod(0o755)
    env = {**os.environ, "PY": str(fake)}
    env.pop("TINY", None)
    done = subprocess.run(["bash", str(LEARN_SCRIPT), "run", str(kb)], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    argvs = [json.loads(line) for line in calls.read_text().splitlines()]
    assert argvs[0][-2:] == ["--check", str(kb / "data")]
    runs = {a[a.index("--out") + 1].rsplit("/", 1)[1]: a for a in argvs[1:]}
    assert runs["ak"][runs["ak"].index("--data") + 1] == str(kb / "data" / "ak")
    assert runs["diffusion"][runs["diffusion"].index("--data") + 1] == str(kb / "data" / "diffusion")
    # a file lost on the way stops the run before any training
    (kb / "data" / "ak" / "videos" / "a.mp4").unlink()
    calls.unlink()
    done = subprocess.run(["bash", str(LEARN_SCRIPT), "run", str(kb)], env=env, capture_output=True, text=True)
    assert "ak/videos/a.mp4 is missing" in (kb / "run.log").read_text()
    assert [json.loads(line)[0] for line in calls.read_text().splitlines()] == ["studies/gpu/gpu_pack.py"]


def test_receiving_with_no_packed_folder_is_one_line(tmp_path):
    env = {**os.environ, "PACKED": str(tmp_path / "nothing")}
    done = subprocess.run(
        ["bash", str(LEARN_SCRIPT), "receive", str(tmp_path / "kb")], env=env, capture_output=True, text=True
    )
    assert done.returncode == 2
    assert done.stderr.strip() == "gpu_learn.sh: no packed folder (.gpu/data*) came with this command"
