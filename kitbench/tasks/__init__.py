"""kitbench's tasks, one module each: the env class (registered with `@register_env`), its constants, success
criteria, failure categories and its expert's entry point. Importing this package imports every module in it,
so adding a task is adding a file here (or, outside the package, importing the module that defines it).
"""

from __future__ import annotations

import importlib
import pkgutil


def _import_all() -> None:
    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")


_import_all()
