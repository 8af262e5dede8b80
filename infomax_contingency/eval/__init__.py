"""Evaluation: experiments (baby-9, rule, greedy, horizon, efficiency) and figures.

Evaluation: experiments (baby-9, rule, greedy, horizon, efficiency) and figures.

Offline and reproducible. No rclpy. May import the base modules, ``core``, ``audio`` and
``sim``.
"""
