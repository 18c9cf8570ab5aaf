"""Free loopback ports for a server a test starts in another process (serve-sim, a skin).

A port found by binding port 0 is an ephemeral one: between the probe and the server's own
bind, any socket that binds port 0 or sends a first datagram (a skin sender, a DDS
participant, a client's connection) in another test may be given it, and the server then fails
with "Address already in use" (a benchmark's skin port was taken so in a run of the suite).
Ports handed out here lie below Linux's ephemeral range (32768-60999), so the kernel never
gives them away by itself, in a block of their own per pytest-xdist worker, so two workers never
hand out the same one, and another block for the processes a worker's tests start (a benchmark
run by its quick test hands out ports of its own, and its lab may outlive it for a moment);
each is checked free (TCP and UDP) when handed out.

Written by hand: no library hands out ports that the kernel's ephemeral allocation cannot take.
"""

from __future__ import annotations

import itertools
import os
import random
import socket

#: First port of the blocks; they end below a UR's own ports (29999-30004), which the
#: virtual lab serves by default.
FIRST = 13_000
#: Ports per block.
BLOCK = 1_000
#: Blocks of workers' own ports, and as many again for processes their tests start (workers
#: beyond these share them, as the main process shares block 0).
BLOCKS = 8
#: The environment's record of the process that hands out its worker's own ports.
OWNER = "ATIKT_TEST_PORTS_OWNER"


def _block() -> range:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    me = f"{worker}:{os.getpid()}"
    owner = os.environ.get(OWNER, "")
    if owner.partition(":")[0] != worker:  # the first process of this worker to ask: its own
        os.environ[OWNER] = owner = me
    index = int(worker.removeprefix("gw")) % BLOCKS if worker.removeprefix("gw").isdigit() else 0
    if owner != me:  # a process started by one of the worker's tests
        index += BLOCKS
    return range(FIRST + index * BLOCK, FIRST + (index + 1) * BLOCK)


#: How long a probe listens for datagrams sent to a port nobody has bound, s: a sender left
#: running (a lab process that outlived its test) would mix its frames into the next skin
#: bound there; a skin's fastest frames come every millisecond.
QUIET_S = 0.005


def _free(port: int) -> bool:
    for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        with socket.socket(socket.AF_INET, kind) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                return False
            if kind == socket.SOCK_DGRAM:
                probe.settimeout(QUIET_S)
                try:
                    probe.recv(1)
                except TimeoutError:
                    continue
                return False  # something sends to this port
    return True


#: Ports of the block in a random order (a process started by a test, e.g. a benchmark, starts
#: elsewhere in the block than its parent), each handed out once.
_ORDER = list(_block())
random.shuffle(_ORDER)
_NEXT = itertools.cycle(_ORDER)


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """Return a loopback port free for TCP and UDP, never the same twice in a row of a block.

    ``kind`` is accepted for the callers' clarity (every port is free for both).
    """
    del kind
    for port in itertools.islice(_NEXT, BLOCK):
        if _free(port):
            return port
    msg = f"no free loopback port in {_block()}"
    raise OSError(msg)
