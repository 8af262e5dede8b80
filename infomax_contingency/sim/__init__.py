"""Simulated worlds and the one closed observe/step/act loop.

* ``rooms.py`` — the one registry of room names (bit-level rates, audio-level presets);
* ``world.py`` — bit-level rooms made from those names (``make_room``);
* ``fake_room.py`` — the audio-level fake room; ``room_config.py`` its settings;
  ``audio_loop.py`` the room heard through a bit source, as a loop world;
* ``loop.py`` — :func:`~infomax_contingency.sim.loop.run_loop`, the closed loop every
  offline simulation runs through;
* ``simulation.py`` — the bit-level simulator (streaming ``iter_simulate``).

No rclpy. May import the base modules, :mod:`~infomax_contingency.core` and
:mod:`~infomax_contingency.audio`.
"""
