"""One process at a time drives an arm from this computer.

A controller runs one program at a time: a second session started against the same arm (a
forgotten terminal, a live ``learn`` beside a ``session``) would replace the first one's
motion with its own, mid-action, and neither would know. A driver takes :func:`arm_lock` for
the arm it drives before it sends anything that moves it; a second process is refused in one
line naming the first.

The lock is an advisory ``flock`` on a file per arm in the user's runtime directory
(``$XDG_RUNTIME_DIR/atikt``, else ``<tmp>/atikt-<uid>``): the kernel releases it when its
process ends however it ends (SIGKILL, a power cut leaves no lock behind). It guards one
computer and one user; another computer driving the same arm is the controller's business (a
UR controller in remote control takes programs from every client).
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from recorder.errors import RigError

if TYPE_CHECKING:
    from collections.abc import Iterator

#: Characters kept in a lock file's name (the rest of an arm's name becomes ``_``).
_SAFE = re.compile(r"[^A-Za-z0-9._-]")


def lock_directory() -> Path:
    """Return the directory of the arms' lock files (created, private to the user).

    Raises:
        RigError: Neither the runtime directory nor the temporary one can hold it.
    """
    uid = os.getuid() if hasattr(os, "getuid") else 0
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    candidates = [Path(runtime) / "atikt"] if runtime and Path(runtime).is_dir() else []
    candidates.append(Path(tempfile.gettempdir()) / f"atikt-{uid}")
    problem = ""
    for base in candidates:
        try:
            base.mkdir(mode=0o700, parents=True, exist_ok=True)
        except OSError as err:
            problem = f"{base}: {err.strerror}"
            continue
        return base
    msg = f"cannot make the arms' lock directory ({problem}); set XDG_RUNTIME_DIR to a writable one"
    raise RigError(msg)


@contextlib.contextmanager
def arm_lock(arm: str, where: str) -> Iterator[None]:
    """Hold the lock of ``arm`` (e.g. ``ur-127.0.0.1-30004``) for the block.

    Args:
        arm: The arm's identity: its kind and an address that is the arm's alone (a UR:
            its host and RTDE port).
        where: The configuration file, for the message.

    Raises:
        RigError: Another process of this user on this computer holds it.
    """
    if sys.platform == "win32":  # no flock: the controller's own rules apply
        yield
        return
    import fcntl  # noqa: PLC0415 (POSIX only)

    path = lock_directory() / f"{_SAFE.sub('_', arm)}.lock"
    try:
        handle = path.open("a+", encoding="utf-8")
    except OSError as err:
        msg = f"{path}: cannot open the arm's lock ({err.strerror}); check the directory"
        raise RigError(msg) from err
    with handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            msg = (
                f"{where}: {holder} drives the arm {arm} from this computer; a controller runs "
                "one program at a time, so a second would replace its motion: wait for it to "
                "end or stop it"
            )
            raise RigError(msg) from None
        handle.seek(0)
        handle.truncate()
        command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:2]]) if sys.argv else "python"
        handle.write(f"pid {os.getpid()} ({command})")
        handle.flush()
        try:
            yield
        finally:
            handle.seek(0)
            handle.truncate()
            fcntl.flock(handle, fcntl.LOCK_UN)
