"""Sound to numbers: wav I/O, resampling, window energies, thresholds, binarizers, live audio.

Modules, lowest first (each imports only those above it):

* :mod:`.common` — AudioError, the processing rate, argument checks.
* :mod:`.wav` — WAV header parsing, block-by-block and whole-file reading, mixdown, writing.
* :mod:`.resample` — whole-signal and streaming resampling (bit-identical).
* :mod:`.energy` — window energies, WindowAssembler, the one WAV-to-energies path.
* :mod:`.threshold` — k-means threshold, the bit rule, separation check, threshold files,
  the noise-floor tracker.
* :mod:`.synth` — the robot's synthesized chirp.
* :mod:`.binarizer` — WavReplay and Binarizer (energies to bits, calibration), and
  NoiseFloorBinarizer (a margin above a tracked noise floor).
* :mod:`.bitsource` — bit sources by name (energy, speech_band, vad): one window of
  samples to one bit; ``make_bit_source``, used by mic_node and the offline loop.
* :mod:`.devices` — PortAudio devices: listing, choosing, formats, opening streams.
* :mod:`.timeline` — window timing of a live capture (plain class, no threads).
* :mod:`.capture` — MicrophoneStream; :mod:`.playback` — SpeakerOutput.
* :mod:`.calibration` — calibration energies (file or live) and their histogram.
* :mod:`.latency` — measuring the robot's own sound delay.

No rclpy. May import the base modules and :mod:`infomax_contingency.core`. The live
modules use threads and a clock that the caller can replace, so their logic is tested
without sleeping.
"""
