"""Writing files safely: exclusive, unpredictable temporary names, then one rename.

Every file the project writes (indexes, caches, results, figures, exports, reports, object
declarations) goes through :func:`atomic_write` or :func:`atomic_path`:

- the temporary file is created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` beside the target,
  under a name drawn from :mod:`secrets`, so a link planted in the directory is never
  followed and no other process can guess the name;
- the data is flushed and synced before the rename, so a crash leaves either the old file or
  the new one, never half of one;
- ``replace=False`` publishes with :func:`os.link` (which fails on an existing target), so an
  existing file is never replaced, not even by a race.

The standard library's :func:`tempfile.mkstemp` creates files the same way; it is not used
because its names carry no hint of the target, and a leftover after a power cut should say
what it was (``.<name>.<random>.tmp``).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

#: Random bytes in a temporary name (128 bits: never guessed, never repeated).
TOKEN_BYTES = 16
_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
_FLAGS |= getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)


def temporary_name(target: Path, what: str = "tmp") -> Path:
    """Return an unpredictable hidden name beside ``target`` (``.<name>.<random>.<what>``)."""
    return target.with_name(f".{target.name}.{secrets.token_hex(TOKEN_BYTES)}.{what}")


def create_exclusive(path: Path) -> IO[bytes]:
    """Create ``path`` for writing; fail if anything (a file, a link) exists there.

    Raises:
        FileExistsError: Something exists at ``path`` (a link is not followed).
        OSError: The file cannot be created.
    """
    # builtin open: Path.open takes no opener, and the flags must be ours (O_EXCL, O_NOFOLLOW)
    return open(path, "wb", opener=lambda name, _flags: os.open(name, _FLAGS, 0o666))


def reserve_temporary(target: Path, what: str = "tmp") -> Path:
    """Create an empty temporary file beside ``target`` exclusively and return its name.

    For writers that take a path rather than an open file (the caller then writes into the
    file it owns; nobody else could have created or guessed the name).

    Raises:
        OSError: The file cannot be created.
    """
    path = temporary_name(target, what)
    create_exclusive(path).close()
    return path


def _sync_directory(directory: Path) -> None:
    """Sync a directory's entries (the rename) to disk where the platform allows it."""
    with contextlib.suppress(OSError):
        descriptor = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def publish_temporary(temporary: Path, target: Path, *, replace: bool = True) -> None:
    """Give the finished ``temporary`` file the name ``target``.

    Args:
        temporary: The written file, in ``target``'s directory.
        target: The final name.
        replace: Replace an existing ``target`` (else it is refused, also in a race).

    Raises:
        FileExistsError: ``target`` exists and ``replace`` is False.
        OSError: The rename failed.
    """
    if replace:
        temporary.replace(target)
    else:
        try:
            os.link(temporary, target)  # fails on an existing target, a link included
        except FileExistsError:
            raise
        except OSError:  # no hard links here: reserve the name exclusively, then rename
            create_exclusive(target).close()
            temporary.replace(target)
        else:
            temporary.unlink()
    _sync_directory(target.parent)


@contextlib.contextmanager
def atomic_path(target: Path, *, replace: bool = True, what: str = "tmp") -> Iterator[Path]:
    """Yield an exclusively created temporary file beside ``target``; on success, publish it.

    For writers that only take a path (``sink_parquet``). The file is synced and renamed
    when the block ends without an exception, and removed in every case that fails.

    Raises:
        FileExistsError: ``target`` exists and ``replace`` is False.
        OSError: A file cannot be created, synced or renamed.
    """
    temporary = reserve_temporary(target, what)
    try:
        yield temporary
        with temporary.open("rb+") as stream:
            os.fsync(stream.fileno())
        publish_temporary(temporary, target, replace=replace)
    finally:
        temporary.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_file(target: Path, *, replace: bool = True) -> Iterator[IO[bytes]]:
    """Yield a binary file that becomes ``target`` when the block ends without an exception.

    Raises:
        FileExistsError: ``target`` exists and ``replace`` is False.
        OSError: A file cannot be created, written, synced or renamed.
    """
    temporary = temporary_name(target)
    try:
        with create_exclusive(temporary) as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        publish_temporary(temporary, target, replace=replace)
    finally:
        temporary.unlink(missing_ok=True)


def atomic_write(
    target: Path, write: Callable[[IO[bytes]], object], *, replace: bool = True
) -> Path:
    """Write ``target`` through ``write(stream)`` atomically (see the module docstring).

    Args:
        target: The file to write.
        write: Writes the content into the open binary stream it is given.
        replace: Replace an existing ``target`` (else it is refused).

    Returns:
        ``target``.

    Raises:
        FileExistsError: ``target`` exists and ``replace`` is False.
        OSError: A file cannot be created, written, synced or renamed.
    """
    with atomic_file(Path(target), replace=replace) as stream:
        write(stream)
    return Path(target)


def atomic_write_text(target: Path, text: str, *, replace: bool = True) -> Path:
    """Write UTF-8 ``text`` to ``target`` atomically (see :func:`atomic_write`).

    Raises:
        FileExistsError: ``target`` exists and ``replace`` is False.
        OSError: The file cannot be written.
    """
    return atomic_write(target, lambda stream: stream.write(text.encode("utf-8")), replace=replace)
