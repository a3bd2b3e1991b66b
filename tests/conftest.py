import os

import pytest


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
