"""Serving a web viewer (``view --serve``) on one address, loopback by default.

rerun-sdk's in-process servers (``serve_grpc``, ``serve_web_viewer``, 0.41) take a port but no
address and listen on every interface (0.0.0.0). The rerun command line that ships in the
same package (``rerun_cli``) takes ``--bind``; the viewer therefore runs as that command in
its own process group, bound to ``--host`` (127.0.0.1 unless told otherwise), and the
recordings are streamed to it over loopback gRPC. Stopping is ours: the first Ctrl-C ends the
group and the command.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from replay.errors import ReplayError

if TYPE_CHECKING:
    from collections.abc import Iterator

#: Default address of the served viewer: this machine only.
DEFAULT_HOST = "127.0.0.1"
#: Seconds to wait for the viewer's ports to accept connections.
START_TIMEOUT_S = 30.0
#: Seconds the viewer gets to stop after SIGTERM before it is killed.
STOP_TIMEOUT_S = 5.0
_POLL_S = 0.1


@dataclass(frozen=True, slots=True)
class Served:
    """A running web viewer.

    Attributes:
        process: The rerun command line serving it.
        grpc_url: Where recordings are sent (``rerun+http://HOST:PORT/proxy``).
        address: The web viewer's address, to open in a browser.
    """

    process: subprocess.Popen[bytes]
    grpc_url: str
    address: str


def _url_host(host: str) -> str:
    """Return ``host`` as it appears in a URL (IPv6 addresses in brackets)."""
    return f"[{host}]" if ":" in host else host


def _connect_host(host: str) -> str:
    """Return the address to reach a server bound to ``host`` from this machine."""
    return {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(host, host)  # noqa: S104 (compared only)


def _accepts(host: str, port: int) -> bool:
    """Return True if ``host:port`` accepts a TCP connection (a local check)."""
    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=1):
        return True
    return False


def _stop(process: subprocess.Popen[bytes]) -> None:
    """End the viewer's process group: SIGTERM, then SIGKILL after a grace period."""
    if process.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGTERM)
    try:
        process.wait(STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _wait_ready(process: subprocess.Popen[bytes], host: str, ports: tuple[int, ...]) -> None:
    """Wait until every port accepts connections.

    Raises:
        ReplayError: The viewer exited or did not start in time.
    """
    deadline = time.monotonic() + START_TIMEOUT_S
    while not all(_accepts(host, port) for port in ports):
        if process.poll() is not None:
            error = process.stderr.read().decode(errors="replace") if process.stderr else ""
            reason = " ".join(error.split())[-300:] or f"exit status {process.returncode}"
            msg = (
                f"--serve: the rerun viewer stopped ({reason}); choose free ports with "
                "--web-port/--grpc-port, or use --save FILE.rrd"
            )
            raise ReplayError(msg)
        if time.monotonic() > deadline:
            msg = f"--serve: the rerun viewer did not start within {START_TIMEOUT_S:g} s"
            raise ReplayError(msg)
        time.sleep(_POLL_S)


@contextlib.contextmanager
def serve_viewer(host: str, web_port: int, grpc_port: int) -> Iterator[Served]:
    """Run a web viewer and its gRPC data server bound to ``host`` until the block ends.

    Raises:
        ReplayError: The viewer cannot start (ports taken, rerun missing).
    """
    command = [
        sys.executable,
        "-m",
        "rerun_cli",
        "--serve-web",
        "--bind",
        host,
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(web_port),
    ]
    try:
        process = subprocess.Popen(  # noqa: S603 (rerun's own command line, fixed arguments)
            command,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            start_new_session=True,  # Ctrl-C reaches us only; we stop the whole group
        )
    except OSError as err:
        msg = f"--serve: cannot start the rerun viewer ({err.strerror}); use --save FILE.rrd"
        raise ReplayError(msg) from err
    try:
        local = _connect_host(host)
        _wait_ready(process, local, (grpc_port, web_port))
        grpc_url = f"rerun+http://{_url_host(local)}:{grpc_port}/proxy"
        address = f"http://{_url_host(host)}:{web_port}/?url={grpc_url}"
        yield Served(process, grpc_url, address)
    finally:
        _stop(process)


def wait_until_interrupted(served: Served) -> None:
    """Block until Ctrl-C (SIGINT) or SIGTERM, or until the viewer exits by itself.

    Both signals are handled explicitly: a shell starts background jobs with SIGINT ignored,
    and a served viewer must still stop on the first Ctrl-C sent to it.
    """
    handled = (signal.SIGINT, signal.SIGTERM)
    previous = {number: signal.signal(number, signal.default_int_handler) for number in handled}
    try:
        served.process.wait()
    except KeyboardInterrupt:
        return
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
