"""Packs the files kitbench ships beside its code into a wheel, in the layout of the checkout, as
`kitbench/_shipped/` (`kitbench.shipped` reads them there). An editable install reads them from the checkout
itself, so it gets no copy."""

from __future__ import annotations

from typing import Any

from hatchling.builders.hooks.plugin.interface import BuildHookInterface

SHIPPED = {
    "policies": "kitbench/_shipped/policies",
    "eval/suites": "kitbench/_shipped/eval/suites",
    "datasets": "kitbench/_shipped/datasets",
}


class ShippedFiles(BuildHookInterface):
    def initialize(self, version: str, build_data: dict[str, Any]) -> None:
        if version == "standard":  # "editable" reads the checkout
            build_data["force_include"].update(SHIPPED)
