"""`python -m kitbench.cli ...` run as a process of its own, without paying the interpreter's start-up each time.

A kill test runs the command line dozens of times, and each fresh interpreter spends seconds importing kitbench,
SAPIEN, torch and LeRobot before it does anything. Here a fork server imports them once, and each run is a fork of
it: a process of its own (its own pid, environment, folder, stdout and stderr; a SIGKILL at a fault point kills it
alone and is its exit status, as for a subprocess), with `sys.argv` as `python -m kitbench.cli` sets it, so that
what a run records of its command line is the same either way. The server forks from a single-threaded process
that has only imported modules: nothing a test did beforehand leaks into a run.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import tempfile
from pathlib import Path

# imported once by the server: what `kitbench record`, `eval`, `convert` and `merge` load before they work
PRELOAD = [
    "kitbench.cli",
    "kitbench.recording.recorder",
    "kitbench.recording.dataset",
    "kitbench.evaluation.runner",
    "lerobot.datasets.lerobot_dataset",
    "lerobot.scripts.lerobot_train",
]
# console scripts run as their entry points: the script's name -> "module:function" (reads sys.argv)
SCRIPTS = {
    "kitbench": "kitbench.cli:main",
    "lerobot-train": "lerobot.scripts.lerobot_train:main",
    "lerobot-eval": "lerobot.scripts.lerobot_eval:main",
}
_context = None


def _server():
    global _context
    if _context is None:
        _context = multiprocessing.get_context("forkserver")
        _context.set_forkserver_preload(PRELOAD)
    return _context


def _main(script: str, args: list[str], env: dict[str, str], cwd: str, stdout: str, stderr: str) -> None:
    os.chdir(cwd)
    os.environ.clear()
    os.environ.update(env)
    for fd, path in ((1, stdout), (2, stderr)):
        handle = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
        os.dup2(handle, fd)
        os.close(handle)
    try:
        code = _call(script, args)
    except SystemExit as exc:  # argparse's refusals and --help
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001  (an uncaught error ends the run as the interpreter does: its hook, 1)
        sys.excepthook(*sys.exc_info())
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # as the interpreter would, without this fork running its server's exit handlers


def _call(script: str, args: list[str]) -> int:
    """Run `script` with `args` as its interpreter would, `sys.argv` as it sets it: what a run records of its
    command line. A `.py` file runs as `python FILE` runs it (its folder first on the path)."""
    if script.endswith(".py"):
        import runpy

        sys.argv = [script, *args]
        sys.path.insert(0, str(Path(script).parent))
        runpy.run_path(script, run_name="__main__")
        return 0
    import importlib

    module, _, name = SCRIPTS[script].partition(":")
    loaded = importlib.import_module(module)
    sys.argv = [loaded.__file__ if script == "kitbench" else str(Path(sys.executable).parent / script), *args]
    code = getattr(loaded, name)(*([args] if script == "kitbench" else []))
    return code if isinstance(code, int) else 0


class Started:
    """A command started as a fork of the server, not waited for; what tests use of subprocess.Popen: poll,
    send_signal, wait, communicate (its output as text) and returncode (-N for a run killed by signal N)."""

    def __init__(self, script: str, args: list[str], env: dict[str, str], cwd: Path | str, logs: Path | str | None):
        """`script` with `args` in `cwd` with `env`, its output in two files in `logs` (default: the temporary
        folder; `communicate` deletes them)."""
        self._files: list[Path] = []
        for suffix in (".out", ".err"):
            fd, path = tempfile.mkstemp(prefix="kitbench-launch-", suffix=suffix, dir=logs)
            os.close(fd)
            self._files.append(Path(path))
        files = [str(f) for f in self._files]
        self._process = _server().Process(target=_main, args=(script, list(args), env, str(cwd), *files))
        self._process.start()
        self.args = [script, *args]

    @property
    def returncode(self) -> int | None:
        return self._process.exitcode

    def poll(self) -> int | None:
        return self._process.exitcode

    def send_signal(self, signum: int) -> None:
        os.kill(self._process.pid, signum)

    def wait(self, timeout: float | None = None) -> int | None:
        self._process.join(timeout)
        return self._process.exitcode

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """Its output once it ends; past `timeout` it is killed and TimeoutExpired raised."""
        self._process.join(timeout)
        if self._process.exitcode is None:
            self._process.kill()
            self._process.join()
            raise subprocess.TimeoutExpired(self.args, timeout or 0)
        try:
            return self._files[0].read_text(), self._files[1].read_text()
        finally:
            for path in self._files:
                path.unlink(missing_ok=True)


def start(command: list, *, env=None, cwd=None, logs: Path | str | None = None) -> Started:
    """A kitbench command (as `script_args` knows it) started as a fork and not waited for, as subprocess.Popen
    starts one; its output in files in `logs`."""
    known = script_args(command)
    if known is None:
        raise ValueError(f"not a command the server runs: {command}")
    return Started(known[0], known[1], dict(env or os.environ), Path(cwd or os.getcwd()), logs)


def run_cli(
    args: list[str],
    *,
    env: dict[str, str] | None = None,
    cwd: Path | str | None = None,
    timeout: float = 600,
    script: str = "kitbench",
) -> subprocess.CompletedProcess:
    """`script` (a console script of `SCRIPTS`; `kitbench`: `python -m kitbench.cli`) with `args` in `cwd` with
    `env` (default: this process's), its output captured: the subprocess.run(..., capture_output=True, text=True)
    of it, with -N the exit status of a run killed by signal N."""
    started = Started(script, args, dict(env or os.environ), Path(cwd or os.getcwd()), None)
    try:
        out, err = started.communicate(timeout)
    except subprocess.TimeoutExpired:
        raise subprocess.TimeoutExpired([script, *args], timeout) from None
    return subprocess.CompletedProcess([script, *args], started.returncode, out, err)


def script_args(command: list) -> tuple[str, list[str]] | None:
    """(script, arguments) of `python -m kitbench.cli ...`, of a console script of `SCRIPTS` beside this
    interpreter or of `python FILE.py ...`, or None for another command."""
    command = [str(part) for part in command]
    if command[:3] == [sys.executable, "-m", "kitbench.cli"]:
        return "kitbench", command[3:]
    for script in SCRIPTS:
        if command[:1] == [str(Path(sys.executable).parent / script)]:
            return script, command[1:]
    if command[:1] == [sys.executable] and len(command) > 1 and command[1].endswith(".py"):
        return command[1], command[2:]  # a script file: `python FILE args`
    return None


def run(command: list, *, env=None, cwd=None, timeout: float = 600, check: bool = False, text: bool = False, **kwargs):
    """subprocess.run(command, ...) with its output captured, a kitbench command by `run_cli`, any other as
    subprocess runs it; `check` and `text` as subprocess has them."""
    known = script_args(command)
    if known is None:
        kwargs.setdefault("capture_output", True)
        return subprocess.run(command, env=env, cwd=cwd, timeout=timeout, check=check, text=text, **kwargs)
    done = run_cli(known[1], env=env, cwd=cwd, timeout=timeout, script=known[0])
    if not text:
        done = subprocess.CompletedProcess(done.args, done.returncode, done.stdout.encode(), done.stderr.encode())
    if check:
        done.check_returncode()
    return done
