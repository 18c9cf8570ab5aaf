"""A threaded TCP server on loopback: the virtual lab's RTDE and URScript ports share it."""

from __future__ import annotations

import contextlib
import socket
import threading
from typing import TYPE_CHECKING, Any, Self

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import TracebackType


class TcpServer:
    """Listen on ``host:port`` while inside ``with``; one thread per client runs :meth:`serve`.

    Subclasses implement :meth:`serve` (and return when :attr:`stopping` is set).
    """

    #: Name of the server's threads.
    thread_name = "atikt-tcp"
    #: Whether to send small packets at once (the RTDE stream: Nagle off).
    no_delay = False

    def __init__(self, host: str, port: int) -> None:
        """Prepare the server (it listens from ``__enter__``; port 0: any free port)."""
        self._bind = (host, port)
        self._listener: socket.socket | None = None
        self.stopping = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def address(self) -> tuple[str, int]:
        """Return the bound (host, port)."""
        if self._listener is None:
            return self._bind
        host, port = self._listener.getsockname()[:2]
        return str(host), int(port)

    def __enter__(self) -> Self:
        """Bind, listen and start accepting clients."""
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(self._bind)
            listener.listen()
            listener.settimeout(0.1)
        except BaseException:  # an address it cannot bind (a name that does not resolve)
            listener.close()
            raise
        self._listener = listener
        self.spawn(self._accept)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop serving and close the listening socket."""
        self.stopping.set()
        for thread in self._threads:
            thread.join(2.0)
        if self._listener is not None:
            self._listener.close()

    def stop_listening(self) -> None:
        """Refuse new clients from now on (those connected are served on)."""
        if self._listener is not None:
            # shut down first: a close alone leaves the socket listening while the accepting
            # thread still polls it
            with contextlib.suppress(OSError):
                self._listener.shutdown(socket.SHUT_RDWR)
            self._listener.close()

    def spawn(self, target: Callable[..., None], *args: Any) -> None:  # noqa: ANN401
        """Run ``target(*args)`` in a daemon thread joined at the end."""
        thread = threading.Thread(target=target, args=args, daemon=True, name=self.thread_name)
        self._threads.append(thread)
        thread.start()

    def _accept(self) -> None:
        listener = self._listener
        assert listener is not None  # noqa: S101 (set in __enter__)
        while not self.stopping.is_set():
            try:
                sock, _ = listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            if self.no_delay:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.spawn(self.serve, sock)

    def serve(self, sock: socket.socket) -> None:
        """Serve one client until it leaves or the server stops."""
        raise NotImplementedError
