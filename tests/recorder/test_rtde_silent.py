"""An RTDE port that takes the connection and never answers: one line naming the port and fix."""

from __future__ import annotations

import socket
import threading

import pytest

from recorder.ur._rtde import RtdeClient, RtdeError


def test_a_port_that_never_answers_the_handshake_is_said_with_the_fix() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        taken: list[socket.socket] = []
        threading.Thread(target=lambda: taken.append(server.accept()[0]), daemon=True).start()
        port = server.getsockname()[1]
        client = RtdeClient("127.0.0.1", port, connect_timeout_s=0.3)
        with pytest.raises(RtdeError) as info:
            client.connect()
        client.close()
        for sock in taken:
            sock.close()
    said = str(info.value)
    assert said.startswith(f"RTDE 127.0.0.1:{port}: no answer to request 'V' within 0.3 s"), said
    assert "the controller's RTDE port (30004)" in said
    assert "\n" not in said
