"""Live sources: reader threads, bounded queues, sample accounting, clocks and skin blocks.

Every live source (the arm's RTDE stream, a skin's UDP or serial frames, ROS 2 topics over
DDS) is read by one :class:`SourceReader` thread into a bounded queue that counts what it
could not hold; the consumer counts every sample with a :class:`SourceCounter` (expected from
the source's sequence counter or clock, received, missing, duplicated, out of order, clock
offset), and the counts of each recording are written into its file (:class:`SourceStats`).

The DDS transport (Cyclone DDS, an optional extra) is the public submodule
:mod:`recorder.live.dds`, imported only by what uses it. This package imports nothing of
:mod:`recorder.bagimport`, which builds on it (``listen`` and the ROS 2 live skin).
"""

from recorder.live._accounting import (
    SOURCES_RECORD,
    SourceCounter,
    SourceStats,
    Verdict,
    counter_skipped,
    gap_periods,
    parse_source_stats,
)
from recorder.live._clock import RecorderClock
from recorder.live._framelayout import FIELD_TYPES, FrameType, SkinLayout, parse_layout
from recorder.live._frames import SerialSkin, UdpSkin
from recorder.live._packer import BlockPacker
from recorder.live._reader import Drop, Received, SourceLostError, SourceReader
from recorder.live._realtime import check_rt_priority, readers_at, real_time, rt_refusal
from recorder.live._skin import (
    FORCE_WINDOW_NS,
    SKIN_ENTRY_POINTS,
    SKIN_TRANSPORTS,
    ExplainingSkin,
    LiveSkin,
    ReportingSkin,
    SensingSkin,
    SkinFinding,
    open_skin,
    skin_transports,
    window_samples,
)

__all__ = [
    "FIELD_TYPES",
    "FORCE_WINDOW_NS",
    "SKIN_ENTRY_POINTS",
    "SKIN_TRANSPORTS",
    "SOURCES_RECORD",
    "BlockPacker",
    "Drop",
    "ExplainingSkin",
    "FrameType",
    "LiveSkin",
    "Received",
    "RecorderClock",
    "ReportingSkin",
    "SensingSkin",
    "SerialSkin",
    "SkinFinding",
    "SkinLayout",
    "SourceCounter",
    "SourceLostError",
    "SourceReader",
    "SourceStats",
    "UdpSkin",
    "Verdict",
    "check_rt_priority",
    "counter_skipped",
    "gap_periods",
    "open_skin",
    "parse_layout",
    "parse_source_stats",
    "readers_at",
    "real_time",
    "rt_refusal",
    "skin_transports",
    "window_samples",
]
