"""The mathematics: model, exact inference, DP solver, policy tables, controllers.

The mathematics: the model and its exact inference, the DP solver, policy tables,
controllers, exact policy scores, TD learning, the step clock and the posture rule.

Pure functions and small classes over numpy/scipy: no I/O beyond reading and writing
policy tables, no threads, no clocks, no rclpy. May import only :mod:`infomax_contingency`'s
base modules (``resources``, ``errors``) and other ``core`` modules. Start reading at
``model.py`` (MODEL.md in code), then ``solver.py`` and ``controllers.py``.
"""
