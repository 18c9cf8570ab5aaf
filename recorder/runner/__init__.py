"""The action runner: one robot loop for every arm (phases, limits, silence, the stop).

An arm is a small driver (:class:`ArmDriver`: a state stream, move, speed, force mode, stop);
:class:`ArmRig` drives any of them with a live skin through an action's phases. Recording an
action (:func:`recorder.record_action`) runs the runner's loop in the main thread, the writer
in its own (:class:`WriterThread`), and signals as a flag (:func:`deferred_interrupts`).
"""

from recorder.runner._arm import ArmDriver, ArmSample, Context, StopsOtherwise
from recorder.runner._interrupts import InterruptFlag, deferred_interrupts, raise_interrupt
from recorder.runner._limits import (
    LIGHT_CONTACT_N,
    REACHED_M,
    Limits,
    Motion,
    check_action,
    check_motion,
    check_pose,
    tool_axis,
)
from recorder.runner._lock import arm_lock
from recorder.runner._runner import ArmRig, RunnerOptions, Stop, Watch, peak_total
from recorder.runner._sink import WriterThread

__all__ = [
    "LIGHT_CONTACT_N",
    "REACHED_M",
    "ArmDriver",
    "ArmRig",
    "ArmSample",
    "Context",
    "InterruptFlag",
    "Limits",
    "Motion",
    "RunnerOptions",
    "Stop",
    "StopsOtherwise",
    "Watch",
    "WriterThread",
    "arm_lock",
    "check_action",
    "check_motion",
    "check_pose",
    "deferred_interrupts",
    "peak_total",
    "raise_interrupt",
    "tool_axis",
]
