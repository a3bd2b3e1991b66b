"""The Rerun layout of a live view, sent before the first frame: each camera's image, and per motor one plot of
its state beside the action commanding it, so a person sees what they do against what the arm does.

lerobot's `log_rerun_data` builds its layout from the entities of the first frame it logs and keeps it (its
`blueprint` attribute, reset by `init_rerun`); a view that logs its first frame before any action (the scene at an
episode's reset) would never show actions. This layout names every entity lerobot will log, under lerobot's own
paths (`observation.<key>`, `action.<key>`), and takes lerobot's place, so it holds from the first frame.
"""

from __future__ import annotations

from collections.abc import Iterable


def entity(prefix: str, key: str) -> str:
    """Where lerobot's `log_rerun_data` logs `key` of an observation (prefix "observation") or action ("action")."""
    return key if key.startswith(f"{prefix}.") else f"{prefix}.{key}"


def blueprint(state: Iterable[str], action: Iterable[str], images: Iterable[str]):
    """Images first, then one plot per state value with the action of the same name (a leader's `<motor>.pos` on
    the follower's), then the actions that have no state of their name (end-effector deltas) in one plot."""
    import rerun.blueprint as rrb

    state, actions = list(state), list(action)
    views: list = [rrb.Spatial2DView(origin=entity("observation", k), name=k) for k in images]
    for name in state:
        paired = [entity("action", name)] if name in actions else []
        views.append(rrb.TimeSeriesView(name=name, contents=[entity("observation", name), *paired]))
    unpaired = [entity("action", name) for name in actions if name not in state]
    if unpaired:
        views.append(rrb.TimeSeriesView(name="action", contents=unpaired))
    return rrb.Blueprint(rrb.Grid(*views))


def send(state: Iterable[str], action: Iterable[str], images: Iterable[str]) -> None:
    """Show the layout in the Rerun recording in use, in place of the one lerobot would build from its first frame
    (once a recording: a recording that has one keeps it)."""
    import rerun as rr
    from lerobot.utils.rerun_visualization import log_rerun_data

    if getattr(log_rerun_data, "blueprint", None) is not None:
        return
    layout = blueprint(state, action, images)
    log_rerun_data.blueprint = layout  # lerobot keeps a layout once it has one
    rr.send_blueprint(layout)
