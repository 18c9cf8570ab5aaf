"""Other tools read our recordings: rosbags' AnyReader and mcap with mcap-ros2-support."""

from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from replay import ActionRecording, read_recording

_SKIN_TOPICS = {
    "/skin/force": "force",
    "/skin/temperature": "temperature",
    "/skin/acceleration": "acceleration",
    "/skin/proximity": "proximity",
}


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _compare(recording: ActionRecording, decoded: list[tuple[str, Any]]) -> None:
    """Check messages decoded by another tool against our reader's arrays."""
    by_topic: dict[str, list[Any]] = {}
    for topic, msg in decoded:
        by_topic.setdefault(topic, []).append(msg)
    for topic, modality in _SKIN_TOPICS.items():
        series = recording.skin(modality)
        blocks = [
            np.asarray(m.data, dtype=np.float32).reshape(m.n_samples, m.n_cells, m.n_channels)
            for m in by_topic[topic]
        ]
        np.testing.assert_array_equal(np.concatenate(blocks), series.data)
        firsts = [_stamp(m) for m in by_topic[topic]]
        starts = np.cumsum([0] + [len(b) for b in blocks[:-1]])
        np.testing.assert_array_equal(series.stamps_ns[starts], firsts)
    assert recording.joints is not None
    assert recording.tcp is not None
    joints = by_topic["/robot/joint_states"]
    np.testing.assert_array_equal([m.position for m in joints], recording.joints.position)
    np.testing.assert_array_equal([m.effort for m in joints], recording.joints.effort)
    assert tuple(joints[0].name) == recording.joints.names
    poses = by_topic["/robot/tcp_pose"]
    np.testing.assert_array_equal(
        [[p.pose.orientation.x, p.pose.orientation.w] for p in poses],
        recording.tcp.orientation[:, [0, 3]],
    )
    np.testing.assert_array_equal([_stamp(p) for p in poses], recording.tcp.stamps_ns)
    events = by_topic["/action/events"]
    assert [(e.phase, _stamp(e)) for e in events] == list(recording.phases)
    assert {e.action_id for e in events} == {recording.metadata.action_id}


def test_mcap_ros2_decodes_the_same_values(fake_recording: Path) -> None:
    with fake_recording.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [
            (channel.topic, msg)
            for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=False)
        ]
    _compare(read_recording(fake_recording), decoded)


def _rosbag2_directory(recording: Path, directory: Path) -> Path:
    """Put a recording into a rosbag2 directory: rosbags' reader wants a metadata.yaml."""
    directory.mkdir()
    (directory / recording.name).symlink_to(recording)
    with recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    assert summary.statistics is not None
    stats = summary.statistics
    topics = "".join(
        f"""
    - topic_metadata:
        name: {channel.topic}
        type: {summary.schemas[channel.schema_id].name}
        serialization_format: cdr
      message_count: {stats.channel_message_counts.get(channel.id, 0)}"""
        for channel in summary.channels.values()
    )
    (directory / "metadata.yaml").write_text(
        f"""rosbag2_bagfile_information:
  version: 5
  storage_identifier: mcap
  relative_file_paths: [{recording.name}]
  duration: {{nanoseconds: {stats.message_end_time - stats.message_start_time}}}
  starting_time: {{nanoseconds_since_epoch: {stats.message_start_time}}}
  message_count: {stats.message_count}
  compression_format: ""
  compression_mode: ""
  topics_with_message_count:{topics}
"""
    )
    return directory


def test_rosbags_anyreader_decodes_the_same_values(fake_recording: Path, tmp_path: Path) -> None:
    bag = _rosbag2_directory(fake_recording, tmp_path / "bag")
    with AnyReader([bag]) as reader:  # types from the definitions in the file alone
        assert {c.msgdef.format.name for c in reader.connections} == {"MSG"}
        decoded = [
            (connection.topic, reader.deserialize(raw, connection.msgtype))
            for connection, _, raw in reader.messages()
        ]
    _compare(read_recording(fake_recording), decoded)
