"""Settings are declared once (`kitbench.config`): the command line's flags, recipe and suite keys and the LeRobot
plugin's config are derived from the declarations, with the same names, defaults, help and checks."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from kitbench import cli
from kitbench.config import declare
from kitbench.config.checks import one_of, positive_int
from kitbench.config.declare import build, flatten, leaves, replace, resolve, setting
from kitbench.config.flags import flag_of
from kitbench.env_settings import PolicyEnvSettings
from kitbench.errors import KitbenchError
from kitbench.evaluation.suite import SUITE_KEYS
from kitbench.recording.config import RECIPE_KEYS, RecordConfig, load_recipe

COMMAND_CONFIGS = {
    command: [cli._imported(path) for path, _ in spec.settings] for command, spec in cli.COMMANDS.items()
}


@pytest.mark.parametrize("command", [c for c, configs in COMMAND_CONFIGS.items() if configs])
def test_every_flag_has_the_help_of_its_declaration(command, capsys):
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    spec = cli.COMMANDS[command]
    for config, (_, only) in zip(COMMAND_CONFIGS[command], spec.settings, strict=True):
        for name, leaf in leaves(config).items():
            if not leaf.meta("cli") or name in spec.skip or (only is not None and name not in only):
                continue
            help_text = " ".join(leaf.help.split())
            assert help_text, f"{config.__name__}.{name} has no help (a comment above its field)"
            assert help_text[:40] in text, (command, name)
            if not leaf.meta("positional"):
                assert flag_of(leaf) in text, (command, name)


def test_recipe_keys_are_the_record_flags_and_an_unknown_one_names_the_valid(tmp_path):
    flags = {n for n, leaf in leaves(RecordConfig).items() if leaf.meta("cli")}
    assert set(RECIPE_KEYS) == flags
    recipe = tmp_path / "r.toml"
    recipe.write_text('[record]\ntask = "LiftPegUpright-v1"\nepisodes = 1\nout = "x"\nobs_mod = "rgb"\n')
    with pytest.raises(KitbenchError, match=r"unknown key\(s\) obs_mod; valid keys: .*obs_mode"):
        load_recipe(recipe)


def test_a_recipe_layers_under_the_flags_and_nests_its_flat_keys(tmp_path):
    recipe = tmp_path / "r.toml"
    recipe.write_text(
        '[record]\ntask = "kitbench/LiftPegUpright-v1"\nepisodes = 3\nout = "x"\nworkers = 2\nmcap = false\n'
        'noise_phases = ["swing"]\naction_noise = 0.5\n'
    )
    config = load_recipe(recipe, workers=4, episodes=None)
    assert (config.task, config.episodes, config.executor.workers, config.output.mcap) == (
        "LiftPegUpright-v1",
        3,
        4,
        False,
    )
    assert config.demo.noise_phases == ("swing",) and config.out == Path("x")
    again = RecordConfig.of(**flatten(config))
    assert again == config
    assert replace(config, seed=7, overwrite=True).demo.seed == 7 and config.demo.seed == 0


def test_suite_keys_are_declared_settings():
    assert {"task", "seeds", "obs_mode", "control_mode", "reward_mode", "robot", "settle_steps", "executor"} <= set(
        SUITE_KEYS
    )
    assert "pointcloud_points" not in SUITE_KEYS


def test_layers_resolve_later_over_earlier_and_say_where_each_value_came_from():
    resolved = resolve(("suite", {"workers": 4, "executor": "ray"}), ("command line", {"workers": 2, "executor": None}))
    assert resolved.values == {"workers": 2, "executor": "ray"}
    assert resolved.asked_on("workers", "command line") and resolved.asked_on("executor", "suite")


def test_unknown_settings_and_bad_values_are_one_line():
    with pytest.raises(KitbenchError, match=r"unknown setting\(s\) epsiodes; valid ones: "):
        RecordConfig.of(task="LiftPegUpright-v1", epsiodes=2)
    config = RecordConfig.of(task="LiftPegUpright-v1", episodes=2, out="x", workers=0)
    with pytest.raises(KitbenchError, match=r"^workers must be a positive integer, got 0$"):
        declare.validate(config)
    with pytest.raises(KitbenchError, match=r"^unknown control_mode 'joints'; valid choices: pd_joint_delta_pos, "):
        declare.validate(RecordConfig.of(task="LiftPegUpright-v1", control_mode="joints"))


@dataclasses.dataclass
class Inner:
    # How many.
    count: int = setting(1, check=positive_int)


@dataclasses.dataclass
class Twice:
    inner: Inner = dataclasses.field(default_factory=Inner)
    # Again.
    count: int = setting(2, check=one_of((2,)))


def test_a_setting_is_declared_once_in_a_tree():
    with pytest.raises(TypeError, match="declared twice"):
        leaves(Twice)
    built = build(Inner, {"count": 3})
    assert built.count == 3 and leaves(Inner)["count"].help == "How many (default 1)."


def test_the_plugin_config_inherits_the_env_settings_with_their_help_and_checks():
    """draccus (lerobot's parser) reads the help of `--env.task`, `--env.robot`, `--env.control_mode` and
    `--env.pointcloud_points` from kitbench's declarations; their checks are the same."""
    from draccus.wrappers.docstring import get_attribute_docstring, get_preferred_help_text

    from lerobot_env_kitbench.config import KitbenchEnvConfig

    for name, leaf in leaves(PolicyEnvSettings).items():
        field = {f.name: f for f in dataclasses.fields(KitbenchEnvConfig)}[name]
        assert field.default == leaf.default or name == "task"
        text = " ".join(
            (get_preferred_help_text(get_attribute_docstring(KitbenchEnvConfig, name), "inline") or "").split()
        )
        assert text and text.removesuffix(".") in leaf.help, name
    with pytest.raises(KitbenchError, match=r"^unknown control_mode 'joints'; valid choices: "):
        KitbenchEnvConfig(task="LiftPegUpright-v1", control_mode="joints")
    with pytest.raises(KitbenchError, match=r"^pointcloud_points must be a positive integer, got 0$"):
        KitbenchEnvConfig(task="LiftPegUpright-v1", pointcloud_points=0)
