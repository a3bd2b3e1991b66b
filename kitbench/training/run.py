"""Training a config with stock `lerobot-train` and scoring its checkpoint with `kitbench eval`: the one piece of
code `kitbench reproduce` and `bench/learnability.py` both run, so that their minutes and figures mean the same.

`train` runs `lerobot-train --config_path=<config>` (only the dataset, output folder, seed and steps given on top)
with its output in a log, shows its progress while it runs (the steps lerobot has done, its loss, the time left),
times it (wall clock, and lerobot's own loop from its log), and times the machine's reference workload as it ends;
a checkpoint whose training finished with the same command on the same data is reused (its stamp, written last,
says so), so a killed run started again picks up where it stopped. A finished training is never replaced by
another request unless the caller says `overwrite` (`--overwrite`): it is refused in one line naming what differs,
as lerobot-train refuses an existing output folder. `evaluate` runs `kitbench eval` of the checkpoint on a suite,
reusing a report the same command wrote after the checkpoint's training finished.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.training.precision import amp_flags
from kitbench.training.reference import read

BIN = Path(sys.executable).parent  # the venv's console scripts, whichever way Python was started
THREADS_VAR = "OMP_NUM_THREADS"
# the data never comes from the Hub (dataset.root is local), and a stray lookup must not stall a long run
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
LOG_TAIL_LINES = 30
REPORT_JSON = "report.json"
# lerobot-train's tqdm bar ("Training:  41%|...| 1013/2500 [...]") and its log lines ("step:1K ... loss:0.094")
_BAR = re.compile(rb"(\d+)/(\d+) \[")
_LOSS = re.compile(rb" loss:([\d.]+)")


class FinishedTraining(KitbenchError):
    """A finished training in the folder a different request would train into: kept, not replaced."""


class CommandFailed(Exception):
    def __init__(self, command: list[str], log: Path, status: int):
        how = f"killed by signal {-status}" if status < 0 else f"exit status {status}"
        super().__init__(f"{how}: {shlex.join(command)}")
        self.command, self.log, self.status = command, log, status


def shell_line(command: list[str], env: dict[str, str] | None = None) -> str:
    """The command as one shell line, with the variables it is run with in front (`OMP_NUM_THREADS=1 lerobot-...`)."""
    return " ".join([*(f"{k}={shlex.quote(v)}" for k, v in (env or {}).items()), shlex.join(command)])


def log_tail(log: Path, lines: int = LOG_TAIL_LINES) -> str:
    """The last lines of a log, each progress bar's redrawn line reduced to its final state."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return "(no log)"
    return "\n".join(line.rsplit("\r", 1)[-1] for line in text.splitlines()[-lines:])


def run_logged(command: list[str], log: Path, env: dict[str, str] | None = None, follow=None) -> float:
    """Run a command with its output in `log` and the variables `env` set on top of ENV; the wall-clock seconds it
    took, or CommandFailed. `follow(chunk)` is handed what the command writes as it writes it."""
    log.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    with log.open("w") as f:
        f.write(f"$ {shell_line(command, env)}\n")
        f.flush()
        proc = subprocess.Popen(command, stdout=f, stderr=subprocess.STDOUT, env={**ENV, **(env or {})})
        watcher = _Follower(log, follow) if follow is not None else None
        try:
            status = proc.wait()
        finally:
            if proc.poll() is None:
                proc.kill()
            if watcher is not None:
                watcher.stop()
    if status != 0:
        raise CommandFailed(command, log, status)
    return time.monotonic() - start


class _Follower:
    """Reads a growing log in a thread and hands each new chunk to `follow`."""

    def __init__(self, log: Path, follow):
        self.log, self.follow = log, follow
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        with self.log.open("rb") as f:
            while True:
                chunk = f.read()
                if chunk:
                    self.follow(chunk)
                elif self._done.is_set():
                    return
                else:
                    self._done.wait(0.5)

    def stop(self) -> None:
        self._done.set()
        self._thread.join()


class TrainingProgress:
    """lerobot-train's progress as it writes it (its steps, its last loss), on kitbench's bar (`kitbench.progress`:
    a bar on a terminal, a line every few seconds otherwise)."""

    def __init__(self, total: int, desc: str):
        from kitbench.progress import progress

        self.bar = progress(total, desc, unit="step", interval=60.0)  # off a terminal: a line a minute
        self.done = 0

    def __call__(self, chunk: bytes) -> None:
        steps = _BAR.findall(chunk)
        if steps:
            now = int(steps[-1][0])
            if now > self.done:
                self.bar.update(now - self.done)
                self.done = now
        losses = _LOSS.findall(chunk)
        if losses:
            self.bar.set_postfix(loss=losses[-1].decode())

    def close(self) -> None:
        self.bar.close()


def train_threads(config_path: Path, published_threads: int | None = None, on_cpu: bool = False) -> str:
    """torch's threads for lerobot-train: OMP_NUM_THREADS if set, else the published run's, else every core for a
    config that reads cameras on the CPU (its update takes a third of a second or more, a loader worker a millisecond
    a sample: docs/training.md), and otherwise the cores its loader workers leave (at least one): on a few cores
    torch's threads otherwise fight the workers, and a GPU's loader workers need the cores. `on_cpu`: a GPU config
    trained on this CPU (`kitbench.training.device`), whose published run's threads were another machine's."""
    if os.environ.get(THREADS_VAR):
        return os.environ[THREADS_VAR]
    if published_threads is not None and not on_cpu:
        return str(published_threads)
    config = json.loads(Path(config_path).read_text())
    cores = os.cpu_count() or 1
    on_cpu = on_cpu or (config.get("policy") or {}).get("device") == "cpu"
    if on_cpu and (config.get("env") or {}).get("obs_type", "state") != "state":
        return str(cores)
    return str(max(1, cores - int(config.get("num_workers", 4))))


def train_command(
    config: Path, data: Path, out: Path, steps: int | None = None, seed: int | None = None, extra: tuple = ()
) -> list[str]:
    command = [str(BIN / "lerobot-train"), f"--config_path={config}", f"--dataset.root={data}", f"--output_dir={out}"]
    if seed is not None:
        command.append(f"--seed={seed}")
    if steps is not None:
        command.append(f"--steps={steps}")
    return [*command, *amp_flags(config), *extra]


def count_parameters(log: Path, checkpoint: Path) -> tuple[int, str]:
    """The policy's parameter count: lerobot-train's own log line, else the checkpoint's tensors."""
    found = re.findall(r"num_total_params=(\d+)", log.read_text(errors="replace"))
    if found:
        return int(found[-1]), "train log"
    from safetensors import safe_open

    with safe_open(checkpoint / "model.safetensors", framework="pt") as f:
        names = f.keys()  # a safe_open handle has keys() but cannot be iterated itself
        return sum(math.prod(f.get_slice(k).get_shape()) for k in names), "model.safetensors"


def loop_seconds(log: Path) -> float | None:
    """Seconds of lerobot-train's training loop, from its log's timestamps (whole seconds): from the parameter
    count, its last line before the loop, to "End of training". None if either line is missing."""
    stamps = {}
    for line in log.read_text(errors="replace").splitlines():
        match = re.match(r"\w+ (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d) .*(num_total_params=|End of training)", line)
        if match:
            stamps[match[2]] = datetime.strptime(match[1], "%Y-%m-%d %H:%M:%S")
    if len(stamps) < 2:
        return None
    return (stamps["End of training"] - stamps["num_total_params="]).total_seconds()


def request_change(before: dict, now: dict) -> str:
    """What differs between a finished training's request and this one, in words: why it is not reused."""
    changes = []
    for key in sorted(set(before.get("env", {})) | set(now.get("env", {}))):
        old, new = before.get("env", {}).get(key), now.get("env", {}).get(key)
        if old != new:
            changes.append(f"{key} {old} -> {new}")
    old_args, new_args = before.get("command", []), now.get("command", [])
    gone = [a for a in old_args if a not in new_args]
    added = [a for a in new_args if a not in old_args]
    if gone or added:
        changes.append(f"arguments {' '.join(gone) or '-'} -> {' '.join(added) or '-'}")
    if before.get("data") != now.get("data"):
        changes.append("the data it trained on")
    return "; ".join(changes) or "the request's format"


TRAIN_STAMP = "train_done.json"


@dataclass(frozen=True)
class Training:
    """One training: `config` on `data` into `policy_dir`/train (its log: `policy_dir`/train.log), on `threads`
    torch threads; `steps` and `seed` over the config's, `extra` lerobot-train flags on top, `data_stamp` what
    identifies the data."""

    config: Path
    data: Path
    policy_dir: Path
    threads: str
    steps: int | None = None
    seed: int | None = None
    extra: tuple = ()
    data_stamp: str = ""

    @property
    def train_dir(self) -> Path:
        return self.policy_dir / "train"

    def request(self) -> dict:
        """What identifies it: the lerobot-train command, the variables it runs with, and the data's digest. A
        finished training of the same request is reused."""
        command = train_command(self.config, self.data, self.train_dir, self.steps, self.seed, self.extra)
        digest = hashlib.sha256(self.data_stamp.encode()).hexdigest()
        return {"command": command, "env": {THREADS_VAR: self.threads}, "data": digest}


def finished_request(policy_dir: Path) -> dict | None:
    """The request of the finished training in `policy_dir` (its stamp, written after its last checkpoint), or None
    when none finished there."""
    stamp = policy_dir / TRAIN_STAMP
    checkpoint = policy_dir / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors"
    if not (stamp.is_file() and checkpoint.is_file()):
        return None
    return json.loads(stamp.read_text()).get("request", {})


def check_replace(training: Training, overwrite: bool = False) -> None:
    """Refuse, in one line naming what differs and what to do, to run `training` over a finished training of
    another request, unless `overwrite`: callers check before they record, so nothing runs first."""
    before, request = finished_request(training.policy_dir), training.request()
    if before is None or before == request or overwrite:
        return
    remedy = "pass --overwrite to replace it, or another --out to keep it"
    env = before.get("env") or {}
    if {k: before.get(k) for k in ("command", "data")} == {k: request[k] for k in ("command", "data")} and env:
        # only the variables differ (an unset OMP_NUM_THREADS): the same ones reuse it
        remedy = f"run with {' '.join(f'{k}={shlex.quote(str(v))}' for k, v in env.items())} to reuse it, or {remedy}"
    raise FinishedTraining(
        f"{training.train_dir} holds a finished training of another request ({request_change(before, request)}); "
        f"{remedy}"
    )


def train(training: Training, *, progress: bool = False, overwrite: bool = False, measured: dict | None = None) -> dict:
    """Run `training`, or reuse the checkpoint the same request trained. A finished training of another request
    is `FinishedTraining` unless `overwrite`; an unfinished one is trained again. `progress`: show the training's
    steps as they come. `measured`: what the caller measured just before it (JSON values), kept in its stamp so a
    reuse reports the readings the training had, not the ones of the day it is reused."""
    policy_dir, train_dir, threads = training.policy_dir, training.train_dir, training.threads
    request = training.request()
    command, env = request["command"], request["env"]
    log = policy_dir / "train.log"
    stamp = policy_dir / TRAIN_STAMP
    checkpoint = train_dir / "checkpoints" / "last" / "pretrained_model"
    before = finished_request(policy_dir)
    if before == request:
        return {**json.loads(stamp.read_text())["trained"], "dir": train_dir, "reused": True, "stamp": stamp}
    check_replace(training, overwrite)
    if before is not None:  # --overwrite: say what is replaced
        print(f"replacing {train_dir} (--overwrite; it differs: {request_change(before, request)})", file=sys.stderr)
    stamp.unlink(missing_ok=True)
    if train_dir.exists():  # lerobot-train refuses an existing output folder
        shutil.rmtree(train_dir)
    follow = None
    if progress:
        total = training.steps or json.loads(Path(training.config).read_text()).get("steps", 0)
        follow = TrainingProgress(int(total), f"train {Path(training.config).stem}")
    try:
        seconds = run_logged(command, log, env, follow)
    finally:
        if follow is not None:
            follow.close()
    # measured again as the training ends: a machine that slowed down during a long training shows it here
    after = read(int(threads))
    train_config = json.loads((checkpoint / "train_config.json").read_text())
    params, source = count_parameters(log, checkpoint)
    trained = {
        "command": command,
        "env": env,
        "dir": train_dir,
        "seconds": seconds,
        "steps": train_config["steps"],
        "batch_size": train_config.get("batch_size"),
        "device": (train_config.get("policy") or {}).get("device"),
        "loop_seconds": loop_seconds(log),
        "params": params,
        "params_source": source,
        "seed": train_config.get("seed"),
        "reference_after": after.seconds,
        "reference_after_share": after.share,
        **(measured or {}),
    }
    stamp.write_text(json.dumps({"request": request, "trained": {**trained, "dir": str(train_dir)}}, indent=1) + "\n")
    return {**trained, "reused": False, "stamp": stamp}


def eval_command(
    checkpoint: Path,
    suite: Path,
    out: Path,
    *,
    control_mode: str | None = None,
    episodes: int | None = None,
    batch_size: int = 1,
    workers: int = 1,
    options: tuple[tuple[str, object], ...] = (),
) -> list[str]:
    command = [str(BIN / "kitbench"), "eval", "--suite", str(suite), "--policy", f"lerobot:{checkpoint}"]
    command += ["--out", str(out), "--overwrite", "--videos", "0"]
    if control_mode is not None:  # the suite's seeds in the mode the policy learned (a suite names the recorder's)
        command += ["--control-mode", control_mode]
    if episodes is not None:
        command += ["--episodes", str(episodes)]
    if batch_size > 1:
        command += ["--batch-size", str(batch_size)]
    if workers > 1:
        command += ["--workers", str(workers)]
    for key, value in options:
        command += ["--policy-option", f"{key}={json.dumps(value)}"]
    return command


def evaluate(command: list[str], out: Path, trained: Path | None = None) -> tuple[dict, bool]:
    """Run the `kitbench eval` command that writes its report in `out` (its log beside it), or reuse the report
    the same command wrote after the training stamped `trained` finished; (report, reused)."""
    stamp = out.with_name(out.name + ".request.json")
    report = out / REPORT_JSON
    # a checkpoint trained again (--overwrite) keeps its path, so the command alone cannot tell its reports apart
    current = trained is None or (report.is_file() and report.stat().st_mtime >= trained.stat().st_mtime)
    if stamp.is_file() and report.is_file() and current and json.loads(stamp.read_text()) == command:
        return json.loads(report.read_text()), True
    stamp.unlink(missing_ok=True)
    run_logged(command, out.with_name(out.name + ".log"))
    stamp.write_text(json.dumps(command) + "\n")
    return json.loads((out / REPORT_JSON).read_text()), False
