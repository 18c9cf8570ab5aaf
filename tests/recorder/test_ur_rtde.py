"""The RTDE client against the virtual lab's RTDE server, and ur_rtde as an independent client."""

import json
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from ur_lab import virtual_lab

from recorder.live import SourceCounter, SourceReader
from recorder.ur import RTDE_VARIABLES, RtdeClient, RtdeError
from recorder.ur._rtde import TEXT_MESSAGE, pack_package, pack_text, unpack_text
from recorder.virtuallab._controller import VirtualController
from recorder.virtuallab._rtde_server import RtdeFaults, RtdeServer

NS = 1_000_000_000


def _stream(port: int, frequency: int, seconds: float) -> tuple[SourceCounter, int]:
    """Receive for ``seconds``; return the counts and how many packages arrived."""
    with RtdeClient("127.0.0.1", port) as client:
        assert client.controller_version()[0] == (3 if frequency == 125 else 5)
        recipe = client.setup_outputs(RTDE_VARIABLES, frequency)
        client.start()
        counter = SourceCounter("rtde", period_ns=round(NS / frequency))
        arrived = 0
        with SourceReader("rtde", client.receive) as reader:
            time.sleep(seconds)
            assert client.pause(2.0)  # the answer follows the last data package
            reader.stop()
            for item in reader.drain():
                stamp = round(recipe.parse(item.payload)["timestamp"] * NS)
                counter.observe(None, stamp, item.receive_ns)
                arrived += 1
    return counter, arrived


@pytest.mark.parametrize("frequency", [125, 500])
def test_client_receives_every_package(frequency: int) -> None:
    with virtual_lab(frequency=frequency) as lab:
        counter, arrived = _stream(lab.rtde.address[1], frequency, 0.3)
        sent = lab.rtde.injected.sent
    stats = counter.stats()
    assert arrived == sent > 0.2 * frequency
    assert stats.complete
    assert stats.expected == stats.received == sent


def test_every_injected_fault_is_counted_exactly() -> None:
    faults = RtdeFaults(drop=3, duplicate=2, reorder=2, after=10)
    with virtual_lab(frequency=500, rtde_faults=faults) as lab:
        counter, arrived = _stream(lab.rtde.address[1], 500, 0.3)
        injected = lab.rtde.injected
    stats = counter.stats()
    assert (injected.dropped, injected.duplicated, injected.reordered) == (3, 2, 2)
    assert (stats.missing, stats.duplicated, stats.out_of_order) == (3, 2, 2)
    assert arrived == injected.sent == stats.received
    assert stats.expected == stats.received - 2 + 3


def test_unknown_variable_is_refused_by_name() -> None:
    with (
        virtual_lab() as lab,
        RtdeClient("127.0.0.1", lab.rtde.address[1]) as client,
        pytest.raises(RtdeError, match="does not provide no_such_variable") as info,
    ):
        client.setup_outputs(["actual_q", "no_such_variable"], 125)
    assert "\n" not in str(info.value)


def test_nothing_listening_is_one_line() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(RtdeError, match=f"127.0.0.1:{port}: cannot connect"):
        RtdeClient("127.0.0.1", port, connect_timeout_s=0.5).connect()


def test_text_messages_are_kept() -> None:
    assert unpack_text(pack_text("hello", "lab", 2)) == ("hello", "lab", 2)
    with virtual_lab() as lab, RtdeClient("127.0.0.1", lab.rtde.address[1]) as client:
        client.setup_outputs(["timestamp"], 125)
        client._connected().sendall(pack_package(ord("X")))  # unknown: the server says so
        client._connected().sendall(pack_package(TEXT_MESSAGE, pack_text("hi", "test", 3)))
        client.start()
        deadline = time.monotonic() + 2
        while not client.messages and time.monotonic() < deadline:
            client.receive()
        assert "unknown RTDE package type 88" in client.messages[0].message
        assert client.messages[0].level == "error"
        assert any("hi" in line for line in lab.controller.log)


def _port_free(port: int) -> bool:
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


#: ur_rtde runs in its own process: its constructor holds the GIL while it waits for answers,
#: which would starve the server's threads in this process.
#: Its default variables (none named): what a lab's own ur_rtde script asks for (every output
#: ur_rtde reads, the ones the lab does not model included).
_UR_RTDE = """
import json, sys, time, rtde_receive
receiver = rtde_receive.RTDEReceiveInterface("127.0.0.1", float(sys.argv[1]))
time.sleep(0.2)
print(json.dumps([
    receiver.getActualQ(), receiver.getActualTCPPose(), receiver.getTimestamp(),
    receiver.getRobotMode(), receiver.getSafetyStatusBits(), receiver.getJointMode(),
    receiver.getActualToolAccelerometer(),
    receiver.getFtRawWrench() if sys.argv[1] == "500" else None,  # e-Series only
]))
receiver.disconnect()
"""


@pytest.mark.parametrize("frequency", [125, 500])  # a CB3, an e-Series (more outputs asked)
def test_ur_rtde_reads_the_virtual_lab(frequency: int) -> None:
    pytest.importorskip("rtde_receive")
    # ur_rtde's receive interface has no port argument: it always connects to 30004.
    if not _port_free(30004):
        pytest.skip("127.0.0.1:30004 is in use; ur_rtde connects to no other port")
    with virtual_lab() as lab:
        lab.world.start_action("wood", "P1", 1)
        time.sleep(0.05)
        lab.world.stop("protective")  # freeze the arm at a pose that is not the origin
        controller = VirtualController(lab.world)
        pose = np.array([-0.7, -0.2, 0.15, 0.1, 3.0, 0.05])
        controller.park(pose)
        with RtdeServer(controller, "127.0.0.1", 30004, frequency=frequency):
            done = subprocess.run(  # noqa: S603 (this interpreter, a fixed script)
                [sys.executable, "-c", _UR_RTDE, str(frequency)],
                capture_output=True,
                text=True,
                timeout=30,
                check=True,
            )
        expected_q = lab.world.robot_at(lab.world.controller_ns()).q
    answer = json.loads(done.stdout.strip().splitlines()[-1])
    q, tcp, stamp, mode, safety, joints, gravity, wrench = answer
    assert (mode, safety) == (7, 1 << 2 | 1 << 10)  # running, in the protective stop above
    assert joints == [253] * 6
    assert abs(np.linalg.norm(gravity) - 9.81) < 1e-9
    assert np.abs(expected_q).max() > 0.1
    np.testing.assert_allclose(q, expected_q, atol=1e-12)
    np.testing.assert_allclose(tcp, pose, atol=1e-12)
    if frequency == 500:  # an e-Series
        assert len(wrench) == 6
    ticks = stamp * frequency
    assert stamp > 0
    assert abs(ticks - round(ticks)) < 1e-6  # on the controller's 8 ms grid
