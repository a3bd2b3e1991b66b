import atexit
import os
import shutil
import tempfile

import pytest

# Under pytest-xdist (`make test` runs a worker a core) each worker's torch keeps to one thread: two workers' OpenMP
# pools spinning against each other on two cores run torch an order of magnitude slower. Set before any test module
# imports torch, and inherited by the commands the tests start.
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["OMP_NUM_THREADS"] = "1"

# kitbench's frame cache (kitbench.training.frames) in a folder of the test run's own, set before any test module
# copies the environment for the lerobot commands it runs
if "KITBENCH_FRAME_CACHE" not in os.environ:
    os.environ["KITBENCH_FRAME_CACHE"] = tempfile.mkdtemp(prefix="kitbench-test-frames-")
    atexit.register(shutil.rmtree, os.environ["KITBENCH_FRAME_CACHE"], True)


def _vulkan_available() -> bool:
    try:
        import sapien

        sapien.render.RenderSystem()
        return True
    except Exception:  # noqa: BLE001  (whatever stops a renderer from starting means no usable device)
        return False


VULKAN = _vulkan_available()


@pytest.fixture
def needs_vulkan():
    if not VULKAN:
        if os.environ.get("CI"):
            pytest.fail("CI must render: no Vulkan device (the Makefile installs one when root)")
        pytest.skip("no Vulkan device on this machine")


@pytest.fixture(scope="session")
def tiny_act_run(tmp_path_factory):
    """A lerobot-train output folder of a small state ACT (`tests.lerobot_cli.small_config`: chunk_size 5) trained
    2 steps on 2 recorded LiftPegUpright-v1 episodes, a checkpoint saved at each step (`checkpoints/000001`,
    `checkpoints/000002`): for the commands that score several checkpoints or settings. About 25 s, once."""
    import json

    from kitbench.recording.recorder import RecordConfig, record
    from tests.lerobot_cli import lerobot_train, small_config

    base = tmp_path_factory.mktemp("tiny_act_run")
    data = base / "data"
    record(RecordConfig.of("LiftPegUpright-v1", 2, data, mcap=False), progress=False)
    info = json.loads((data / "meta/info.json").read_text())["features"]
    inputs = [n for n in info if n.startswith("observation.")]
    lerobot_train(small_config(data, base, inputs, "act", steps=2), data, base / "train", base, "--save_freq=1")
    return base / "train"


# KITBENCH_TEST_TIMES=FILE: each test's seconds (setup, call, teardown) appended as it ends, one line a phase, so a
# run stopped part way still says where its time went (pytest's --durations prints only at the end).
_TIMES = os.environ.get("KITBENCH_TEST_TIMES")


def pytest_runtest_logreport(report):
    if _TIMES:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(_TIMES, "a") as out:
            out.write(f"{report.duration:.2f}\t{report.when}\t{worker}\t{report.outcome}\t{report.nodeid}\n")


# The longest test files first (seconds measured with KITBENCH_TEST_TIMES on 2 cores): pytest-xdist hands out whole
# files (--dist loadfile) in collection order when told not to reorder them (--no-loadscope-reorder, as the Makefile
# runs it; by default it puts the files with the most tests first), so a long file collected last runs alone at the
# end while the other worker idles. Longest first, the short files fill in at the end. A file not named keeps its
# place.
LONGEST_FIRST = (
    "test_ray_executor.py",  # 180
    "test_image_configs.py",  # 122
    "test_eval_resume.py",  # 81
    "test_kill_points.py",  # 70
    "test_lerobot_integration.py",  # 59
    "test_train_levers.py",  # 53
    "test_demo.py",  # 45
    "test_reproduce.py",  # 45
    "test_kit_physics.py",  # 42
    "test_eval_inference.py",  # 42
    "test_training_input.py",  # 40
    "test_kill_points_writers.py",  # 40
    "test_damage.py",  # 40
    "test_denormals.py",  # 38
    "test_convert.py",  # 35
    "test_shipped_configs.py",  # 33
    "test_shards.py",  # 32
)


def _slow_without_a_twin(items) -> list[str]:
    """The tests marked `slow` none of whose siblings (the same test function, other parameters) runs in `make test`:
    a slow case is another case of a behaviour `make test` already guards, never the only one."""
    fast: set[tuple[str, str]] = set()
    slow: dict[tuple[str, str], str] = {}
    for item in items:
        key = (str(item.path), getattr(item, "originalname", item.name))
        if item.get_closest_marker("slow"):
            slow.setdefault(key, item.nodeid)
        else:
            fast.add(key)
    return [nodeid for key, nodeid in slow.items() if key not in fast]


def pytest_collection_modifyitems(config, items):
    if lonely := _slow_without_a_twin(items):
        raise pytest.UsageError(f"marked slow with no case of theirs left to make test: {', '.join(lonely)}")
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order
