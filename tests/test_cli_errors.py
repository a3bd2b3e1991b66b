"""The command line prints user errors (KitbenchError) as one line and exits 2; anything else is a bug and keeps
its traceback."""

from __future__ import annotations

import pytest

import kitbench
from kitbench import cli
from kitbench.errors import KitbenchError, check_choice


def test_kitbench_error_is_a_value_error_naming_the_choices():
    with pytest.raises(KitbenchError, match=r"^unknown colour 'mauve'; valid choices: red, blue$"):
        check_choice("colour", "mauve", ("red", "blue"))
    assert issubclass(KitbenchError, ValueError)


def test_user_errors_are_one_line(capsys):
    assert cli.main(["eval", "--task", "Nope-v1", "--episodes", "1", "--out", "unused"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("kitbench eval: error: unknown task 'Nope-v1'; valid choices: ")
    assert all(task in err for task in kitbench.TASKS)


def test_other_errors_are_not_disguised_as_user_errors(monkeypatch):
    import kitbench.evaluation.runner as runner

    def broken(config, progress=True):
        raise ValueError("a bug, not a user error")

    monkeypatch.setattr(runner, "run_eval", broken)
    with pytest.raises(ValueError, match="a bug"):
        cli.main(["eval", "--task", next(iter(kitbench.TASKS)), "--episodes", "1", "--out", "unused"])
