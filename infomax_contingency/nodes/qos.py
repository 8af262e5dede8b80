"""QoS profiles of the graph's topics.

The step-clock topics (``sound``, ``sound_energy``, ``vocalize``, ``belief``,
``partner_present`` and the stamped ``sound_step``, ``vocalize_step``) are reliable,
keep-last :data:`STREAM_DEPTH` (a deep history: a listener starved of CPU for a while
still gets every message resent); ``audio`` chunks are up to megabytes, so their
history is :data:`AUDIO_DEPTH`; slow-changing state (``posture``, ``joint_targets``) is reliable and
transient-local with depth 1, so a late joiner gets the current value.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

STREAM_DEPTH = 1000
"""History depth of the step-clock topics (messages kept for a slow reader): at most
about 100 kB of small messages per topic."""

AUDIO_DEPTH = 1000
"""History depth of the ``audio`` topic: a chunk a reader lost on the way is resent from
this history at the writer's next heartbeat (Fast DDS default: every 3 s). A lockstep room
at full speed publishes about 300 chunks a second, so a history of 100 had dropped a lost
chunk before its repair: a recorder starved of CPU lost 7 of 200 for good. 1000 chunks of
a 0.5 s window at 16 kHz are 32 MB at most."""

STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=STREAM_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of the per-window topics."""

AUDIO_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=AUDIO_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of ``audio``."""

STEP_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=STREAM_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of the nodes that read ``sound_step`` and ``vocalize_step``: as deep as the writers',
so that a burst on the topic (an intruder among the true messages) does not push a true
message out before the node takes it."""

LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""QoS of slow-changing state: late joiners receive the last value."""

LATCHED_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""QoS to read slow-changing state: the last value on joining, then every change (a
deeper queue than the writer's, so two quick changes are both received)."""

LOSSLESS_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""QoS of a monitor that must not lose a step-clock message even when it is busy: the
middleware keeps every sample received until the monitor takes it (a recorder, tests)."""
