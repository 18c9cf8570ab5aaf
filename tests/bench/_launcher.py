"""Start benchmark scripts as forks of one process that has imported the libraries already.

``tests/test_bench_quick.py`` runs every script's ``--quick`` mode as its own process; started
from a fresh interpreter, each spends seconds of CPU importing numpy, scipy, polars, mcap,
scikit-learn and the project before its few steps. This launcher imports them once and forks a
child per script: each run is still a process of its own (its own modules, globals, signal
handlers, environment and working directory; nothing leaks into the next run), started from an
interpreter that has nothing else in it. The launcher holds no threads when it forks (BLAS runs
single-threaded: ``OPENBLAS_NUM_THREADS=1`` in its environment).

Protocol (one request at a time, JSON lines): the caller writes ``{"script", "argv", "cwd",
"env", "stdout", "stderr"}`` to the launcher's stdin; the launcher answers ``{"pid": N}`` when the
child started and ``{"status": S}`` when it ended (S: the exit status, or minus the signal that
ended it, as ``subprocess`` reports it). End of input ends the launcher.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import runpy
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

#: What the quick modes import, loaded once before any fork.
PRELOAD = (
    "numpy",
    "scipy.optimize",
    "scipy.stats",
    "polars",
    "sklearn.gaussian_process",
    "joblib",
    "mcap.reader",
    "rosbags.highlevel",
    "rich.console",
    "schemas",
    "recorder",
    "atikt",
    "replay",
    "replay.cli._main",
    "replay.learning._features",
    "replay.outputs._study_report",
)


def _child(request: dict[str, Any]) -> int:
    """Run one script in this (forked) process as ``python SCRIPT ARGV...`` would; its status."""
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    tempfile.tempdir = None  # found again from the request's TMPDIR
    for fd, name in ((1, "stdout"), (2, "stderr")):
        target = os.open(request[name], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(target, fd)
        os.close(target)
    null = os.open(os.devnull, os.O_RDONLY)  # the requests stay the launcher's
    os.dup2(null, 0)
    os.close(null)
    sys.stdin = open(0, encoding="utf-8", closefd=False)  # noqa: SIM115 (the process's stdin)
    script = request["script"]
    sys.argv = [script, *request["argv"]]
    sys.path.insert(0, str(Path(script).parent))  # `python SCRIPT` puts its directory first
    try:
        runpy.run_path(script, run_name="__main__")
    except SystemExit as done:
        code = done.code
        if code is None:
            return 0
        if isinstance(code, int):
            return code
        print(code, file=sys.stderr)
        return 1
    except BaseException:  # noqa: BLE001 (printed as the interpreter would, then status 1)
        traceback.print_exc()
        return 1
    return 0


def _answer(message: dict[str, int]) -> None:
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()


def main() -> None:
    """Import :data:`PRELOAD`, then fork one child per request line until the input ends.

    What was imported is frozen out of the garbage collector (``gc.freeze``, as Python's
    documentation advises before forking): a child's collections, and the one at its exit,
    would otherwise walk every object of the preloaded libraries, about 0.35 s of CPU per
    script (a quick run takes 0.4-5 s); the child's own objects are collected as usual.
    """
    for name in PRELOAD:
        __import__(name)
    gc.collect()
    gc.freeze()
    _answer({"ready": 1})
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:  # the child ends as an interpreter does: threads joined, atexit run
            os.setpgid(0, 0)  # a group of its own: what it starts and leaves behind is found
            sys.exit(_child(request))
        _answer({"pid": pid})
        _, wait_status = os.waitpid(pid, 0)
        _answer({"status": os.waitstatus_to_exitcode(wait_status), "left": _end_group(pid)})


#: How long what a script started may take to end after it (multiprocessing's resource
#: tracker ends once it sees its parent gone), s.
GRACE_S = 5.0


def _group(pgid: int) -> list[int]:
    """Return the live processes (not zombies) of process group ``pgid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            found.append(int(entry.name))
    return found


def _end_group(pgid: int) -> int:
    """Kill what the script started and left running (a virtual lab ticking on); 1 if any."""
    deadline = time.monotonic() + GRACE_S
    while _group(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    if not _group(pgid):  # the script stopped all it started
        return 0
    with contextlib.suppress(ProcessLookupError):
        os.killpg(pgid, signal.SIGKILL)
    return 1


if __name__ == "__main__":
    main()
