"""The tests' loopback ports: a port something still sends to is never handed out."""

from __future__ import annotations

import socket
import threading
import time

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
