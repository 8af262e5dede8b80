"""Simulated worlds and the one closed observe/step/act loop.

* ``rooms.py`` — the one registry of room names (bit-level rates, audio-level presets);
* ``world.py`` — bit-level rooms made from those names (``make_room``);
* ``fake_room.py`` — the audio-level fake room and its loop world;
* ``loop.py`` — :func:`~infomax_contingency.sim.loop.run_loop`, the closed loop every
  offline simulation runs through;
* ``simulation.py`` — the bit-level simulator (streaming ``iter_simulate``).

No rclpy. May import the base modules, :mod:`~infomax_contingency.core` and
:mod:`~infomax_contingency.audio`.
"""
