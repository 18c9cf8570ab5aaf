"""The channels of a recording, derived from the vocabulary (see schemas/README.md)."""

from __future__ import annotations

from dataclasses import dataclass

from schemas._typestore import VOCABULARY


@dataclass(frozen=True, slots=True)
class Channel:
    """One channel of the recording contract.

    Attributes:
        topic: Topic name, part of the contract.
        msgtype: ROS 2 message type name.
        rate_hz: Nominal sample rate in Hz of the thesis's rig (0 for event channels).
        block_samples: Samples per message written by the simulated rig (1: per sample).
        units: Units of the payload.
        frame: Frame id written into the message headers.
        required: Whether every recording has this channel (only the action events).
        modality: The skin modality it carries ("" for robot and event channels).
    """

    topic: str
    msgtype: str
    rate_hz: float
    block_samples: int
    units: str
    frame: str
    required: bool = False
    modality: str = ""


def _channels() -> tuple[Channel, ...]:
    robot = [
        Channel(c.topic, c.msgtype, c.rate_hz, 1, c.units, c.frame)
        for c in VOCABULARY.robot.values()
    ]
    skin = [
        Channel(m.topic, m.msgtype, m.rate_hz, m.block_samples, m.units, "skin", modality=m.name)
        for m in VOCABULARY.modalities.values()
    ]
    events = VOCABULARY.events
    return (
        *robot,
        *skin,
        Channel(events.topic, events.msgtype, 0.0, 1, events.units, events.frame, required=True),
    )


#: Every channel of the contract: robot, skin modalities, action events.
CHANNELS: tuple[Channel, ...] = _channels()

_BY_TOPIC = {channel.topic: channel for channel in CHANNELS}


def channel_for_topic(topic: str) -> Channel | None:
    """Return the contract's channel for a topic, or None if the topic is not in the contract."""
    return _BY_TOPIC.get(topic)
