"""Simulated worlds and the one closed observe/step/act loop.

Simulated worlds and the one closed observe/step/act loop: bit-level rooms
(``world.py``), the audio-level fake room (``fake_room.py``) and the offline simulator.

No rclpy. May import the base modules, :mod:`~infomax_contingency.core` and
:mod:`~infomax_contingency.audio`.
"""
