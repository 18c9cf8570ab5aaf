"""Start this project's commands (``python -m recorder ...``, ``python -m replay ...``) as forks
of a process that has imported their libraries already.

The live tests run a few dozen commands each as a lab types them (``serve-sim``, ``session``,
``listen``, ``learn``, ``check``) in processes of their own: Ctrl-C, SIGTERM, SIGKILL and the exit
status are what they test. A fresh interpreter spends 0.5-1.3 s of CPU importing numpy, scipy,
mcap and the project before the command's first line, on a machine whose two cores the tests
share. :class:`Popen` starts such a command as a fork of a server (this file run as a script,
one per xdist worker, started at the first command) that imported them once: the command is
still a process of its own, with its own pid, signals, file descriptors, working directory,
environment and exit status, run by ``runpy`` as ``python -m`` runs it, and the test's process
is its parent (a child subreaper: the server forks twice, the command is handed to the test's
process), so ``wait``, ``poll``, ``send_signal`` and ``communicate`` are subprocess's own. Any
other command line is started by :class:`subprocess.Popen` as usual.

Not for the tests of the interpreter's start itself (what a command imports, the installed
wheel): those start a fresh interpreter.
"""

from __future__ import annotations

import ctypes
import io
import json
import os
import runpy
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

#: The commands started as forks: ``python -m MODULE`` of these modules.
MODULES = ("recorder", "replay")
#: What the server imports before it serves (what the commands import at their start).
PRELOAD = (
    "numpy",
    "scipy.signal",
    "scipy.stats",
    "scipy.optimize",
    "mcap.reader",
    "rosbags.highlevel",
    "rich.console",
    "schemas",
    "recorder",
    "recorder._cli",
    "recorder._session_command",
    "recorder.virtuallab",
    "recorder.virtuallab._command",
    "atikt",
    "replay",
    "replay.cli._main",
    "replay.cli._learn",
    "replay.learning._session",
    "replay.outputs._study_report",  # matplotlib (learn's and study's figures)
    "recorder.bagimport._listen",
)
# Not replay.live: it imports rerun, whose runtime starts threads at import that a fork leaves
# behind.
#: prctl(2)'s option that makes this process the parent of its descendants' orphans.
PR_SET_CHILD_SUBREAPER = 36

_server: _Server | None = None
_server_lock = threading.Lock()
#: pid -> command line of every command started as a fork (the tests' checks of what was left
#: running look the command up here: a fork's /proc cmdline is the server's).
STARTED: dict[int, list[str]] = {}


class _Server:
    """This process's fork server: a connection to it, one request at a time."""

    def __init__(self) -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_CHILD_SUBREAPER)")
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        self.process = subprocess.Popen(  # noqa: S603 (this interpreter, this file)
            [sys.executable, __file__, str(theirs.fileno())],
            pass_fds=[theirs.fileno()],
            stdin=subprocess.DEVNULL,
        )
        theirs.close()
        self.socket = ours
        self.lines = ours.makefile("r", encoding="utf-8")
        self.lock = threading.Lock()
        ready = self.lines.readline()
        assert ready == "ready\n", f"the fork server did not start: {ready!r}"

    def start(self, request: dict[str, Any], fds: Sequence[int]) -> int:
        """Return the pid of a fork running ``request`` with ``fds`` as its stdin/out/err."""
        with self.lock:
            socket.send_fds(self.socket, [json.dumps(request).encode() + b"\n"], list(fds))
            answer = json.loads(self.lines.readline())
        if "error" in answer:
            raise OSError(answer["error"])
        pid: int = answer["pid"]
        return pid


def _server_started() -> _Server:
    global _server  # noqa: PLW0603 (one server per process, started at the first command)
    with _server_lock:
        if _server is None:
            _server = _Server()
        return _server


def _forkable(args: object, kwargs: Mapping[str, Any]) -> list[str] | None:
    """Return the ``-m`` command line of ``args`` when it can be forked (else None)."""
    if not isinstance(args, list | tuple) or len(args) < 3:
        return None
    argv = [str(arg) for arg in args]
    if argv[0] != sys.executable or argv[1] != "-m" or argv[2] not in MODULES:
        return None
    unsupported = ("preexec_fn", "pass_fds", "user", "group", "umask", "shell")
    if any(kwargs.get(name) for name in unsupported):
        return None
    if kwargs.get("process_group") not in {None, 0}:
        return None
    if kwargs.get("close_fds") is False or kwargs.get("executable") is not None:
        return None
    return argv


class Popen(subprocess.Popen[Any]):
    """:class:`subprocess.Popen`; ``python -m recorder|replay ...`` as a fork of the server."""

    def __init__(self, args: Any, **kwargs: Any) -> None:
        self._forked = _forkable(args, kwargs)
        self._new_session = bool(kwargs.get("start_new_session"))
        self._new_group = kwargs.get("process_group") == 0
        super().__init__(args, **kwargs)

    def _execute_child(self, *args: Any) -> None:
        """Start the child: subprocess's own way, or as a fork of the server."""
        if self._forked is None:
            super()._execute_child(*args)  # type: ignore[misc]
            return
        cwd, env = args[5:7]
        p2cread, p2cwrite, c2pread, c2pwrite, errread, errwrite = args[10:16]
        environment = dict(os.environ if env is None else env)
        request = {
            "argv": self._forked[2:],
            "cwd": os.fspath(cwd) if cwd is not None else str(Path.cwd()),
            "env": {os.fsdecode(k): os.fsdecode(v) for k, v in environment.items()},
            "new_session": self._new_session,
            "new_group": self._new_group,
        }
        # what is not redirected is this process's own, as a fresh subprocess inherits it
        fds = [fd if fd != -1 else own for own, fd in enumerate((p2cread, c2pwrite, errwrite))]
        self.pid = _server_started().start(request, fds)
        self._child_created = True
        STARTED[self.pid] = self._forked
        self._close_pipe_fds(  # type: ignore[attr-defined]
            p2cread, p2cwrite, c2pread, c2pwrite, errread, errwrite
        )

    def _handle_exitstatus(self, sts: int, *args: Any) -> None:
        super()._handle_exitstatus(sts, *args)  # type: ignore[misc]
        STARTED.pop(self.pid, None)


def run(
    args: list[str],
    *,
    timeout: float | None = None,
    check: bool = False,
    input: str | None = None,  # noqa: A002 (subprocess.run's name)
    **kwargs: Any,
) -> subprocess.CompletedProcess[Any]:
    """:func:`subprocess.run` with :class:`Popen`."""
    if kwargs.pop("capture_output", False):
        kwargs["stdout"] = kwargs["stderr"] = subprocess.PIPE
    if input is not None:
        kwargs["stdin"] = subprocess.PIPE
    with Popen(args, **kwargs) as process:
        try:
            out, err = process.communicate(input, timeout=timeout)
        except BaseException:
            process.kill()
            raise
        status = process.poll()
        assert status is not None
    if check and status:
        raise subprocess.CalledProcessError(status, args, out, err)
    return subprocess.CompletedProcess(args, status, out, err)


# --- the server (this file run as a script) ----------------------------------------------------


def _stdio(env: Mapping[str, str]) -> None:
    """Make sys.stdin/stdout/stderr anew on fds 0-2, as the interpreter makes them at its start."""
    unbuffered = bool(env.get("PYTHONUNBUFFERED"))
    encoding = env.get("PYTHONIOENCODING", "utf-8").split(":")[0] or "utf-8"

    def text(fd: int, mode: str, errors: str, *, line: bool) -> IO[str]:
        raw = io.FileIO(fd, mode, closefd=False)
        if mode == "rb":
            buffer: Any = io.BufferedReader(raw)
        else:
            buffer = raw if unbuffered else io.BufferedWriter(raw)
        wrapper = io.TextIOWrapper(
            buffer,
            encoding=encoding,
            errors=errors,
            line_buffering=line,
            write_through=unbuffered and mode != "rb",
        )
        wrapper.mode = mode.replace("b", "")  # type: ignore[misc]
        return wrapper

    made = {
        "stdin": text(0, "rb", "strict", line=False),
        "stdout": text(1, "wb", "strict", line=os.isatty(1)),
        "stderr": text(2, "wb", "backslashreplace", line=True),
    }
    for name, stream in made.items():
        setattr(sys, name, stream)
        setattr(sys, f"__{name}__", stream)


def _become(request: dict[str, Any], fds: list[int], server: socket.socket) -> list[str]:
    """Turn this fork into the requested command's process; return its ``-m`` argv."""
    server.close()
    signal.set_wakeup_fd(-1)
    for number in (signal.SIGCHLD, signal.SIGTERM, signal.SIGHUP):
        signal.signal(number, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
    os.closerange(3, os.sysconf("SC_OPEN_MAX"))
    os.chdir(request["cwd"])
    env: dict[str, str] = request["env"]
    os.environ.clear()
    os.environ.update(env)
    _stdio(env)
    argv: list[str] = request["argv"]
    sys.argv = ["-m", *argv[1:]]
    paths = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    sys.path[:] = [str(Path.cwd()), *paths, *(p for p in sys.path[1:] if p not in paths)]
    return argv


def _serve(server: socket.socket) -> tuple[dict[str, Any], list[int]] | None:
    """Fork a command per request; return the request in the fork that is to run it."""
    while True:
        message, fds, _, _ = socket.recv_fds(server, 1 << 20, 3)
        if not message:
            return None
        buffered = message
        while not buffered.endswith(b"\n"):
            more = server.recv(1 << 20)
            if not more:
                return None
            buffered += more
        request = json.loads(buffered)
        read, write = os.pipe()
        middle = os.fork()
        if middle == 0:  # the intermediate: forks the command, ends (it goes to the subreaper)
            os.close(read)
            started, setup = os.pipe()
            command = os.fork()
            if command == 0:
                os.close(write)
                os.close(started)
                if request["new_session"]:
                    os.setsid()
                elif request["new_group"]:
                    os.setpgid(0, 0)
                os.close(setup)  # its session or group is made: the caller may signal it
                return request, fds
            os.close(setup)
            os.read(started, 1)  # until the command closed its end (or ended)
            os.write(write, str(command).encode())
            os._exit(0)
        os.close(write)
        pid = int(os.read(read, 64) or b"0")
        os.close(read)
        os.waitpid(middle, 0)
        for fd in fds:
            os.close(fd)
        answer = {"pid": pid} if pid else {"error": "the fork server could not fork"}
        server.sendall(json.dumps(answer).encode() + b"\n")


def _main(fd: int) -> int:
    """Preload the libraries, then serve; in a command's fork, run the command."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    for name in PRELOAD:
        __import__(name)
    # Python's threads: none but this one (polars' allocator and spill cleaner start native
    # threads at import, which a fork leaves behind; its thread pool starts at first use)
    assert threading.active_count() == 1, f"the fork server holds {threading.enumerate()}"
    server = socket.socket(fileno=fd)
    server.sendall(b"ready\n")
    forked = _serve(server)
    if forked is None:
        return 0
    request, fds = forked
    argv = _become(request, fds, server)
    runpy._run_module_as_main(argv[0])  # type: ignore[attr-defined]  # as `python -m` does
    return 0


if __name__ == "__main__":
    sys.path[0] = str(Path(__file__).resolve().parents[1])  # the checkout, not tests/
    sys.exit(_main(int(sys.argv[1])))
