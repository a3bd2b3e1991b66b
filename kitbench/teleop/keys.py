"""lerobot-record's episode keys: right arrow (or `n`) ends the episode now, left arrow (or `r`) re-records it,
escape (or `q`) stops the recording. The keys are read by lerobot's own listener (`create_key_listener`: pynput on
an X11 desktop, else the terminal) into the same events dict lerobot-record keeps, set by lerobot's own
`apply_recording_control`. A keyboard device's arrows move the arm, so with one only the letters and escape count.
"""

from __future__ import annotations

from kitbench.rollout import Control

# key name (as lerobot's listeners name them) -> lerobot's control; lerobot's `init_keyboard_listener` table
KEYS = {"right": "right", "n": "right", "left": "left", "r": "left", "esc": "esc", "q": "esc"}
ARROWS = ("right", "left")
# a device's own episode events (lerobot's `TeleopEvents`; a gamepad's X, Y and A buttons) -> lerobot's control,
# the first that holds counting (lerobot's gamepad also sets terminate_episode with re-record)
DEVICE_EVENTS = {"RERECORD_EPISODE": "left", "SUCCESS": "right", "TERMINATE_EPISODE": "esc"}
BUTTON = "button:"  # how `last_key` names a device's event (`button:success`)
HELP = "right arrow or n: next episode, left arrow or r: re-record it, Esc or q: stop"
LETTERS_HELP = "n: next episode, r: re-record it, Esc or q: stop"
# before an episode, while a leader arm is brought to the start pose
START_HELP = "right arrow or n: start now, Esc or q: stop"
LETTERS_START_HELP = "n: start now, Esc or q: stop"


def new_events() -> dict[str, bool]:
    """lerobot-record's events dict, nothing pressed."""
    return {"exit_early": False, "rerecord_episode": False, "stop_recording": False}


class EpisodeKeys:
    """The episode keys of a recording; `take()` is the control pressed since it was last asked (stop first, then
    re-record, then next), as lerobot-record acts on its events."""

    def __init__(self, arrows: bool = True):
        self.keys = KEYS if arrows else {k: v for k, v in KEYS.items() if k not in ARROWS}
        self.help = HELP if arrows else LETTERS_HELP
        self.start_help = START_HELP if arrows else LETTERS_START_HELP
        self.events = new_events()
        self.listener = None
        self.last_key: str | None = None  # the name of the key behind the last control pressed

    def start(self) -> None:
        """Listen (pynput where it can capture, else the terminal, else nothing: lerobot's choice)."""
        from lerobot.utils import keyboard_input

        self.listener = keyboard_input.create_key_listener(self.press, controls_help=self.help)

    def press(self, name: str) -> None:
        """A key, by the name lerobot's listeners give it."""
        from lerobot.utils.keyboard_input import apply_recording_control

        control = self.keys.get(name.lower())
        if control is not None:
            self.last_key = name.lower()
            apply_recording_control(control, self.events)

    def device_events(self, events: dict) -> None:
        """A device's own episode buttons (lerobot's `TeleopEvents`: a gamepad's X, Y, A), as the keys: re-record
        (X) discards the episode, success (Y) ends it (kept), terminate (A: failure) ends it and stops the
        recording."""
        from lerobot.teleoperators.utils import TeleopEvents
        from lerobot.utils.keyboard_input import apply_recording_control

        for event, control in DEVICE_EVENTS.items():
            member = getattr(TeleopEvents, event)
            if events.get(member) or events.get(member.value):
                self.last_key = f"{BUTTON}{member.value}"
                apply_recording_control(control, self.events)
                return

    @property
    def stopping(self) -> bool:
        return self.events["stop_recording"]

    def take(self) -> Control | None:
        events = self.events
        control = None
        if events["stop_recording"]:
            control = Control.STOP
        elif events["rerecord_episode"]:
            control = Control.RERECORD
        elif events["exit_early"]:
            control = Control.NEXT
        if control is not None:
            self.events.update(new_events())
        return control

    def clear(self) -> None:
        """A new episode starts: an arrow pressed between episodes (while the last one was stored) does not end
        it; a stop still stands."""
        self.events["exit_early"] = self.events["rerecord_episode"] = False

    def stop(self) -> None:
        if self.listener is not None:
            self.listener.stop()
            self.listener = None
