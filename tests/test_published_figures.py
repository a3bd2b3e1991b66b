"""Every published figure from one source: docs/results.md, policies/README.md's results and the README's headline
are what `make results` makes from policies/published.toml; the reader refuses a row whose held-out seeds were used
to choose, and the held-out seeds are the documented draw's; `kitbench reproduce` says what its training should take
here before it trains."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from kitbench import figures
from kitbench.errors import KitbenchError
from kitbench.published import HELDOUT_FIGURES, PUBLISHED, SELECTION_FIGURES, load_published
from kitbench.training.reference import Reading

ROOT = Path(__file__).resolve().parents[1]
CONFIG = "act_lift_peg_upright_state"


def test_the_generated_figures_match_published_toml():
    for path, text in figures.render(ROOT).items():
        assert path.read_text() == text, f"{path.relative_to(ROOT)} differs from policies/published.toml: make results"


def test_a_changed_figure_changes_every_generated_file_the_headline_included():
    published = load_published()
    changed, row = dict(published), published[figures.HEADLINE_CONFIG]
    seed_success = (row.seed_success[0] - 1, *row.seed_success[1:])
    changed[figures.HEADLINE_CONFIG] = dataclasses.replace(row, success=row.success - 1, seed_success=seed_success)
    before, after = figures.render(ROOT, published), figures.render(ROOT, changed)
    assert all(before[p] != after[p] for p in before), "a generated file does not show the row"
    rate = figures.percent((row.success - 1) / row.episodes)
    assert f"This loop reaches {rate} (95% CI " in after[ROOT / "README.md"]
    assert f"This loop reaches {figures.percent(row.rate)} (95% CI " in before[ROOT / "README.md"]


def test_a_file_without_its_markers_is_refused_in_one_line(tmp_path):
    for name, *_ in figures.REGIONS:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text((ROOT / name).read_text())
    (tmp_path / "policies" / "published.toml").write_text(PUBLISHED.read_text())
    (tmp_path / "README.md").write_text("no markers\n")
    with pytest.raises(KitbenchError) as refused:
        figures.render(tmp_path)
    assert str(refused.value).startswith("README.md: needs one '<!-- make results: headline -->'")
    assert "\n" not in str(refused.value)


def _draw_section() -> tuple[str, str]:
    text = (ROOT / "docs" / "results.md").read_text().split("### The held-out draw", 1)[1]
    code = re.search(r"```python\n(.*?)```", text, re.S)
    output = re.search(r"```text\n(.*?)```", text, re.S)
    assert code and output, "docs/results.md's draw lacks its code or its output"
    return code.group(1), output.group(1)


def test_the_heldout_seeds_are_the_documented_draw_and_disjoint_from_the_selection_seeds():
    code, output = _draw_section()
    ran = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert ran.stdout == output  # the code, run again, prints what the document says it printed
    drawn = {line.split(": ")[0]: json.loads(line.split(": ")[1]) for line in output.splitlines()}
    published = load_published()
    assert list(drawn) == list(published)
    # a row part-way through its held-out seeds: a seed whose own interval lies below the row's figure (93.8%) says
    # so; one whose interval holds it does not
    camera = dataclasses.replace(
        published["diffusion_lift_peg_upright_rgb_96_cpu"],
        figure_seeds="selection",
        success=563,
        episodes=600,
        seed_success=(190, 189, 184),
        heldout_success=(177,),
        heldout_episodes=(200,),
    )
    assert (
        figures.heldout(camera)
        == "19853: 88.5% (177/200; the figure above its interval); 74048, 80197 (not yet trained)"
    )
    inside = dataclasses.replace(camera, heldout_success=(188,))
    assert figures.heldout(inside) == "19853: 94.0% (188/200); 74048, 80197 (not yet trained)"
    for name, entry in published.items():
        assert list(entry.heldout_seeds) == drawn[name], name
        assert len(entry.heldout_seeds) >= 3 and not set(entry.heldout_seeds) & set(entry.selection_seeds)
        # reproduce's default seed is the first of the seeds the figure pools; a held-out figure keeps the selection
        # seeds' figures beside it
        assert entry.seeds[0] == (1000 if entry.figure_seeds == "selection" else entry.heldout_seeds[0]), name
        assert entry.figure_seeds == "selection" or entry.selection_rate is not None, name
        # the pooled figure is its training seeds' figures added up
        assert (sum(entry.seed_success), sum(entry.seed_episodes)) == (entry.success, entry.episodes), name


# a figure from held-out seeds, with its selection seeds' figures beside it
HELDOUT_FIGURE = {
    "figure_seeds": '"heldout"',
    "heldout_seeds": "[50000, 60000, 70000]",
    "heldout_success": None,
    "heldout_episodes": None,
    "selection_suite": '"lift_peg_upright_val"',
    "selection_success": "[99, 98, 97]",
    "selection_episodes": "[100, 100, 100]",
}


# what a row keeps only once its held-out seeds are in, or keeps optionally: `_row` starts without them
NOT_IN_A_SELECTION_ROW = (*HELDOUT_FIGURES, *SELECTION_FIGURES)


def _row(**changes: str | None) -> str:
    """The CONFIG row of published.toml as a selection figure (its held-out figures left out), with `changes` (key
    = its TOML value) written over it."""
    text = PUBLISHED.read_text()
    start = text.index(f"[{CONFIG}]")
    entry = text[start : text.index("\n[", start)]
    changes = {"figure_seeds": '"selection"', **dict.fromkeys(NOT_IN_A_SELECTION_ROW), **changes}
    for key, value in changes.items():
        if value is None:  # left out
            entry = re.sub(rf"(?m)^{key} = .*\n?", "", entry)
            continue
        entry, replaced = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", entry)
        if not replaced:
            entry += f"\n{key} = {value}"
    return entry


@pytest.mark.parametrize(
    "changes,message",
    [
        (
            {"heldout_seeds": "[2000, 50000, 60000]"},
            "heldout_seeds share 2000 with selection_seeds; a held-out seed is one never used to choose anything",
        ),
        ({"figure_seeds": '"test"'}, "figure_seeds is 'test'; valid choices: selection, heldout"),
        (
            {"figure_seeds": '"heldout"', "heldout_seeds": "[50000, 60000]", "seed_success": "[183, 368]"},
            "a figure from held-out seeds pools at least 3; got [50000, 60000]",
        ),
        ({"seed_success": "[183, 368]"}, "seed_success and seed_episodes give 2 and 3 figures for the 3 selection"),
        ({"selection_seeds": "[1000, 1000, 3000]"}, "selection_seeds [1000, 1000, 3000] repeats a seed"),
        ({"interval": "[0.89, 0.94]"}, "unknown key 'interval'; valid keys: recipe, demos"),
        ({"train_reference_seconds": "0"}, "train_reference_seconds is 0; give a positive number"),
        ({"step_seconds": '"fast"'}, "step_seconds is 'fast'; give a positive number"),
        ({"train_minutes": "-13.5"}, "train_minutes is -13.5; give a positive number"),
        ({"cpu": '"yes"'}, "cpu is 'yes'; valid choices: true, false"),
        (
            {"heldout_success": "[180, 170]", "heldout_episodes": "[200]"},
            "heldout_success and heldout_episodes give 2 and 1 figures; give one each for the first held-out seeds",
        ),
        (
            {"heldout_success": "[1, 2, 3, 4]", "heldout_episodes": "[200, 200, 200, 200]"},
            "give one each for the first held-out seeds trained, of 3",
        ),
        (
            {"heldout_success": "[201]", "heldout_episodes": "[200]"},
            "heldout_success [201] is not within 0..heldout_episodes",
        ),
        ({"selection_success": "[99, 98, 97]"}, "selection_success is for a figure from held-out seeds"),
        (
            {**HELDOUT_FIGURE, "heldout_success": "[199]", "heldout_episodes": "[200]"},
            "heldout_success is seed_success when figure_seeds is heldout; leave it out",
        ),
        (
            {**HELDOUT_FIGURE, "selection_episodes": "[100, 100]"},
            "selection_success and selection_episodes give 3 and 2 figures for the 3 selection seeds",
        ),
        ({**HELDOUT_FIGURE, "selection_success": "[99, 101, 97]"}, "selection_success [99, 101, 97] is not within"),
        (
            {**HELDOUT_FIGURE, "selection_suite": '"lift_peg_upright"'},
            "selection_suite 'lift_peg_upright' is one of the figure's suites",
        ),
        (
            {**HELDOUT_FIGURE, "selection_on_test_suites": "true"},
            "selection_on_test_suites has no selection_suite; the figure's are it",
        ),
        (
            {**HELDOUT_FIGURE, "selection_suite": None, "selection_success": None, "selection_on_test_suites": "true"},
            "selection_on_test_suites needs selection_success and selection_episodes",
        ),
    ],
)
def test_a_bad_row_is_refused_in_one_line_naming_it(tmp_path, changes, message):
    path = tmp_path / "published.toml"
    path.write_text(_row(**changes))
    with pytest.raises(KitbenchError) as refused:
        load_published(path)
    assert str(refused.value).startswith(f"published figures {path}: [{CONFIG}]") and "\n" not in str(refused.value)
    assert message in str(refused.value)


def test_a_heldout_figure_shows_the_selection_figures_beside_it(tmp_path):
    path = tmp_path / "published.toml"
    # a held-out figure of 551/600 (89.4-93.8%) beside selection figures at 97-99%
    below = {"success": "551", "episodes": "600", "seed_success": "[183, 185, 183]", "seed_episodes": "[200, 200, 200]"}
    path.write_text(_row(**HELDOUT_FIGURE, **below))
    entry = load_published(path)[CONFIG]
    assert entry.seeds == (50000, 60000, 70000) and entry.selection_rate == pytest.approx(0.98)
    shown = figures.figure_from(entry)
    assert "selection seeds 1000: 99.0%, 2000: 98.0%, 3000: 97.0% on `lift_peg_upright_val` (pooled 98.0%" in shown
    # the selection figure above the held-out figure's interval is said so
    assert entry.interval[1] < 0.98 and "above the held-out figure's interval" in shown
    # below it too (a figure the held-out seeds beat); inside it, neither
    path.write_text(_row(**{**HELDOUT_FIGURE, **below, "selection_success": "[50, 50, 50]"}))
    shown = figures.figure_from(load_published(path)[CONFIG])
    assert "below the held-out figure's interval" in shown and "above" not in shown
    path.write_text(_row(**{**HELDOUT_FIGURE, **below, "selection_success": "[92, 91, 92]"}))
    shown = figures.figure_from(load_published(path)[CONFIG])
    assert "held-out figure's interval" not in shown


def test_a_row_chosen_before_the_split_shows_its_selection_figures_on_the_test_suites(tmp_path):
    path = tmp_path / "published.toml"
    path.write_text(_row(**{**HELDOUT_FIGURE, "selection_suite": None, "selection_on_test_suites": "true"}))
    entry = load_published(path)[CONFIG]
    assert entry.selection_on_test_suites and entry.selection_suite is None
    assert "selection seeds 1000: 99.0%, 2000: 98.0%, 3000: 97.0% on the test suites, before the split" in (
        figures.figure_from(entry)
    )


def test_a_figure_trained_on_the_cpu_names_cpu_in_its_reproduce_command(tmp_path):
    path = tmp_path / "published.toml"
    path.write_text(_row(cpu="true"))
    assert f"| `kitbench reproduce {CONFIG} --cpu` |" in figures.results_table(load_published(path))
    path.write_text(_row())
    assert f"| `kitbench reproduce {CONFIG}` |" in figures.results_table(load_published(path))
    # a shipped row says so only of a config made for a GPU: a CPU config trains on the CPU without the flag
    from kitbench.training.device import config_device

    for name, entry in load_published().items():
        if entry.cpu:
            assert config_device(ROOT / "policies" / f"{name}.json") == "cuda", name


def test_the_learnability_bench_reads_the_same_rows_as_reproduce():
    sys.path.insert(0, str(ROOT))
    from bench import learnability

    for name, entry in load_published().items():
        assert learnability.published_entry(ROOT / "policies" / f"{name}.json") == entry
    assert learnability.published_entry(ROOT / "policies" / "act_lift_peg_upright_fetch_rgb.json") is None


def _stub_training(monkeypatch, step: float, after: float, after_share: float = 0.98) -> list[list[str]]:
    """lerobot-train stood in for (`tests.test_reproduce`'s stand-in), its probe taking `step` seconds a step; the
    reference workload after it reads `after`. The training commands it was asked to run."""
    from kitbench.training import pace
    from tests.test_reproduce import _trained_here

    monkeypatch.setattr(pace, "probe", lambda training, steps=None: step)
    return _trained_here(monkeypatch, Reading(after, after_share))


def test_reproduce_says_what_the_training_should_take_here_before_it_trains(tmp_path, monkeypatch):
    from kitbench.reproduce import ReproduceConfig, plan, train_policy
    from kitbench.training import pace

    row = load_published()[CONFIG]
    slow = 2 * row.training_reference
    planned = plan(ReproduceConfig(CONFIG, out=tmp_path, steps=row.steps // 2))
    commands = _stub_training(monkeypatch, step=2 * row.step_seconds, after=slow)
    said: list[str] = []
    threads: list[int] = []

    def twice_as_slow(n: int) -> Reading:  # this machine's reference workload: twice the published one's
        threads.append(n)
        return Reading(slow, 0.97)

    result, here = train_policy(planned, said.append, measure=twice_as_slow)
    assert result["reused"] is False and here == slow and threads == [1]  # the state config's published thread
    # half the published steps, each twice as slow here as the row's own: the published minutes
    assert said[0].startswith(f"timing {pace.PROBE_STEPS} steps of lerobot-train here")
    assert said[1] == (
        f"expected training time: about {row.train_minutes:.1f} min here for {row.steps // 2} steps (a step "
        f"{2 * row.step_seconds:.3f} s here, lerobot-train's own timing on 1 thread(s); published "
        f"{row.train_minutes:.1f} min for {row.steps} on {row.device} at {row.step_seconds:.3f} s a step)"
    )
    assert said[2].startswith("training: OMP_NUM_THREADS=1 ")
    assert len(commands) == 1 and result["probe_step_seconds"] == 2 * row.step_seconds
    # the same request again: its checkpoint reused, with nothing timed and no minutes expected of it, and the
    # readings its training had rather than the day's
    said.clear()
    result, here = train_policy(planned, said.append, measure=lambda n: Reading(37.5, 0.5))
    assert result["reused"] is True and len(commands) == 1
    assert here == slow and result["probe_step_seconds"] == 2 * row.step_seconds
    assert not [line for line in said if line.startswith(("timing", "expected training time", "the machine was"))]
    assert any(line.startswith("  reused the checkpoint the same command trained") for line in said)


def test_reproduce_says_when_the_machine_was_busy_as_the_reference_workload_was_timed(tmp_path, monkeypatch):
    """Another process on the same cores stalls torch's threads (docs/training.md, "A busy machine"):
    the reading is said to be busy before the minutes it scales, and marked in the verdict and reproduce.json."""
    from kitbench.reproduce import ReproduceConfig, plan, train_policy, verdict
    from kitbench.training import run

    row = load_published()[CONFIG]
    planned = plan(ReproduceConfig(CONFIG, out=tmp_path, steps=row.steps))
    _stub_training(monkeypatch, step=row.step_seconds, after=1.6)
    said: list[str] = []
    result, here = train_policy(planned, said.append, measure=lambda n: Reading(37.5, 0.5))
    assert said[0] == (
        "the machine was busy before the training: the reference workload had 50% of its 1 thread(s)' time (about "
        "100% alone: another process held the cores), so its 37.5 s say little of this machine and minutes scaled "
        "by it read long"
    )
    assert said[2].startswith("expected training time: about ")
    said.clear()
    verdict(planned, row.success // 3, row.episodes // 3, {**result, "step_seconds": None}, here, said.append)
    assert "reference workload 37.5 s (busy) before it, 1.6 s after;" in said[-1]
    stamped = json.loads(planned.result.read_text())
    assert (stamped["reference_share"], stamped["reference_share_after_training"]) == (0.5, 0.98)
    # a quiet reading is not marked
    (planned.policy_dir / run.TRAIN_STAMP).unlink()  # trained again
    result, _ = train_policy(planned, said.append, measure=lambda n: Reading(1.6, 0.97))
    said.clear()
    verdict(planned, row.success // 3, row.episodes // 3, {**result, "step_seconds": None}, 1.6, said.append)
    assert "reference workload 1.6 s before it, 1.6 s after;" in said[-1]


def test_the_reference_workload_beside_busy_processes_reads_busy(monkeypatch):
    """Processes spinning on every core (three runnable for each): the workload gets a share of its thread's time
    far under what it has alone, and says so. On 1 thread: on 2 the stall itself costs the test 20 s more."""
    import os

    from kitbench.training import reference

    monkeypatch.setattr(reference, "WARMUP", 1)
    monkeypatch.setattr(reference, "STEPS", 3)
    cores = os.cpu_count() or 1
    spin = "print(flush=True)\nwhile True: pass"  # says it runs, then spins
    spinners = [subprocess.Popen([sys.executable, "-c", spin], stdout=subprocess.PIPE) for _ in range(3 * cores)]
    try:
        for spinner in spinners:  # every one spinning before the workload is timed
            assert spinner.stdout is not None and spinner.stdout.readline() == b"\n"
        reading = reference.read(1)
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()
    assert reading.busy and reading.share < 0.5 and reading.seconds > 0


def test_a_row_without_a_reference_workload_is_not_scaled():
    from kitbench.reproduce import expectation

    # a row as the GPU rows were published before their held-out seeds: minutes on one H100, nothing to scale them by
    gpu = dataclasses.replace(
        load_published()["act_assembling_kits_rgb"],
        train_minutes=9.9,
        device="one H100",
        cpu=False,
        reference_seconds=None,
        train_reference_seconds=None,
        step_seconds=None,
        threads=None,
    )
    assert gpu.train_minutes_here(2.0) is None
    assert expectation(gpu, 2.0, 8).startswith(
        "expected training time: not scaled here (the published 9.9 min on one H100 came without a reference workload)"
    )
    # trained on a CPU (`--cpu`), its steps are timed here and said alone
    assert expectation(gpu, 2.0, 2, None, 0.9) == (
        "expected training time: its 3000 steps alone take about 45.0 min here (a step 0.900 s here, lerobot-train's "
        "own timing on 2 thread(s); the published 9.9 min on one H100 came without a step time or a reference workload)"
    )
