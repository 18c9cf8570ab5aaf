"""The channels of a recording: topic, type, rate, units and frame (see schemas/README.md)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Channel:
    """One channel of the recording contract.

    Attributes:
        topic: Topic name, part of the contract.
        msgtype: ROS 2 message type name.
        rate_hz: Nominal sample rate in Hz (0 for event channels).
        block_samples: Samples carried per message (1 for per-sample channels).
        units: Units of the payload.
        frame: Frame id written into the message headers.
        required: Whether a recording without this channel is invalid.
    """

    topic: str
    msgtype: str
    rate_hz: float
    block_samples: int
    units: str
    frame: str
    required: bool = True


CHANNELS: tuple[Channel, ...] = (
    Channel("/ur10/joint_states", "sensor_msgs/msg/JointState", 125.0, 1, "rad, rad/s, N m", ""),
    Channel("/ur10/tcp_pose", "geometry_msgs/msg/PoseStamped", 125.0, 1, "m, quaternion", "base"),
    Channel("/skin/force", "tactile_msgs/msg/SkinForce", 250.0, 25, "N", "skin"),
    Channel("/skin/temperature", "tactile_msgs/msg/SkinTemperature", 20.0, 2, "C", "skin"),
    Channel(
        "/skin/acceleration", "tactile_msgs/msg/SkinAcceleration", 1000.0, 100, "m/s^2", "skin"
    ),
    Channel("/skin/proximity", "tactile_msgs/msg/SkinProximity", 50.0, 5, "m", "skin"),
    Channel("/action/events", "tactile_msgs/msg/ActionEvent", 0.0, 1, "SI", "base"),
)

_BY_TOPIC = {channel.topic: channel for channel in CHANNELS}


def channel_for_topic(topic: str) -> Channel | None:
    """Return the contract's channel for a topic, or None if the topic is not in the contract."""
    return _BY_TOPIC.get(topic)
