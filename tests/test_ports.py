"""The tests' loopback ports: a port something still sends to is never handed out."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import ports


def test_a_port_a_leftover_sender_sends_to_is_not_free() -> None:
    """A skin sender left running by an earlier test (nothing bound at its target) would mix
    its frames into the next skin bound there: its port is not handed out."""
    port = ports.free_port()
    done = threading.Event()

    def send() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            while not done.is_set():
                sender.sendto(b"frame", ("127.0.0.1", port))
                time.sleep(0.001)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    try:
        time.sleep(0.02)
        assert not ports._free(port)
    finally:
        done.set()
        thread.join()
    time.sleep(0.01)
    assert ports._free(port)  # quiet again


def test_a_process_a_test_starts_hands_out_ports_of_another_block() -> None:
    """A benchmark started by a test hands out ports of its own: never one its worker may hand
    out next while the benchmark's lab is still sending."""
    started = subprocess.run(
        [sys.executable, "-c", "import ports; print(ports._block().start)"],
        env=os.environ | {"PYTHONPATH": str(Path(ports.__file__).parent)},
        capture_output=True,
        text=True,
        check=True,
    )
    own = ports._block()
    theirs = int(started.stdout)
    assert theirs not in own
    assert theirs - own.start == ports.BLOCKS * ports.BLOCK
