"""Other tools open our recordings: rerun's MCAP loader, rosbags and ``mcap``, same values.

rerun's loader is driven headlessly two ways: ``rerun.chunk.McapReader`` (the loader behind
``rerun mcap convert``) and ``RecordingStream.log_file_from_path`` (the importers the viewer
runs when it opens a file), saved to an .rrd and read back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rerun_frames import Entities, nanoseconds, read_mcap_with_rerun, read_rrd
from rosbags.highlevel import AnyReader

from replay import MODALITIES, ActionRecording, read_recording

SIMULATED = Path(__file__).parents[2] / "recordings" / "data" / "foam_block" / "S2" / "001.mcap"
NS = 1_000_000_000
_SKIN = {
    "force": "SkinForce",
    "temperature": "SkinTemperature",
    "acceleration": "SkinAcceleration",
    "proximity": "SkinProximity",
}


@pytest.fixture(params=["fake", "simulated"])
def recording_path(request: pytest.FixtureRequest, fake_recording: Path) -> Path:
    return fake_recording if request.param == "fake" else SIMULATED


def _blocks(messages: list[dict[str, Any]]) -> np.ndarray:
    """Return the samples of skin block messages (as decoded by a tool), concatenated."""
    return np.concatenate(
        [
            np.asarray(m["data"], dtype=np.float32).reshape(
                m["n_samples"], m["n_cells"], m["n_channels"]
            )
            for m in messages
        ]
    )


def _stamp(header: dict[str, Any]) -> int:
    return int(header["stamp"]["sec"]) * NS + int(header["stamp"]["nanosec"])


def _check_rerun(entities: Entities, recording: ActionRecording) -> None:
    """Compare what rerun's MCAP loader decoded with our reader's arrays."""
    assert recording.joints is not None
    assert recording.tcp is not None
    joints = entities.temporal["/robot/joint_states/position"]
    np.testing.assert_array_equal(
        np.array(joints["Scalars:scalars"].to_list()), recording.joints.position
    )
    assert nanoseconds(joints["message_publish_time"]) == recording.joints.stamps_ns.tolist()
    assert tuple(joints["SeriesLines:names"][0]) == recording.joints.names
    tcp = entities.temporal["/robot/tcp_pose"]
    translations = np.array([row[0] for row in tcp["InstancePoses3D:translations"].to_list()])
    quaternions = np.array([row[0] for row in tcp["InstancePoses3D:quaternions"].to_list()])
    np.testing.assert_array_equal(translations, recording.tcp.position.astype(np.float32))
    np.testing.assert_array_equal(quaternions, recording.tcp.orientation.astype(np.float32))
    for modality, name in _SKIN.items():
        frame = entities.temporal[f"/skin/{modality}"].sort("message_publish_time")
        messages = [row[0] for row in frame[f"tactile_msgs.msg.{name}:message"].to_list()]
        np.testing.assert_array_equal(_blocks(messages), recording.skin(modality).data)
    events = entities.temporal["/action/events"].sort("message_publish_time")
    messages = [row[0] for row in events["tactile_msgs.msg.ActionEvent:message"].to_list()]
    assert [(m["phase"], _stamp(m["header"])) for m in messages] == list(recording.phases)
    (pairs,) = entities.static["/__mcap_metadata"]["atikt.recording"]  # an Arrow map
    metadata = {pair["first"]: pair["second"] for pair in pairs}
    meta = recording.metadata
    assert (metadata["object_id"], metadata["action_id"]) == (meta.object_id, meta.action_id)
    assert json.loads(metadata["rig"])["kind"] == meta.rig["kind"]


def test_rerun_mcap_loader_decodes_the_same_values(recording_path: Path) -> None:
    _check_rerun(read_mcap_with_rerun(recording_path), read_recording(recording_path))


def test_the_viewers_file_importer_decodes_the_same_values(
    recording_path: Path, tmp_path: Path
) -> None:
    stream = rr.RecordingStream("atikt-interop", send_properties=False)
    stream.set_log_time_enabled(False)
    stream.save(tmp_path / "opened.rrd")
    stream.log_file_from_path(recording_path)
    stream.flush()  # waits for the importers (rerun >= 0.28)
    stream.disconnect()
    _check_rerun(
        read_rrd(tmp_path / "opened.rrd", "message_log_time"), read_recording(recording_path)
    )


def _as_dict(message: Any) -> dict[str, Any]:
    """Return the fields a skin or event check needs, from a rosbags or mcap-ros2 message."""
    names = ("data", "n_samples", "n_cells", "n_channels", "phase")
    fields = {name: getattr(message, name) for name in names if hasattr(message, name)}
    stamp = message.header.stamp
    return fields | {"header": {"stamp": {"sec": stamp.sec, "nanosec": stamp.nanosec}}}


def _check_messages(decoded: list[tuple[str, Any]], recording: ActionRecording) -> None:
    """Compare messages decoded by rosbags or mcap with our reader's arrays."""
    by_topic: dict[str, list[Any]] = {}
    for topic, message in decoded:
        by_topic.setdefault(topic, []).append(message)
    for modality in MODALITIES:
        messages = [_as_dict(m) for m in by_topic[f"/skin/{modality}"]]
        np.testing.assert_array_equal(_blocks(messages), recording.skin(modality).data)
    assert recording.joints is not None
    positions = np.array([m.position for m in by_topic["/robot/joint_states"]])
    np.testing.assert_array_equal(positions, recording.joints.position)
    events = [_as_dict(m) for m in by_topic["/action/events"]]
    assert [(m["phase"], _stamp(m["header"])) for m in events] == list(recording.phases)


def test_rosbags_opens_the_file_itself() -> None:
    with AnyReader([SIMULATED]) as reader:  # rosbags >= 0.11: no metadata.yaml needed
        decoded = [
            (connection.topic, reader.deserialize(raw, connection.msgtype))
            for connection, _, raw in reader.messages()
        ]
    _check_messages(decoded, read_recording(SIMULATED))


def test_mcap_with_ros2_support_decodes_the_same_values() -> None:
    with SIMULATED.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [(c.topic, m) for _, c, _, m in reader.iter_decoded_messages()]
    _check_messages(decoded, read_recording(SIMULATED))
