"""The plugin's switches for what it changes in `lerobot-train` (`KITBENCH_FLUSH_DENORMALS`): on unless set to an
off value; any other value is one logged line naming the choices, and the change is not made."""

from __future__ import annotations

import logging
import os
import sys

log = logging.getLogger(__name__)

ON = ("1", "true", "yes", "on")
OFF = ("0", "false", "no", "off")
TRAINING_SCRIPT = "lerobot.scripts.lerobot_train"


def wanted(var: str, when_off: str) -> bool:
    """What the switch `var` asks for (on when unset); a value outside ON and OFF logs one line ending with
    `when_off` and counts as off."""
    value = os.environ.get(var, "1").strip().lower()
    if value in ON:
        return True
    if value not in OFF:
        log.error("%s=%r: expected one of %s; %s", var, os.environ[var], ", ".join(ON + OFF), when_off)
    return False


def in_training() -> bool:
    """Whether this process runs lerobot's training script (its console script or `python -m`)."""
    main = getattr(sys.modules.get("__main__"), "__spec__", None)
    return TRAINING_SCRIPT in sys.modules or getattr(main, "name", None) == TRAINING_SCRIPT
