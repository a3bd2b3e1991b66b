"""Settings, each declared once (`declare.setting`: name, type, default, help, check) in config dataclasses; the
command line's flags (`flags`), recipe and suite files (`files`) and the LeRobot plugin's config are derived from
the declarations. `checks` holds what settings accept."""

from kitbench.config.declare import (
    Resolved as Resolved,
    build as build,
    flatten as flatten,
    leaves as leaves,
    replace as replace,
    resolve as resolve,
    setting as setting,
    validate as validate,
)
