"""Where the models shipped by example-robot-data live (the Panda, the SO-101), for SAPIEN and for MuJoCo.

Both simulators read the same URDF so the controller, the planner and the simulator share one kinematic model.
Nothing is downloaded: the package ships the URDFs and meshes.
"""

from __future__ import annotations

import functools
import re
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

_ROBOTS = "cmeel.prefix/share/example-robot-data/robots"


@functools.cache
def description_dir(name: str, urdf: str) -> Path:
    """The installed `<name>` folder of example-robot-data (URDF, meshes), checked to hold `urdf/<urdf>`."""
    try:
        # str(): typeshed types locate_file's result as a SimplePath, which Path() does not accept.
        root = Path(str(distribution("example-robot-data").locate_file(f"{_ROBOTS}/{name}")))
    except PackageNotFoundError as exc:  # pragma: no cover - install problem
        raise RuntimeError("example-robot-data is not installed; run `make test` or `uv sync`") from exc
    if not (root / "urdf" / urdf).is_file():  # pragma: no cover - install problem
        raise RuntimeError(f"{name}/urdf/{urdf} not found under {root.parent}")
    return root


def mujoco_urdf(name: str, urdf: str) -> str:
    """The URDF `<name>/urdf/<urdf>` as MuJoCo needs it: absolute mesh paths and no static-body fusing (without
    `fusestatic="false"` MuJoCo merges fixed frames such as the Panda's `panda_hand` and TCP into their parent)."""
    root = description_dir(name, urdf)
    text = (root / "urdf" / urdf).read_text()
    text = re.sub(
        rf'filename="package://example-robot-data/robots/{name}/meshes/([^"]+)"',
        lambda m: f'filename="{root / "meshes" / m.group(1)}"',
        text,
    )
    compiler = '<mujoco><compiler fusestatic="false" discardvisual="true" balanceinertia="true"/></mujoco>'
    return re.sub(r"(<robot[^>]*>)", r"\1" + compiler, text, count=1)


def panda_description_dir() -> Path:
    """The installed `panda_description` folder (URDF, SRDF, meshes)."""
    return description_dir("panda_description", "panda.urdf")


def panda_urdf_path() -> Path:
    return panda_description_dir() / "urdf" / "panda.urdf"


def panda_srdf_path() -> Path:
    return panda_description_dir() / "srdf" / "panda.srdf"


@functools.cache
def panda_mujoco_urdf() -> str:
    return mujoco_urdf("panda_description", "panda.urdf")


def so101_urdf_path() -> Path:
    return description_dir("so_arm_description", "so101.urdf") / "urdf" / "so101.urdf"


@functools.cache
def so101_mujoco_urdf() -> str:
    return mujoco_urdf("so_arm_description", "so101.urdf")
