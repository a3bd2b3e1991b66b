"""A config's training pace on this machine, timed by stock lerobot-train itself.

The reference workload (`kitbench.training.reference`) is a state config's update in fp32; a camera config's update
is a ResNet under bf16 autocast (fp32 on a CPU without bf16), whose speed the reference does not carry from one CPU
to another (docs/learnability.md). So a published row may keep its training's own step time (`step_seconds`), and
for such a row, or a config that trains on images (`reference_misleads`), `probe` times the same steps here:
lerobot-train with the training's command, data, seed and torch threads for `PROBE_STEPS` steps, logging every
`WINDOW`, saving nothing, into a temporary folder. A step's seconds are lerobot's own `updt_s + data_s` (each the
mean over its log window), the median over the windows after the first, which holds the warm-up: `step_seconds`
reads them from any lerobot-train log, the published training's included.
"""

from __future__ import annotations

import json
import re
import statistics
import tempfile
from pathlib import Path

from kitbench.errors import KitbenchError
from kitbench.training.run import THREADS_VAR, Training, run_logged, train_command

PROBE_STEPS = 30
WINDOW = 5
PROBE_LOG = "pace.log"
# lerobot-train's log line: "step:1K smpl:32K ep:... loss:0.094 grdn:... lr:... updt_s:0.352 data_s:0.003 ..."
_WINDOW = re.compile(r"\bstep:\S+ .*\bupdt_s:([\d.]+) data_s:([\d.]+)")


def reference_misleads(config: Path) -> bool:
    """Whether the reference workload does not carry `config`'s minutes between machines: a config that trains
    on camera images (a ResNet, bf16 or not, where the reference is a state config's fp32 transformer)."""
    env = json.loads(Path(config).read_text()).get("env") or {}
    return env.get("obs_type", "state") != "state"


def step_seconds(log: Path) -> float | None:
    """The median seconds of a training step in a lerobot-train log (updt_s + data_s, per log window), leaving out
    the first window when there are others; None when the log is missing or has no window."""
    if not Path(log).is_file():
        return None
    windows = [float(u) + float(d) for u, d in _WINDOW.findall(Path(log).read_text(errors="replace"))]
    if not windows:
        return None
    return statistics.median(windows[1:] or windows)


def probe(training: Training, steps: int | None = None) -> float:
    """Seconds of one of `training`'s steps on this machine: lerobot-train run as the training would run, for
    `steps` steps (default `PROBE_STEPS`), its log kept as `PROBE_LOG` beside the training's; CommandFailed if
    lerobot-train fails."""
    steps = steps or PROBE_STEPS
    log = training.policy_dir / PROBE_LOG
    log.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="kitbench-pace-") as scratch:
        extra = (*training.extra, f"--log_freq={WINDOW}", "--save_checkpoint=false")
        command = train_command(training.config, training.data, Path(scratch) / "train", steps, training.seed, extra)
        run_logged(command, log, {THREADS_VAR: training.threads})
    seconds = step_seconds(log)
    if seconds is None:
        raise KitbenchError(f"lerobot-train logged no step in {steps} steps (log every {WINDOW}); its log: {log}")
    return seconds
