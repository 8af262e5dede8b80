"""Sound to numbers: wav I/O, resampling, window energies, thresholds, binarizers, live audio.

Modules, lowest first (each imports only those above it):

* :mod:`.common` — AudioError, the processing rate, argument checks.
* :mod:`.wav` — WAV header parsing, block-by-block and whole-file reading, mixdown, writing.
* :mod:`.resample` — whole-signal and streaming resampling (bit-identical).
* :mod:`.energy` — window energies, WindowAssembler, the one WAV-to-energies path.
* :mod:`.threshold` — the mathematics: k-means threshold, the bit rule, separation check,
  the noise-floor tracker; :mod:`.threshold_file` — threshold files.
* :mod:`.synth` — the robot's synthesized chirp.
* :mod:`.bitsources` — the registry of bit sources (energy, speech_band, vad): one window
  of samples to one bit, each source one class with its settings dataclass;
  ``make_bit_source``, used by mic_node, the offline loop and the CLI.
* :mod:`.devices` — PortAudio devices: listing, choosing, formats, opening streams.
* :mod:`.timeline` — window timing of a live capture (plain class, no threads).
* :mod:`.capture` — MicrophoneStream; :mod:`.playback` — SpeakerOutput.
* :mod:`.windows` — window sources behind one interface: WavReplay, TopicWindows,
  MicrophoneWindows (and :mod:`.bag_replay`'s BagReplay).
* :mod:`.calibration` — calibration energies (file or live) and their histogram.
* :mod:`.latency` — measuring the robot's own sound delay.

No rclpy. May import the base modules and :mod:`infomax_contingency.core`. The live
modules use threads and a clock that the caller can replace, so their logic is tested
without sleeping.
"""
