"""Where the Panda model lives, for SAPIEN and for MuJoCo.

Both simulators read the same example-robot-data URDF so the controller, the planner and the simulator share
one kinematic model. Nothing is downloaded: the package ships the URDF and meshes.
"""

from __future__ import annotations

import functools
import re
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

_PANDA_SUBDIR = "cmeel.prefix/share/example-robot-data/robots/panda_description"


@functools.cache
def panda_description_dir() -> Path:
    """The installed `panda_description` folder (URDF, SRDF, meshes)."""
    try:
        # str(): typeshed types locate_file's result as a SimplePath, which Path() does not accept.
        root = Path(str(distribution("example-robot-data").locate_file(_PANDA_SUBDIR)))
    except PackageNotFoundError as exc:  # pragma: no cover - install problem
        raise RuntimeError("example-robot-data is not installed; run `make test` or `uv sync`") from exc
    if not (root / "urdf" / "panda.urdf").is_file():  # pragma: no cover - install problem
        raise RuntimeError(f"panda_description not found under {root}")
    return root


def panda_urdf_path() -> Path:
    return panda_description_dir() / "urdf" / "panda.urdf"


def panda_srdf_path() -> Path:
    return panda_description_dir() / "srdf" / "panda.srdf"


@functools.cache
def panda_mujoco_urdf() -> str:
    """The Panda URDF as MuJoCo needs it: absolute mesh paths and no static-body fusing.

    Without `fusestatic="false"` MuJoCo merges `panda_hand` (and the TCP frame) into `panda_link7`.
    """
    text = panda_urdf_path().read_text()
    meshes = panda_description_dir() / "meshes"
    text = re.sub(
        r'filename="package://example-robot-data/robots/panda_description/meshes/([^"]+)"',
        lambda m: f'filename="{meshes / m.group(1)}"',
        text,
    )
    compiler = '<mujoco><compiler fusestatic="false" discardvisual="true" balanceinertia="true"/></mujoco>'
    return re.sub(r"(<robot[^>]*>)", r"\1" + compiler, text, count=1)
