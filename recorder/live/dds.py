"""ROS 2 topics over DDS without a ROS installation: the public names of the DDS transport.

Importing this module needs Cyclone DDS's Python binding (``pip install 'atikt[ros2]'``), an
optional extra; :mod:`recorder.live` itself does not import it, so a program without DDS
imports this module only where it uses DDS (and can say what to install when it is missing).
"""

from recorder.live._dds import (
    ATIKT_TYPES,
    LOOPBACK_CONFIG,
    DdsDomain,
    DdsError,
    Publication,
    RawReader,
    RawWriter,
    dds_topic,
    dds_type,
    leads_with_header,
    register_atikt_types,
    ros_type,
)

__all__ = [
    "ATIKT_TYPES",
    "LOOPBACK_CONFIG",
    "DdsDomain",
    "DdsError",
    "Publication",
    "RawReader",
    "RawWriter",
    "dds_topic",
    "dds_type",
    "leads_with_header",
    "register_atikt_types",
    "ros_type",
]
