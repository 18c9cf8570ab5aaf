"""Live execution: the only part of ``replay`` that uses the recorder.

A live run performs each action the learner asks for on a rig, records it with the recorder
and reads the file back through the same reader and features as offline runs
(:class:`LiveExecutor`, :func:`learn_live`); the default simulated dataset is recorded here
on first use (:func:`ensure_default_dataset`). Every other module of ``replay`` reads files
only, and a test keeps it that way.
"""

from replay.live._default import default_dataset_dir, default_dataset_ready, ensure_default_dataset
from replay.live._executor import LiveExecutor
from replay.live._outputs import (
    LIVE_NAME,
    SESSION_DIR,
    check_live_run,
    claim_live_run,
    free_file,
    live_output,
    live_run_of,
    refuse_unfinished_replay,
    release_unused_claim,
)
from replay.live._run import (
    LiveCheck,
    LiveView,
    check_live,
    check_plan,
    check_rig,
    configured_rig,
    foxglove_view,
    learn_live,
    rig_configuration,
    session_view,
)

__all__ = [
    "LIVE_NAME",
    "SESSION_DIR",
    "LiveCheck",
    "LiveExecutor",
    "LiveView",
    "check_live",
    "check_live_run",
    "check_plan",
    "check_rig",
    "claim_live_run",
    "configured_rig",
    "default_dataset_dir",
    "default_dataset_ready",
    "ensure_default_dataset",
    "foxglove_view",
    "free_file",
    "learn_live",
    "live_output",
    "live_run_of",
    "refuse_unfinished_replay",
    "release_unused_claim",
    "rig_configuration",
    "session_view",
]
