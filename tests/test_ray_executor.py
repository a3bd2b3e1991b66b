"""`--executor ray` on a two-node Ray cluster on 127.0.0.1 (Ray's own cluster utility: a head and a second node,
one CPU each, started and stopped here): the same dataset and report as a local one-worker run, a worker killed
with SIGKILL mid-run costs nothing, and bad settings are refused before anything is written."""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from kitbench import faults
from kitbench.engine import ExecutorConfig, RolloutEngine, make_executor
from kitbench.engine.ray_executor import RayExecutor
from kitbench.errors import KitbenchError
from kitbench.evaluation.config import EvalConfig
from kitbench.evaluation.runner import run_eval
from kitbench.evaluation.suite import load_suite
from kitbench.recording.recorder import RecordConfig, record
from tests import launch
from tests.datasets_equal import no_leftovers, same_content
from tests.engine_work import DiesOnceWork, SleepWork

ROOT = Path(__file__).resolve().parents[1]
SHORT = ROOT / "eval" / "suites" / "lift_peg_upright_short.toml"
# Loopback only: Ray replaces 127.0.0.1 by the machine's network address unless told it is a one-machine
# cluster; the cluster, this process's driver and the CLI's driver below all read this.
LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}
EPISODES = 6


@pytest.fixture(scope="module")
def cluster():
    for key, value in LOOPBACK_ENV.items():
        os.environ[key] = value
    from ray.cluster_utils import Cluster

    head = {"node_ip_address": "127.0.0.1", "num_cpus": 1, "include_dashboard": False}
    ray_cluster = Cluster(initialize_head=True, head_node_args=head)
    ray_cluster.add_node(node_ip_address="127.0.0.1", num_cpus=1)
    assert ray_cluster.address.startswith("127.0.0.1:")
    yield ray_cluster
    ray_cluster.shutdown()


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _same_dataset(a: Path, b: Path) -> None:
    """Every file byte for byte (MCAP logs and parquet included); stats.json as JSON (lerobot writes its keys in
    set order, which differs between processes)."""
    fa, fb = _files(a), _files(b)
    assert fa.keys() == fb.keys()
    stats = "meta/stats.json"
    assert json.loads(fa.pop(stats)) == json.loads(fb.pop(stats))
    different = [name for name in fa if fa[name] != fb[name]]
    assert not different, different


@pytest.fixture(scope="module")
def local_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "lpu"
    record(RecordConfig.of(task="LiftPegUpright-v1", episodes=EPISODES, out=out), progress=False)
    return out


# -- the engine on Ray -------------------------------------------------------------------------------
def test_ray_workers_run_on_both_nodes_and_results_come_in_order(cluster):
    executor = make_executor(ExecutorConfig("ray", 2, cluster.address))
    assert isinstance(executor, RayExecutor)
    with RolloutEngine(executor, SleepWork()) as engine:
        got = list(engine.results(range(10)))
        import ray

        nodes = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
    assert [job for job, _ in got] == list(range(10))
    assert [value for _, (value, _) in got] == [n * n for n in range(10)]
    assert len({pid for _, (_, pid) in got}) == 2
    assert len(nodes) == 2  # one CPU a node and one CPU an actor: an actor on each node


def test_a_worker_that_dies_is_restarted_and_its_job_delivered_once(cluster, tmp_path):
    with RolloutEngine(make_executor(ExecutorConfig("ray", 2, cluster.address)), DiesOnceWork(str(tmp_path), 4)) as e:
        values = list(e.map(range(8)))
    assert values == [n * 10 for n in range(8)]  # every job once, in order
    runs = [int(line) for line in (tmp_path / "runs").read_text().split()]
    assert runs.count(4) == 2 and (tmp_path / "died").exists()  # it did die, and its job ran again


def test_more_workers_than_the_cluster_has_cpus_is_refused(cluster):
    with pytest.raises(KitbenchError, match=r"^workers 3 needs 3 CPUs but the Ray cluster has 2;"):
        RolloutEngine(make_executor(ExecutorConfig("ray", 3, cluster.address)), SleepWork()).__enter__()


# -- record and eval ---------------------------------------------------------------------------------
def test_record_on_ray_writes_the_same_dataset_as_one_local_worker(cluster, local_dataset, tmp_path):
    out = tmp_path / "lpu"
    config = RecordConfig.of(
        task="LiftPegUpright-v1", episodes=EPISODES, out=out, executor="ray", workers=2, ray_address=cluster.address
    )
    summary = record(config, progress=False)
    assert summary.stored == EPISODES
    _same_dataset(local_dataset, out)


def test_sharded_recording_on_ray_writes_the_same_dataset_as_one_local_writer(cluster, local_dataset, tmp_path):
    out = tmp_path / "lpu"
    config = RecordConfig.of(
        task="LiftPegUpright-v1",
        episodes=EPISODES,
        out=out,
        executor="ray",
        workers=2,
        ray_address=cluster.address,
        shard_episodes=EPISODES // 2,  # a shard an actor
    )
    assert record(config, progress=False).stored == EPISODES
    same_content(local_dataset, out)


# Camera episodes at 64 pixels: the frames' way from the actor to the dataset is tested, not the pixels.
CAMERA = {"task": "LiftPegUpright-v1", "episodes": 2, "obs_mode": "rgb", "camera_size": "64", "mcap": False}


@pytest.fixture(scope="module")
def local_camera(tmp_path_factory):
    """The local one-worker camera recording both cases compare with, recorded once when first asked for (after
    `needs_vulkan`)."""

    @functools.cache
    def recorded() -> Path:
        out = tmp_path_factory.mktemp("camera") / "local"
        record(RecordConfig.of(**CAMERA, out=out), progress=False)
        return out

    return recorded


# Sharded (1), the frames are encoded into a shard in the actor: a variant whose parts make test runs already (a
# sharded recording on Ray above, shards' videos merged in test_merge.py) beside the frames' way from the actor
# to the writer (0), run by make test-all and CI.
@pytest.mark.parametrize("shard_episodes", [0, pytest.param(1, marks=pytest.mark.slow)])
def test_camera_recording_on_ray_decodes_to_the_same_frames_as_local(
    needs_vulkan, cluster, local_camera, tmp_path, shard_episodes
):
    """Camera episodes rendered in Ray actors (sent to the writer, or written into shards there) decode to the
    frames a local one-worker recording stores."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    on_ray = RecordConfig.of(
        **CAMERA,
        out=tmp_path / "ray",
        executor="ray",
        workers=2,
        ray_address=cluster.address,
        shard_episodes=shard_episodes,
    )
    record(on_ray, progress=False)
    local, ray_ds = LeRobotDataset("kitbench/a", root=local_camera()), LeRobotDataset("kitbench/b", root=on_ray.out)
    assert len(local) == len(ray_ds) and local.meta.video_keys == ray_ds.meta.video_keys
    for i in range(len(local)):
        a, b = local[i], ray_ds[i]
        for key in (*local.meta.video_keys, "observation.state", "action"):
            assert np.array_equal(a[key].numpy(), b[key].numpy()), (i, key)


def test_eval_on_ray_gives_the_same_report_numbers_as_local(cluster, tmp_path):
    suite = load_suite(SHORT).first(EPISODES)
    local = run_eval(EvalConfig.of(suite, "random", tmp_path / "local"), progress=False)
    ray_run = run_eval(
        EvalConfig.of(suite, "random", tmp_path / "ray", workers=2, executor="ray", ray_address=cluster.address),
        progress=False,
    )
    assert ray_run["timing"]["executor"] == "ray" and ray_run["timing"]["workers"] == 2
    for report in (local, ray_run):
        del report["timing"], report["output"]
    assert ray_run == local


def _record_command(out: Path, address: str, *extra: str, episodes: int = EPISODES, workers: int = 2) -> list[str]:
    return [
        sys.executable,
        "-m",
        "kitbench.cli",
        "record",
        "--task",
        "LiftPegUpright-v1",
        "--episodes",
        str(episodes),
        "--out",
        str(out),
        "--executor",
        "ray",
        "--workers",
        str(workers),
        "--ray-address",
        address,
        *extra,
    ]


def _start(command: list[str], logs: Path) -> launch.Started:
    """A run to watch and kill while it runs: a fork of the command server (`tests.launch`), a process of its own
    spared the interpreter's start, its output in files in `logs`."""
    env = {**os.environ, **LOOPBACK_ENV, "HF_HUB_OFFLINE": "1"}
    return launch.start(command, cwd=ROOT, env=env, logs=logs)


def _end(proc: launch.Started) -> tuple[str, str]:
    """SIGKILL `proc` unless it has ended, and its output."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    return proc.communicate(timeout=60)


def _run(command: list[str]) -> subprocess.CompletedProcess:
    """A run waited for (a resume): a fork of the command server (`tests.launch`), spared the interpreter's start."""
    env = {**os.environ, **LOOPBACK_ENV, "HF_HUB_OFFLINE": "1"}
    return launch.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _seeds(out: Path) -> list[int]:
    jsonl = out / "meta" / "kitbench_episodes.jsonl"
    return [json.loads(line)["seed"] for line in jsonl.read_text().splitlines()] if jsonl.is_file() else []


def test_kill_minus_nine_of_a_ray_worker_mid_recording_changes_nothing(cluster, local_dataset, tmp_path):
    out = tmp_path / "lpu"
    proc = _start(_record_command(out, cluster.address), tmp_path)
    journal = out.with_name(out.name + ".journal")
    killed = None
    deadline = time.monotonic() + 240
    try:
        while killed is None and proc.poll() is None and time.monotonic() < deadline:
            # mid-run: some episodes are done (journaled), more are to come
            if len(list(journal.glob("seed-*.npz"))) >= 1:
                workers = _actor_pids()
                if workers:
                    killed = workers[0]
                    os.kill(killed, signal.SIGKILL)
            time.sleep(0.05)
        proc.wait(timeout=300)
    finally:
        stdout, stderr = _end(proc)
    assert killed is not None, "no Ray worker to kill before the recording ended"
    assert proc.returncode == 0, stderr[-3000:]
    assert f"episodes stored: {EPISODES}" in stdout
    assert _seeds(out) == list(range(EPISODES))  # every seed exactly once, in order
    _same_dataset(local_dataset, out)


def test_resume_after_the_driver_is_killed_continues_from_the_last_committed_episode(cluster, local_dataset, tmp_path):
    out = tmp_path / "lpu"
    proc = _start(_record_command(out, cluster.address, "--commit-interval", "0"), tmp_path)
    deadline = time.monotonic() + 240
    try:
        while proc.poll() is None and len(_seeds(out)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        _end(proc)
    committed = _seeds(out)
    assert 2 <= len(committed) < EPISODES and committed == list(range(len(committed)))
    resumed = _run(_record_command(out, cluster.address, "--resume"))
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert _seeds(out) == list(range(EPISODES))
    same_content(local_dataset, out)


@pytest.mark.parametrize(
    ("extra", "fault"),
    [
        ((), "writer.saved:4"),
        # a variant whose parts make test runs already: a sharded kill (test_kill_points_writers.py, the same point)
        # and a sharded recording on Ray (above); run by make test-all and CI
        pytest.param(("--shard-episodes", "2"), "shards.merged:1", marks=pytest.mark.slow),
    ],
    ids=["one writer, a data file open", "sharded, the shards merged but not in place"],
)
def test_a_ray_recording_whose_driver_is_killed_at_a_fault_point_resumes_into_the_local_one(
    cluster, local_dataset, tmp_path, extra, fault
):
    out = tmp_path / "lpu"
    env = {**os.environ, **LOOPBACK_ENV, "HF_HUB_OFFLINE": "1", faults.VAR: fault}
    env.pop(faults.OWNER_VAR, None)
    killed = launch.run(
        _record_command(out, cluster.address, *extra), cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-3000:]
    resumed = _run(_record_command(out, cluster.address, "--resume", *extra))
    assert resumed.returncode == 0 and "Traceback" not in resumed.stderr, resumed.stderr[-3000:]
    same_content(local_dataset, out)
    no_leftovers(out)


def test_an_evaluation_on_ray_whose_driver_is_killed_resumes_into_the_uninterrupted_report(cluster, tmp_path):
    from tests.test_eval_resume import _eval_args, _killed, _ok, _resumed, same_report

    on_ray = ("--executor", "ray", "--workers", "2", "--ray-address", cluster.address)
    # four episodes: three journaled before the kill, one run by the resume
    _ok(tmp_path / "twin", _eval_args(*on_ray, episodes=4))
    _killed(tmp_path / "killed", _eval_args(*on_ray, episodes=4), "eval.journaled:3")
    _ok(tmp_path / "killed", _eval_args(*on_ray, "--resume", episodes=4))
    same_report(tmp_path / "twin" / "report", tmp_path / "killed" / "report")
    assert _resumed(tmp_path / "killed" / "report") == 3


def _actor_pids() -> list[int]:
    """Processes of the kitbench Ray actors (Ray names them ray::_EpisodeWorker)."""
    listing = launch.run(["ps", "-eo", "pid=,args="], capture_output=True, text=True).stdout
    return [int(line.split()[0]) for line in listing.splitlines() if "ray::_EpisodeWorker" in line]


# -- bad input -----------------------------------------------------------------------------------------
def test_an_unreachable_ray_address_is_refused_before_anything_is_written(tmp_path):
    out = tmp_path / "lpu"
    started = time.monotonic()
    with pytest.raises(KitbenchError) as err:
        record(
            RecordConfig.of(task="LiftPegUpright-v1", episodes=2, out=out, executor="ray", ray_address="127.0.0.1:9"),
            progress=False,
        )
    assert str(err.value).startswith("no Ray cluster answers at ray_address '127.0.0.1:9'")
    assert time.monotonic() - started < 30
    assert list(tmp_path.iterdir()) == []
    report = tmp_path / "report"
    with pytest.raises(KitbenchError, match="no Ray cluster answers"):
        run_eval(
            EvalConfig.of(load_suite(SHORT).first(2), "zero", report, executor="ray", ray_address="127.0.0.1:9"),
            progress=False,
        )
    assert list(tmp_path.iterdir()) == []


def test_ray_not_installed_is_one_line_before_anything_is_written(tmp_path):
    """Ray hidden from the import system, in a fresh process, as on an install without the extra."""
    code = (
        "import sys\n"
        "sys.modules['ray'] = None  # what `import ray` and find_spec('ray') then see: no Ray\n"
        "from kitbench.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    out = tmp_path / "lpu"
    done = launch.run(
        [sys.executable, "-c", code, "record", "--task", "LiftPegUpright-v1", "--episodes", "1"]
        + ["--out", str(out), "--executor", "ray"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.strip().splitlines()
    assert lines == [
        (
            "kitbench record: error: --executor ray needs Ray: pip install 'kitbench[ray]' (or use --executor local; "
            "valid: local, ray)"
        )
    ]
    assert list(tmp_path.iterdir()) == []


def test_results_are_numpy_episodes_not_paths(cluster):
    """What a Ray worker sends back holds the episode and its log, nothing on the worker's disk."""
    from kitbench.recording.work import RecordWork

    config = RecordConfig.of(task="LiftPegUpright-v1", episodes=1, out=Path("unused"))
    with RolloutEngine(make_executor(ExecutorConfig("ray", 1, cluster.address)), RecordWork(config)) as engine:
        ((seed, (episode, mcap)),) = list(engine.results([3]))
    assert seed == 3 and episode.seed == 3 and isinstance(mcap, bytes) and mcap.startswith(b"\x89MCAP")
    assert isinstance(episode.frames[0]["action"], np.ndarray)


def test_a_lost_head_ends_the_recording_in_one_line_saying_resume(tmp_path):
    """The whole cluster goes (its head node killed mid-run): one line naming the cluster and `--resume`, a non-zero
    exit, and the episodes finished before kept for the resume."""
    from ray.cluster_utils import Cluster

    for key, value in LOOPBACK_ENV.items():
        os.environ[key] = value
    doomed = Cluster(initialize_head=True, head_node_args={"node_ip_address": "127.0.0.1", "num_cpus": 2})
    out, address = tmp_path / "lpu", doomed.address
    # Episodes enough that the recording cannot finish between its first commit and the head's removal; one actor:
    # the cluster goes whole, however many it runs.
    command = _record_command(out, address, "--commit-interval", "0", episodes=10 * EPISODES, workers=1)
    proc = _start(command, tmp_path)
    deadline = time.monotonic() + 240
    try:
        while proc.poll() is None and len(_seeds(out)) < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        doomed.remove_node(doomed.head_node, allow_graceful=False)
        proc.wait(timeout=300)
    finally:
        _, stderr = _end(proc)
        doomed.shutdown()
    lines = [line for line in stderr.splitlines() if line.startswith("kitbench record: error:")]
    assert proc.returncode == 2 and len(lines) == 1, stderr[-3000:]
    assert f"the Ray cluster at {address} was lost" in lines[0] and "continue with --resume" in lines[0]
    assert "Traceback" not in stderr
    kept = _seeds(out)
    assert kept and kept == list(range(len(kept)))
