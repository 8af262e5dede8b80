"""Sound to numbers: wav I/O, energies, thresholds, binarizers, the live PortAudio path.

Sound to numbers: wav I/O, resampling, window energies, thresholds, binarizers,
and the live PortAudio path (devices, capture, playback, calibration, latency).

No rclpy. May import the base modules and :mod:`infomax_contingency.core`. The live
modules use threads and a clock that the caller can replace, so their logic is tested
without sleeping.
"""
