"""For the import tests: a fake room made and stepped in child_imports.py's fresh interpreter.

``python test/child_imports.py child_room:step_room:ROOM[+SPECTRUM] FORBIDDEN,...`` makes
the room ``ROOM`` (a preset of :class:`FakeRoomConfig`), with the noise floor spectrum
``SPECTRUM`` if given, and steps it 20 windows with a vocalization in every other one;
child_imports.py then says which FORBIDDEN modules that loaded.
"""

from __future__ import annotations

from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig


def step_room(spec: str) -> None:
    """Make the room ``ROOM[+SPECTRUM]`` and step it 20 windows."""
    name, _, spectrum = spec.partition("+")
    overrides = {"floor_spectrum": spectrum} if spectrum else {}
    room = FakeRoom(FakeRoomConfig.preset(name, **overrides), seed=1)
    for window in range(20):
        if window % 2:
            room.vocalize()
        room.next_window()
