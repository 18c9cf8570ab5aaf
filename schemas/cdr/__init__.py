"""One decoder of the contract's message bytes, for the reader, the import and live topics.

Two fast paths share one set of rules (:mod:`schemas.cdr._rules`: base types, bounds checks,
limits) and one error (:class:`~schemas.errors.CdrError`):

- :func:`decode_topic` / :func:`gather`: a topic's CDR payloads as numpy columns, vectorised
  over the messages that share a layout (the reader: skin blocks, joint states, poses);
- :func:`compile_cdr` / :func:`compile_ros1`: a generated function per message type that reads
  a message's stamp and mapped fields from its bytes (the import and live DDS topics), or None
  for a type or a message it cannot vouch for (rosbags decodes it then).
"""

from schemas.cdr._columns import DecodedGroup, Layout, decode_topic, gather, message_layout
from schemas.cdr._compiled import Decoder, compile_cdr, compile_ros1
from schemas.cdr._rules import MAX_DECODER_LINES, MAX_DEPTH, header_stamp
from schemas.errors import CdrError

__all__ = [
    "MAX_DECODER_LINES",
    "MAX_DEPTH",
    "CdrError",
    "DecodedGroup",
    "Decoder",
    "Layout",
    "compile_cdr",
    "compile_ros1",
    "decode_topic",
    "gather",
    "header_stamp",
    "message_layout",
]
