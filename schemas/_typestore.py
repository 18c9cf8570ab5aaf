"""The message definitions of the data contract and the rosbags typestore that knows them."""

from __future__ import annotations

import functools
from importlib import resources
from typing import TYPE_CHECKING

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from schemas._vocabulary import load_vocabulary

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

#: ROS package name under which the custom message types live.
PACKAGE = "tactile_msgs"
#: The contract's vocabulary (``schemas/contract.toml``).
VOCABULARY = load_vocabulary(PACKAGE)
#: Version of the contract: layout, topics and metadata record.
SCHEMA_VERSION = VOCABULARY.schema_version
#: Version of the custom message definitions (the ``schema_version`` field of each message).
MESSAGE_VERSION = VOCABULARY.message_version
#: Custom message type names, each defined by ``schemas/msg/<Name>.msg``.
CUSTOM_TYPES = tuple(
    msgtype.rsplit("/", 1)[1]
    for msgtype in (*(m.msgtype for m in VOCABULARY.modalities.values()), VOCABULARY.events.msgtype)
    if msgtype.startswith(f"{PACKAGE}/")
)


def msg_definition(name: str) -> str:
    """Return the ``.msg`` text of one custom message type.

    Args:
        name: Short type name, e.g. ``"SkinForce"``.

    Returns:
        The definition text as shipped in ``schemas/msg``.
    """
    return resources.files(__package__).joinpath("msg", f"{name}.msg").read_text("utf-8")


def full_type_name(name: str) -> str:
    """Return the ROS 2 type name of a custom type, e.g. ``tactile_msgs/msg/SkinForce``."""
    return f"{PACKAGE}/msg/{name}"


@functools.cache
def build_typestore() -> Typestore:
    """Return a ROS 2 Humble typestore with the custom message types registered.

    The result is cached: the typestore is immutable once built.
    """
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name in CUSTOM_TYPES:
        store.register(get_types_from_msg(msg_definition(name), full_type_name(name)))
    return store
