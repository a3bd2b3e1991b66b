"""The published figures as Markdown, generated from `policies/published.toml` (with the recipes and configs it
names): docs/results.md's table, policies/README.md's results and the README's headline sentence. Each lives in
its file between a begin and an end marker, so the prose around it stays written by hand; `make results` (`python
-m kitbench.figures`) rewrites the marked regions and a test fails when a file differs from what `render` makes.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Mapping
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.published import Published, load_published
from kitbench.shipped import CHECKOUT, ROOT

ROBOT_NAMES = {"panda": "Panda", "fetch": "Fetch", "so101": "SO-101"}
DEFAULT_CAMERA_SIZE = "128x128"  # kitbench.env_settings.OBSERVATION_SIZE: a recipe that names no size renders this
# The README's one headline figure: the loop its three commands run.
HEADLINE_CONFIG = "act_lift_peg_upright_state"
COMMAND = "kitbench reproduce"


def begin(region: str) -> str:
    return f"<!-- make results: {region} -->"


def end(region: str) -> str:
    return f"<!-- end {region} -->"


def percent(rate: float) -> str:
    return f"{rate:.1%}"


def interval(entry: Published) -> str:
    lo, hi = entry.interval
    return f"{lo * 100:.1f}–{percent(hi)}"


def robot_and_observation(entry: Published) -> str:
    """The task, robot and what the policy reads, from the row's recipe and its lerobot-train config."""
    from kitbench.recording.config import load_recipe

    recipe = load_recipe(entry.recipe)
    robot = ROBOT_NAMES.get(recipe.env.robot or "panda", str(recipe.env.robot))
    task = str(recipe.env.task).removesuffix("-v1")
    if recipe.env.obs_mode == "state":
        return f"{task}, {robot}: state"
    config = json.loads((ROOT / "policies" / f"{entry.config}.json").read_text())
    features = config["policy"].get("input_features") or {}
    cameras = [k.removeprefix("observation.images.") for k in features if k.startswith("observation.images.")]
    view = f", `{recipe.env.camera_view}` view" if recipe.env.camera_view else ""
    return (
        f"{task}, {robot}: {' + '.join(f'`{c}`' for c in cameras)} {recipe.env.camera_size or DEFAULT_CAMERA_SIZE}"
        f"{view}, joints"
    )


def per_seed(entry: Published) -> str:
    return ", ".join(f"{seed}: {percent(rate)}" for seed, rate in zip(entry.seeds, entry.seed_rates, strict=True))


def machine(entry: Published) -> str:
    if not entry.training_reference:
        return f"{entry.device}; no reference workload"
    threads = entry.threads or 1
    step = "" if entry.step_seconds is None else f"; a step {entry.step_seconds:.2f} s"
    # the scoring's minutes scale by their own reading where the training's minutes come from another run
    scoring = entry.reference_seconds if entry.reference_seconds != entry.training_reference else None
    apart = "" if scoring is None else f" as it trained, {scoring:.1f} s as it scored"
    return (
        f"{entry.device}; reference {entry.training_reference:.1f} s on {threads} thread{'s' if threads > 1 else ''}"
        f"{apart}{step}"
    )


def figure_from(entry: Published) -> str:
    """Which seeds the figure pools; from held-out seeds, the selection seeds' figures beside it."""
    if entry.figure_seeds == "selection" or entry.selection_rate is None:
        return f"{entry.figure_seeds} seeds"
    trained = zip(entry.selection_seeds, entry.selection_success, entry.selection_episodes, strict=True)
    cells = ", ".join(f"{seed}: {percent(s / n)}" for seed, s, n in trained)
    low, high = entry.interval
    side = "above" if entry.selection_rate > high else "below" if entry.selection_rate < low else ""
    outside = f"; {side} the held-out figure's interval" if side else ""
    where = "the test suites, before the split" if entry.selection_on_test_suites else f"`{entry.selection_suite}`"
    pooled = f"pooled {percent(entry.selection_rate)}{outside}"
    return f"held-out seeds; chosen at selection seeds {cells} on {where} ({pooled})"


def heldout(entry: Published) -> str:
    if entry.figure_seeds == "heldout":
        return ", ".join(map(str, entry.heldout_seeds)) + " (the figure)"
    from kitbench.evaluation.stats import wilson_interval

    trained = zip(entry.heldout_seeds, entry.heldout_success, entry.heldout_episodes, strict=False)
    # a seed whose own interval lies below the row's figure is said to, as figure_from says of a held-out figure
    below = "; the figure above its interval"
    cells = [
        f"{seed}: {percent(s / n)} ({s}/{n}{below * (wilson_interval(s, n)[1] < entry.rate)})" for seed, s, n in trained
    ]
    waiting = entry.heldout_seeds[len(cells) :]
    if waiting:
        cells.append(", ".join(map(str, waiting)) + " (not yet trained)")
    return "; ".join(cells)


def command(entry: Published) -> str:
    """The command that trains and scores a new seed as the figure's were: `--cpu` where they ran on the CPU."""
    return f"`{COMMAND} {entry.config}{' --cpu' if entry.cpu else ''}`"


def row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def results_table(published: Mapping[str, Published]) -> str:
    """docs/results.md's table: one row per published config."""
    header = [
        "config",
        "task, robot: observation",
        "demos",
        "steps",
        "success (pooled)",
        "95% CI",
        "each training seed",
        "figure from",
        "held-out seeds",
        "training",
        "machine",
        "reproduce",
    ]
    lines = [row(header), row(["---"] * len(header))]
    for name, entry in published.items():
        lines.append(
            row(
                [
                    f"`{name}`",
                    robot_and_observation(entry),
                    f"{entry.demos:,}",
                    f"{entry.steps:,}",
                    f"{entry.success}/{entry.episodes} = {percent(entry.rate)}",
                    interval(entry),
                    per_seed(entry),
                    figure_from(entry),
                    heldout(entry),
                    f"{entry.train_minutes:.1f} min",
                    machine(entry),
                    command(entry),
                ]
            )
        )
    return "\n".join(lines)


def policies_section(published: Mapping[str, Published]) -> str:
    """policies/README.md's results: each config's pooled figure and training time, the rest in docs/results.md."""
    lines = [
        row(["config", "success (pooled over training seeds and suites)", "training"]),
        row(["---"] * 3),
    ]
    for name, entry in published.items():
        seeds = "/".join(map(str, entry.seeds))
        figure = f"{percent(entry.rate)} ({interval(entry)}), {entry.success}/{entry.episodes}"
        lines.append(
            row(
                [
                    f"`{name}`",
                    f"{figure}; {'held-out' if entry.figure_seeds == 'heldout' else 'selection'} seeds {seeds}",
                    f"{entry.train_minutes:.1f} min on {entry.device}",
                ]
            )
        )
    return "\n".join(lines)


def headline(published: Mapping[str, Published]) -> str:
    """The README's one sentence of figures."""
    entry = published[HEADLINE_CONFIG]
    seeds, suites = len(entry.seeds), len(entry.suites)
    per_suite = entry.episodes // (seeds * suites)
    # minutes are only half a figure without the machine's pace beside them (docs/results.md)
    ref = entry.training_reference
    reference = f" whose reference workload took {ref:.1f} s; `{COMMAND}` says what it takes on yours" if ref else ""
    return (
        f"This loop reaches {percent(entry.rate)} (95% CI {interval(entry)}) on LiftPegUpright from {entry.demos} "
        f"demonstrations, pooled over {seeds} {'held-out ' if entry.figure_seeds == 'heldout' else ''}training seeds "
        f"and {suites} suites of {per_suite} seeds, in "
        f"{entry.train_minutes:.1f} minutes of training on {entry.device}{reference}."
    )


Renderer = Callable[[Mapping[str, Published]], str]
# (file in the checkout, region, what fills it); a block region stands on lines of its own, an inline one in a line
REGIONS: tuple[tuple[str, str, Renderer, bool], ...] = (
    ("docs/results.md", "results table", results_table, True),
    ("policies/README.md", "results", policies_section, True),
    ("README.md", "headline", headline, False),
)


def replace_region(text: str, region: str, body: str, block: bool, where: str) -> str:
    """`text` with what stands between `region`'s markers replaced by `body`."""
    first, last = begin(region), end(region)
    if text.count(first) != 1 or text.count(last) != 1 or text.index(first) > text.index(last):
        raise KitbenchError(f"{where}: needs one {first!r} and, after it, one {last!r}")
    before, rest = text.split(first, 1)
    _, after = rest.split(last, 1)
    joint = "\n" if block else ""
    return f"{before}{first}{joint}{body}{joint}{last}{after}"


def render(root: Path = CHECKOUT, published: Mapping[str, Published] | None = None) -> dict[Path, str]:
    """Each generated file's text, regenerated in memory: what `make results` writes."""
    published = load_published(root / "policies" / "published.toml") if published is None else published
    out: dict[Path, str] = {}
    for name, region, renderer, block in REGIONS:
        path = root / name
        text = out.get(path) or path.read_text()
        out[path] = replace_region(text, region, renderer(published), block, name)
    return out


def write(files: Mapping[Path, str]) -> list[Path]:
    """Write the files that differ, each replaced whole (a temporary file renamed over it); the ones written."""
    written = []
    for path, text in files.items():
        if path.read_text() == text:
            continue
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
        written.append(path)
    return written


def main() -> int:
    try:
        written = write(render())
    except KitbenchError as exc:
        print(f"make results: error: {exc}", file=sys.stderr)
        return 2
    for path in written:
        print(f"rewrote {path.relative_to(CHECKOUT)}")
    if not written:
        print("the generated figures match policies/published.toml")
    return 0


if __name__ == "__main__":
    sys.exit(main())
