import atexit
import os
import shutil
import tempfile

import pytest

# kitbench's frame cache (kitbench.training.frames) in a folder of the test run's own, set before any test module
# copies the environment for the lerobot commands it runs
if "KITBENCH_FRAME_CACHE" not in os.environ:
    os.environ["KITBENCH_FRAME_CACHE"] = tempfile.mkdtemp(prefix="kitbench-test-frames-")
    atexit.register(shutil.rmtree, os.environ["KITBENCH_FRAME_CACHE"], True)


def _vulkan_available() -> bool:
    try:
        import sapien

        sapien.render.RenderSystem()
        return True
    except Exception:  # noqa: BLE001  (whatever stops a renderer from starting means no usable device)
        return False


VULKAN = _vulkan_available()


@pytest.fixture
def needs_vulkan():
    if not VULKAN:
        if os.environ.get("CI"):
            pytest.fail("CI must render: no Vulkan device (the Makefile installs one when root)")
        pytest.skip("no Vulkan device on this machine")
