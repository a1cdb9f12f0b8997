"""The person at the robot in `adademo-record`: answering on the keyboard (LeRobot's key listener) or through a
teleoperator that reports LeRobot's teleop events."""

from __future__ import annotations

import queue

from adademo_lerobot.core.errors import AdaDemoError

KEYS_HELP = "n/Right = next, r/Left = redo, s = success, f = failure, t = take over, q/Esc = stop"


class StopRecording(Exception):  # noqa: N818  (a request, not an error)
    """The person asked to stop (q / Esc)."""


class KeyboardPerson:
    """The person at the robot, answering on the keyboard through LeRobot's key listener."""

    def __init__(self):
        from lerobot.utils.keyboard_input import create_key_listener

        self.keys: queue.Queue[str] = queue.Queue()
        self.listener = create_key_listener(self.keys.put, controls_help=KEYS_HELP)
        if self.listener is None:
            raise AdaDemoError(
                "adademo-record needs the person's keys and gets none here (no display, and stdin is not a "
                "terminal): run it in an interactive terminal, or with a teleoperator that reports success "
                "(--judge=teleop)"
            )

        self._pressed: set[str] = set()  # keys read while an episode runs, not yet asked for

    def _wait(self, prompt: str, answers: dict[str, object]):
        print(f"{prompt}  [{KEYS_HELP}]", flush=True)
        self._pressed.clear()
        while True:
            key = self.keys.get().lower()
            if key in ("q", "esc"):
                raise StopRecording
            if key in answers:
                return answers[key]

    def ready(self, prompt: str) -> None:
        self._wait(prompt, {"n": True, "right": True, "enter": True})

    def _pressed_during_episode(self, *names: str) -> bool:
        while not self.keys.empty():
            key = self.keys.get_nowait().lower()
            if key in ("q", "esc"):
                raise StopRecording
            self._pressed.add("n" if key == "right" else key)
        found = bool(self._pressed & set(names))
        self._pressed -= set(names)
        return found

    def episode_over(self) -> bool:
        return self._pressed_during_episode("n")

    def takes_over(self) -> bool:
        return self._pressed_during_episode("t")

    def judge(self, task: str) -> bool:
        return self._wait(f"{task}: did the policy succeed? (s / f)", {"s": True, "f": False})

    def keep_demo(self, task: str) -> bool:
        return self._wait(f"{task}: keep this demonstration? (n keeps it, r records it again)", {
            "n": True, "right": True, "r": False, "left": False,
        })  # fmt: skip

    def close(self) -> None:
        self.listener.stop()


class TeleopPerson:
    """The teleoperator answers for the person through LeRobot's teleop events (success, end of episode)."""

    def __init__(self, teleop):
        self.teleop = teleop

    def _events(self) -> dict:
        from lerobot.teleoperators.utils import TeleopEvents

        events = self.teleop.get_teleop_events()
        return {e.value: bool(events.get(e, False)) for e in TeleopEvents}

    def ready(self, prompt: str) -> None:
        print(prompt, flush=True)

    def episode_over(self) -> bool:
        return self._events()["terminate_episode"]

    def takes_over(self) -> bool:
        return self._events()["is_intervention"]

    def judge(self, task: str) -> bool:
        return self._events()["success"]

    def keep_demo(self, task: str) -> bool:
        return self._events()["success"]

    def close(self) -> None:
        pass


def make_person(judge: str, teleop):
    if judge == "teleop" or (judge == "auto" and hasattr(teleop, "get_teleop_events")):
        if not hasattr(teleop, "get_teleop_events"):
            raise AdaDemoError(
                f"--judge=teleop: the {teleop.name} teleoperator reports no events; use --judge=keys"
            )
        return TeleopPerson(teleop)
    return KeyboardPerson()
