"""What lerobot-train reads from a kitbench dataset: kitbench's reader gives stock `LeRobotDataset`'s samples bit for
bit from memory, its frame cache is built once per dataset state, and rgb stored as images is the renderer's exactly
(as video, within the codec's measured error); recordings of either storage train with stock `lerobot-train`."""

from __future__ import annotations

import json
import os
import pickle
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from kitbench import cli
from kitbench.recording.config import RecordConfig, load_recipe
from kitbench.recording.recorder import record
from kitbench.recording.work import RecordWork
from tests.lerobot_cli import OFFLINE, lerobot_train

ROOT = Path(__file__).resolve().parents[1]
LPU = "LiftPegUpright-v1"
# the stock h264 recording's frames against the renderer's (docs/training-input.md: 38-39 dB, worst 134-145)
VIDEO_MIN_PSNR_DB = 35.0


@pytest.fixture(autouse=True)
def frame_cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("KITBENCH_FRAME_CACHE", str(tmp_path / "frame-cache"))
    monkeypatch.delenv("KITBENCH_FAST_READER", raising=False)
    return tmp_path / "frame-cache"


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Two-episode LiftPegUpright recordings with rgb as video and as images, and one AssemblingKits episode with
    rgb, depth and segmentation (two cameras: depth video, 16-bit segmentation images; small, as only the two
    readers' agreement on them is asked)."""
    base = tmp_path_factory.mktemp("input")
    made = {}
    for name, settings in {
        "video": {"task": LPU, "obs_mode": "rgb", "episodes": 2},
        "images": {"task": LPU, "obs_mode": "rgb", "episodes": 2, "rgb_storage": "images"},
        "textures": {
            "task": "AssemblingKits-v1",
            "obs_mode": "rgb+depth+segmentation",
            "episodes": 1,
            "camera_size": "32x32",
        },
    }.items():
        config = RecordConfig.of(out=base / name, control_mode="pd_joint_pos", mcap=False, settle_steps=3, **settings)
        record(config, progress=False)
        made[name] = config
    return made


def _datasets(root: Path, **kwargs):
    """The same dataset read by stock's reader and by kitbench's."""
    from lerobot.datasets import lerobot_dataset
    from lerobot.datasets.dataset_reader import DatasetReader
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from kitbench.training.reader import FastReader

    made = []
    for reader in (DatasetReader, FastReader):
        original = lerobot_dataset.DatasetReader
        lerobot_dataset.DatasetReader = reader
        try:
            made.append(LeRobotDataset("kitbench/test", root=root, **{"video_backend": "pyav", **kwargs}))
        finally:
            lerobot_dataset.DatasetReader = original
    return made


def _shift():
    from lerobot.transforms import ImageTransformConfig, ImageTransforms, ImageTransformsConfig

    shift = ImageTransformConfig(type="RandomAffine", kwargs={"degrees": [0, 0], "translate": [0.05, 0.05]})
    return ImageTransforms(ImageTransformsConfig(enable=True, max_num_transforms=1, tfs={"shift": shift}))


def _assert_same_samples(stock, fast, count: int = 40) -> None:
    rng = random.Random(0)
    indices = [rng.randrange(len(stock)) for _ in range(count)]
    torch.manual_seed(7)
    expected = [stock[i] for i in indices]
    torch.manual_seed(7)
    got = [fast[i] for i in indices]
    assert fast.reader.fast is not None, "kitbench's reader fell back to lerobot's"
    for want, have in zip(expected, got, strict=True):
        assert list(want) == list(have)
        for key, value in want.items():
            if isinstance(value, str):
                assert value == have[key]
                continue
            assert (value.dtype, value.shape) == (have[key].dtype, have[key].shape), key
            assert torch.equal(value, have[key]), key


ACT_CHUNK = {"action": [i / 20 for i in range(10)]}


def _diffusion_window(cameras: list[str]) -> dict:
    return {"action": [i / 20 for i in range(-1, 15)], "observation.state": [-0.05, 0.0]} | {
        camera: [-0.05, 0.0] for camera in cameras
    }


def _backends() -> list[str]:
    from lerobot.datasets.video_utils import get_safe_default_video_backend

    return sorted({"pyav", get_safe_default_video_backend()})  # torchcodec where it loads, as lerobot-train picks


@pytest.mark.parametrize("storage,backend", [("video", b) for b in _backends()] + [("images", "pyav")])
@pytest.mark.parametrize("window", ["act", "diffusion"])
@pytest.mark.parametrize("as_uint8", [True, False])
def test_kitbench_reader_gives_stock_samples_bit_for_bit(recordings, needs_vulkan, storage, backend, window, as_uint8):
    cameras = ["observation.images.base_camera"]
    deltas = ACT_CHUNK if window == "act" else _diffusion_window(cameras)
    stock, fast = _datasets(
        recordings[storage].out,
        delta_timestamps=deltas,
        image_transforms=_shift(),
        return_uint8=as_uint8,
        video_backend=backend,
    )
    _assert_same_samples(stock, fast)


def test_depth_video_segmentation_images_and_an_episode_selection_are_served_as_stock_serves_them(
    recordings, needs_vulkan
):
    root = recordings["textures"].out
    info = json.loads((root / "meta/info.json").read_text())["features"]
    cameras = [k for k, v in info.items() if v["dtype"] in ("video", "image")]
    assert {info[k]["dtype"] for k in cameras} == {"video", "image"} and len(cameras) == 6
    for unit in ("mm", "m"):
        stock, fast = _datasets(
            root, delta_timestamps=_diffusion_window(cameras), return_uint8=True, depth_output_unit=unit
        )
        _assert_same_samples(stock, fast, count=20)
    stock, fast = _datasets(recordings["video"].out, episodes=[1], delta_timestamps=ACT_CHUNK, return_uint8=True)
    assert len(fast) < json.loads((recordings["video"].out / "meta/info.json").read_text())["total_frames"]
    _assert_same_samples(stock, fast, count=20)


def test_the_frame_cache_is_built_once_per_dataset_state_and_replaced_when_the_dataset_changes(
    recordings, needs_vulkan, frame_cache, tmp_path, monkeypatch
):
    import shutil

    from kitbench.training import reader as fast_reader

    root = tmp_path / "ds"
    shutil.copytree(recordings["video"].out, root)
    _, fast = _datasets(root, return_uint8=True)
    fast[0]
    built = sorted(p.name for p in frame_cache.iterdir() if p.is_dir())
    assert len(built) == 1 and (frame_cache / built[0] / "manifest.json").is_file()

    calls = []
    monkeypatch.setattr(fast_reader, "decode_video_frames", lambda *a, **k: calls.append(a) or 1 / 0)
    _, again = _datasets(root, return_uint8=True)
    again[3]  # served from the cache: decoding again would raise
    assert calls == []
    monkeypatch.undo()
    monkeypatch.setenv("KITBENCH_FRAME_CACHE", str(frame_cache))

    # the recording grows: the cache of its earlier state is replaced, not kept beside the new one
    config = recordings["video"].replace(out=root, episodes=3, resume=True)
    record(config, progress=False)
    stock, grown = _datasets(root, delta_timestamps=ACT_CHUNK, return_uint8=True)
    _assert_same_samples(stock, grown, count=20)
    now = sorted(p.name for p in frame_cache.iterdir() if p.is_dir())
    assert len(now) == 1 and now != built


def test_an_unwritable_cache_folder_decodes_into_memory_and_workers_reopen_the_files(
    recordings, needs_vulkan, tmp_path, monkeypatch
):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("KITBENCH_FRAME_CACHE", str(blocker / "cache"))
    stock, fast = _datasets(recordings["video"].out, delta_timestamps=ACT_CHUNK, return_uint8=True)
    _assert_same_samples(stock, fast, count=10)
    assert fast.reader.fast.frames.folder is None

    # a spawned loader worker gets the reader pickled: it reopens the cache files, it is not sent the frames
    monkeypatch.setenv("KITBENCH_FRAME_CACHE", str(tmp_path / "cache"))
    _, fast = _datasets(recordings["video"].out, return_uint8=True)
    fast[0]
    frames = fast.reader.fast.frames
    copy = pickle.loads(pickle.dumps(frames))
    assert copy.folder == frames.folder and len(pickle.dumps(frames)) < 1000
    key = "observation.images.base_camera"
    assert np.array_equal(copy.array(key), frames.array(key))
    assert pickle.loads(pickle.dumps(fast.reader)).fast is None  # rebuilt in the worker on its first sample


def test_stock_reader_serves_other_datasets_and_when_switched_off(recordings, needs_vulkan, tmp_path, monkeypatch):
    import shutil

    plain = tmp_path / "plain"
    shutil.copytree(recordings["video"].out, plain)
    (plain / "meta/kitbench_recording.json").unlink()  # not a kitbench recording any more: no settings file ...
    info = json.loads((plain / "meta/info.json").read_text())
    del info["features"]["episode_seed"]["info"]  # ... and no settings carried in the features
    (plain / "meta/info.json").write_text(json.dumps(info))
    _, fast = _datasets(plain, return_uint8=True)
    fast[0]
    assert fast.reader.fast is None
    monkeypatch.setenv("KITBENCH_FAST_READER", "0")
    _, off = _datasets(recordings["video"].out, return_uint8=True)
    off[0]
    assert off.reader.fast is None


def test_the_lerobot_plugin_installs_the_reader():
    code = (
        "from lerobot.utils.import_utils import register_third_party_plugins as r; r(); "
        "from lerobot.datasets import lerobot_dataset as d; print(d.DatasetReader.__module__)"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=OFFLINE, check=True)
    assert run.stdout.strip() == "kitbench.training.reader"


@pytest.mark.parametrize("storage", ["video", "images"])
def test_stored_frames_are_the_renderers_exactly_as_images_and_within_the_codec_as_video(
    recordings, needs_vulkan, storage
):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    config = recordings[storage]
    seeds = [
        json.loads(line)["seed"] for line in (config.out / "meta/kitbench_episodes.jsonl").read_text().splitlines()
    ]
    work = RecordWork(config)
    work.setup()
    try:
        rendered, _ = work.run(seeds[1])
    finally:
        work.close()
    dataset = LeRobotDataset("kitbench/test", root=config.out, video_backend="pyav", return_uint8=True)
    start = int(dataset.meta.episodes[1]["dataset_from_index"])
    key = "observation.images.base_camera"
    truth = np.stack([f[key].transpose(2, 0, 1) for f in rendered.frames]).astype(np.float64)
    stored = torch.stack([dataset[start + i][key] for i in range(len(rendered.frames))]).numpy()
    stored = stored.astype(np.float64) if stored.dtype == np.uint8 else np.rint(stored * 255)
    if storage == "images":
        assert np.array_equal(stored, truth)
    else:
        mse = np.mean((stored - truth) ** 2)
        assert 10 * np.log10(255**2 / mse) > VIDEO_MIN_PSNR_DB


# images: the same training on the other storage, whose frames kitbench's reader serves as stock's does (the
# bit-for-bit cases on images above)
@pytest.mark.parametrize("storage", ["video", pytest.param("images", marks=pytest.mark.slow)])
def test_each_storage_trains_with_stock_lerobot_train(recordings, needs_vulkan, storage, tmp_path):
    config = ROOT / "policies" / "act_lift_peg_upright_rgb.json"
    out = tmp_path / "train"
    lerobot_train(
        config,
        recordings[storage].out,
        out,
        tmp_path,
        "--policy.device=cpu",
        "--steps=2",
        "--batch_size=2",
        "--save_freq=2",
        "--policy.dim_model=32",
        "--policy.dim_feedforward=64",
    )
    assert (out / "checkpoints/000002/pretrained_model/model.safetensors").is_file()


@pytest.mark.parametrize("value", ["png", "", "VIDEO"])
def test_a_bad_rgb_storage_is_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys, value):
    monkeypatch.chdir(tmp_path)
    argv = ["record", "--task", LPU, "--episodes", "1", "--policy", "zero", "--obs-mode", "rgb"]
    assert cli.main([*argv, "--rgb-storage", value, "--out", "ds"]) == 2
    err = capsys.readouterr().err
    assert err == f"kitbench record: error: unknown rgb_storage {value!r}; valid choices: video, images\n"
    recipe = tmp_path / "r.toml"
    recipe.write_text(f'[record]\ntask = "{LPU}"\nepisodes = 1\nout = "ds"\nrgb_storage = "{value}"\n')
    assert cli.main(["record", str(recipe)]) == 2
    assert "valid choices: video, images" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.toml"]


def test_every_camera_recipe_says_how_it_stores_rgb():
    for path in sorted((ROOT / "datasets").glob("*.toml")):
        recipe = load_recipe(path)
        if recipe.env.obs_mode != "state":
            assert "rgb_storage" in path.read_text(), f"{path.name} does not say how it stores rgb"
            assert recipe.output.rgb_storage in ("video", "images")


def test_the_bench_refuses_unknown_configs_in_one_line():
    run = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "train_input.py"), "--configs", "act_nothing"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, **OFFLINE},
        check=False,
    )
    assert run.returncode == 2 and "unknown 'act_nothing'; valid choices: act_assembling_kits_rgb" in run.stderr


def test_a_recording_resumes_only_with_its_own_rgb_storage(recordings, tmp_path, capsys):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(recordings["images"].out, root)
    argv = ["record", "--task", LPU, "--episodes", "3", "--obs-mode", "rgb", "--control-mode", "pd_joint_pos"]
    argv += ["--settle-steps", "3", "--no-mcap", "--out", str(root), "--resume"]
    before = sorted(p.relative_to(root) for p in root.rglob("*"))
    assert cli.main(argv) == 2
    assert "rgb_storage: recorded 'images', asked 'video'" in capsys.readouterr().err
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before
