"""Cyclone DDS on loopback only: every DDS test and its subprocesses stay on 127.0.0.1.

``CYCLONEDDS_URI`` is read when the binding creates its first participant; it is set here,
when pytest collects this directory (before any test module imports ``cyclonedds``), and the
``dds_domain`` fixture checks it is still in force.
"""

from __future__ import annotations

import os

import pytest

#: Cyclone DDS restricted to the loopback interface, no multicast, one peer: 127.0.0.1.
LOOPBACK_URI = (
    '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    '<Peer address="127.0.0.1"/></Peers><ParticipantIndex>auto</ParticipantIndex>'
    "</Discovery></Domain></CycloneDDS>"
)
os.environ["CYCLONEDDS_URI"] = LOOPBACK_URI


@pytest.fixture(scope="session")
def dds_domain() -> int:
    """Return this run's DDS domain id (from the process id: runs in parallel do not meet)."""
    assert os.environ["CYCLONEDDS_URI"] == LOOPBACK_URI
    return 1 + os.getpid() % 200
