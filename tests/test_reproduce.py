"""`kitbench reproduce`: a shipped config recorded, trained and scored end to end at a tiny scale, its figure compared
with the stated published interval (exit 0 inside, 3 outside); every published figure names a shipped config and
recipe; bad input is one line with nothing written."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from kitbench import cli
from kitbench.reproduce import PUBLISHED, load_published

ROOT = Path(__file__).resolve().parents[1]
CONFIG = "act_lift_peg_upright_state"


def test_every_published_figure_names_a_shipped_config_and_recipe_and_every_state_config_has_one():
    published = load_published()
    state_configs = {p.stem for p in (ROOT / "policies").glob("*_state.json")}
    assert state_configs <= set(published)
    for name, entry in published.items():
        assert (ROOT / "policies" / f"{name}.json").is_file() and entry.recipe.is_file()
        assert 0 <= entry.success <= entry.episodes and entry.interval[0] <= entry.rate <= entry.interval[1]
        assert all((ROOT / "eval" / "suites" / f"{s}.toml").is_file() for s in entry.suites)
        config = json.loads((ROOT / "policies" / f"{name}.json").read_text())
        assert config["steps"] == entry.steps


def _published(tmp_path: Path, low: float, high: float) -> Path:
    text = PUBLISHED.read_text()
    start = text.index(f"[{CONFIG}]")
    end = text.index("\n[", start)
    entry, replaced = re.subn(r"(?m)^interval = \[.*\]$", f"interval = [{low}, {high}]", text[start:end])
    assert replaced == 1, f"no interval line in the [{CONFIG}] entry"
    path = tmp_path / f"published-{low}-{high}.toml"
    path.write_text(
        entry.replace('suites = ["lift_peg_upright"]', 'suites = ["lift_peg_upright", "lift_peg_upright_heldout"]')
    )
    return path


def test_reproduce_runs_end_to_end_and_compares_with_the_stated_interval(tmp_path, needs_vulkan, capsys):
    out = tmp_path / "run"
    argv = ["reproduce", CONFIG, "--steps", "2", "--demos", "2", "--eval-episodes", "2", "--out", str(out)]
    assert cli.main([*argv, "--published", str(_published(tmp_path, 0.0, 1.0))]) == 0
    printed = capsys.readouterr().out
    result = json.loads((out / "reproduce.json").read_text())
    assert result["episodes"] == 4 and result["inside"] is True  # two seeds of each of the two suites
    assert f"{CONFIG}: {result['success']}/4 = " in printed and "inside the published interval" in printed
    assert (out / "eval_lift_peg_upright_heldout" / "report.json").is_file()
    assert result["train_command"][-1] == "--seed=1000" and result["reference_seconds"] > 0
    assert result["reference_seconds_after_training"] > 0

    # the recording is resumed, not made again; an interval the figure misses exits 3
    low = min(0.99, result["success"] / 4 + 0.01)
    status = cli.main([*argv, "--published", str(_published(tmp_path, low, 1.0))])
    assert status == 3 and "outside the published interval" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args,message",
    [
        (
            ["act_nothing"],
            "unknown config 'act_nothing'; valid choices: act_assembling_kits_rgb, act_assembling_kits_state",
        ),
        ([CONFIG, "--steps", "0"], "steps must be a positive integer, got 0"),
        ([CONFIG, "--seed", "-1"], "seed must be a non-negative integer, got -1"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["reproduce", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("kitbench reproduce: error: ") and err.count("\n") == 1 and message in err
    assert list(tmp_path.iterdir()) == []
