"""kitbench installed from its wheel, with no checkout beside it: `kitbench reproduce`, `kitbench demo` and
`kitbench eval --suite <name>` find the configs, published figures, suites and recipes the wheel packs
(`kitbench.shipped`, `hatch_build.py`); in a checkout, a suite or recipe is found by its name from any folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from kitbench import cli

ROOT = Path(__file__).resolve().parents[1]

# Run by the wheel's kitbench from another folder: what each command reads, as JSON.
INSTALLED = """
import json, sys
from pathlib import Path

import kitbench
from kitbench import demo, reproduce, shipped
from kitbench.errors import KitbenchError
from kitbench.evaluation.suite import load_suite
from kitbench.recording.recorder import load_recipe
from kitbench.training.reference import Reading

entry = reproduce.check(reproduce.ReproduceConfig("act_lift_peg_upright_state"))
loop = demo.learning_loop(False, reading=Reading(1.0, 1.0))
try:
    shipped.find("nightly", "suite")
    unknown = None
except KitbenchError as exc:
    unknown = str(exc)
print(json.dumps({
    "kitbench": kitbench.__file__,
    "root": str(shipped.ROOT),
    "published": {name: [str(e.recipe), *(str(shipped.find(s, "suite")) for s in e.suites)]
                  for name, e in reproduce.load_published().items()},
    "reproduce_recipe": str(entry.recipe),
    "demo_suite": demo.demo_suite("LiftPegUpright-v1", 10).name,
    "demo_train": loop.train,
    "demo_record": str(load_recipe(shipped.find(loop.record[-1], "recipe")).out),
    "demo_score": load_suite(shipped.find(loop.score[loop.score.index("--suite") + 1], "suite")).name,
    "by_name": load_suite(shipped.find("lift_peg_upright", "suite")).name,
    "unknown": unknown,
}))
"""


def _uv() -> str | None:
    """The uv `make` bootstraps (scripts/ensure-uv.sh looks in the same places)."""
    for candidate in (shutil.which("uv"), Path.home() / ".local/bin/uv", ROOT / ".tools/bin/uv"):
        if candidate and Path(candidate).is_file():
            return str(candidate)
    return None


@pytest.fixture(scope="module")
def wheel_site(tmp_path_factory) -> Path:
    """The wheel `uv build` makes of this checkout, unpacked as an installer would."""
    uv = _uv()
    if uv is None:
        pytest.skip("no uv to build the wheel with (make bootstrap installs it)")
    dist = tmp_path_factory.mktemp("dist")
    built = subprocess.run(
        [uv, "build", "--wheel", "--offline", "--quiet", "-o", str(dist), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert built.returncode == 0, built.stderr[-2000:]
    site = tmp_path_factory.mktemp("site")
    (wheel,) = dist.glob("kitbench-*.whl")
    zipfile.ZipFile(wheel).extractall(site)
    return site


def test_the_commands_read_what_the_wheel_ships_with_no_checkout_beside_it(wheel_site, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(wheel_site)}  # ahead of the checkout the environment installs
    done = subprocess.run(
        [sys.executable, "-c", INSTALLED], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    found = json.loads(done.stdout.strip().splitlines()[-1])
    packed = wheel_site / "kitbench" / "_shipped"
    assert Path(found["kitbench"]).is_relative_to(wheel_site) and found["root"] == str(packed)
    assert len(found["published"]) >= 2
    for name, files in found["published"].items():
        assert all(Path(f).is_relative_to(packed) and Path(f).is_file() for f in files), name
        assert (packed / "policies" / f"{name}.json").is_file()
    assert Path(found["reproduce_recipe"]).is_relative_to(packed)
    assert found["demo_suite"] == "lift_peg_upright_short"
    config = Path(found["demo_train"][1].removeprefix("--config_path="))
    assert config.is_absolute() and config.is_file() and config.is_relative_to(packed)  # runs from any folder
    assert found["demo_record"].startswith("outputs/datasets/")  # the printed recipe, found from another folder
    assert found["demo_score"] == found["by_name"] == "lift_peg_upright"
    assert found["unknown"].startswith("unknown suite 'nightly'; valid choices: assembling_kits, ")
    assert not (tmp_path / "outputs").exists()


def test_a_suite_or_recipe_is_found_by_its_name_from_any_folder(tmp_path, monkeypatch, capsys):
    from kitbench.shipped import find

    monkeypatch.chdir(tmp_path)
    suite = ROOT / "eval" / "suites" / "lift_peg_upright.toml"
    assert find("lift_peg_upright", "suite") == find("eval/suites/lift_peg_upright.toml", "suite") == suite
    assert find("datasets/lift_peg_upright_state.toml", "recipe") == ROOT / "datasets" / "lift_peg_upright_state.toml"
    (tmp_path / "mine.toml").write_text("")
    assert find("mine.toml", "suite") == Path("mine.toml")  # a file here is the user's, not a shipped one
    assert cli.main(["eval", "--suite", "nightly", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown suite 'nightly'; valid choices: assembling_kits, " in err
    assert list(tmp_path.iterdir()) == [tmp_path / "mine.toml"]
