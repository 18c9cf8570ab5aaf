"""``view --serve`` listens on loopback only and stops on the first Ctrl-C; --scheduler warns."""

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from ports import free_port

from replay.learning._parallel import scheduler_warning

_LISTEN = "0A"  # TCP state LISTEN in /proc/net/tcp


def _listeners(port: int) -> list[str]:
    """Return the local addresses (hex, as the kernel lists them) listening on ``port``."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError):
            for line in Path(table).read_text().splitlines()[1:]:
                fields = line.split()
                address, hex_port = fields[1].rsplit(":", 1)
                if fields[3] == _LISTEN and int(hex_port, 16) == port:
                    found.append(address)
    return found


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads Linux's socket table")
def test_serve_listens_on_loopback_prints_its_address_and_stops_on_ctrl_c(
    fake_recording: Path,
) -> None:
    web, grpc = free_port(), free_port()
    command = [sys.executable, "-m", "replay", "view", str(fake_recording), "--serve"]
    command += ["--web-port", str(web), "--grpc-port", str(grpc), "--no-figures"]
    env = os.environ | {"PYTHONPATH": str(Path.cwd())}
    process = subprocess.Popen(  # noqa: S603 (this project's command)
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline().decode()
        assert line.startswith(f"web viewer on http://127.0.0.1:{web}/"), line
        for port in (web, grpc):
            assert _listeners(port) == ["0100007F"]  # 127.0.0.1, and nothing else
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0
    assert out.decode().strip() == "stopped serving"
    assert _listeners(web) == []
    assert _listeners(grpc) == []


@pytest.mark.parametrize(
    ("address", "warned"),
    [
        ("tcp://10.1.2.3:8786", True),
        ("cluster.example.org:8786", True),
        ("tls://10.1.2.3:8786", False),
        ("tcp://127.0.0.1:8786", False),
        ("localhost:8786", False),
    ],
)
def test_a_scheduler_without_tls_off_this_machine_is_named_a_risk(
    address: str, *, warned: bool
) -> None:
    warning = scheduler_warning(address)
    assert (warning is not None) == warned
    if warning is not None:
        assert "run code here" in warning
        assert "\n" not in warning
