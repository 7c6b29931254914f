"""A meshcat server process and a pipelined connection to it.

meshcat 0.3.2's ``Visualizer()`` starts its server with stdout and stderr piped and never read (a long session
that logs many browser connections can block it), prints to stdout, and its ``close()`` fails. Here the server
(``python -m meshcat.servers.zmqserver``) writes into a log file that nobody has to drain, its URLs are read from
that file, and :meth:`MeshcatServer.close` always stops it (terminate, then kill); on Linux it also dies with the
process that started it.

:class:`MeshcatConnection` speaks the server's ZMQ REQ/REP protocol through a DEALER socket, so commands are
pipelined: sending does not wait for the server, replies are collected later, and the number still owed tells a
live view when the server (or a browser behind it) is falling behind.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import ctypes.util
import logging
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

import zmq

from simnav.errors import SimnavError
from simnav.viz.commands import Command

log = logging.getLogger(__name__)

_URLS = re.compile(r"^zmq_url=(\S+)\s*^web_url=(\S+)\s*$", re.MULTILINE)
_PR_SET_PDEATHSIG = 1
_POLL_S = 0.02


def _die_with_parent() -> None:  # runs in the child between fork and exec
    libc_name = ctypes.util.find_library("c")
    if libc_name:
        ctypes.CDLL(libc_name).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


class MeshcatServer:
    """A meshcat server subprocess (ZMQ for commands, HTTP + websocket for browsers).

    Args:
        timeout_s: how long to wait for the server to report its URLs, s.

    Attributes:
        zmq_url: where commands go, e.g. ``tcp://127.0.0.1:6000``.
        web_url: the page to open in a browser, e.g. ``http://127.0.0.1:7000/static/``.

    Raises:
        SimnavError: the server did not start (the message holds the end of its log).
    """

    def __init__(self, timeout_s: float = 20.0) -> None:
        fd, name = tempfile.mkstemp(prefix="simnav-meshcat-", suffix=".log")
        self.log_path = Path(name)
        preexec = _die_with_parent if sys.platform.startswith("linux") else None
        with os.fdopen(fd, "wb") as out:
            self.process = subprocess.Popen([sys.executable, "-u", "-m", "meshcat.servers.zmqserver"],
                                            stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                            start_new_session=True, preexec_fn=preexec)
        atexit.register(self.close)
        try:
            self.zmq_url, self.web_url = self._wait_for_urls(timeout_s)
        except BaseException:
            self.close()
            raise
        log.info("meshcat server %d: %s (browser %s)", self.process.pid, self.zmq_url, self.web_url)

    def _wait_for_urls(self, timeout_s: float) -> tuple[str, str]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            match = _URLS.search(self.log_path.read_text(errors="replace"))
            if match:
                return match.group(1), match.group(2)
            if self.process.poll() is not None:
                break
            time.sleep(_POLL_S)
        state = "exited" if self.process.poll() is not None else f"gave no URL within {timeout_s:.0f} s"
        raise SimnavError(f"the meshcat server {state}; its log ({self.log_path}) ends with:\n{self.log_tail()}")

    def log_tail(self, lines: int = 10) -> str:
        """The last lines the server wrote."""
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    @property
    def running(self) -> bool:
        return self.process.poll() is None

    def close(self) -> None:
        """Stop the server (SIGTERM, then SIGKILL after 5 s) and remove its log. Safe to call twice."""
        atexit.unregister(self.close)
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5.0)
        self.log_path.unlink(missing_ok=True)

    def __enter__(self) -> MeshcatServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class MeshcatConnection:
    """Pipelined commands to a meshcat server.

    Args:
        zmq_url: the server's ZMQ URL.
        timeout_s: how long :meth:`flush` and :meth:`scene_html` wait for replies, s.
        connect_timeout_s: how long to wait for the server's first answer (its browser URL), s.

    Raises:
        SimnavError: no meshcat server answers at ``zmq_url`` within ``connect_timeout_s``.
    """

    def __init__(self, zmq_url: str, timeout_s: float = 20.0, connect_timeout_s: float = 5.0) -> None:
        self.zmq_url, self.timeout_s = zmq_url, timeout_s
        self._context = zmq.Context.instance()
        self._socket = self._connect()
        self._pending = 0
        # ask for the browser URL on a socket of its own: meshcat's own client reconnects after this request too
        self.web_url = self._request(b"url", connect_timeout_s).decode()

    def _connect(self) -> zmq.Socket:
        socket = self._context.socket(zmq.DEALER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.SNDHWM, 0)
        try:
            socket.connect(self.zmq_url)
        except zmq.ZMQError as err:
            socket.close(linger=0)
            raise SimnavError(f"meshcat: cannot connect to '{self.zmq_url}' ({err}); expected a ZMQ URL such as "
                              "tcp://127.0.0.1:6000") from None
        return socket

    def _request(self, request: bytes, timeout_s: float | None = None) -> bytes:
        """One request-reply on a fresh socket (nothing else may be in flight on it)."""
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        socket = self._connect()
        try:
            socket.send_multipart([b"", request])
            if not socket.poll(int(timeout_s * 1000)):
                raise SimnavError(f"meshcat: no server answers at {self.zmq_url} (waited {timeout_s:g} s)")
            return socket.recv_multipart()[-1]
        finally:
            socket.close(linger=0)

    @property
    def pending(self) -> int:
        """Commands sent whose reply has not arrived yet (replies that did arrive are collected first)."""
        self._collect(0)
        return self._pending

    def send(self, commands: Iterable[Command]) -> int:
        """Queue commands for the server without waiting; returns how many were sent."""
        count = 0
        for command in commands:
            self._socket.send_multipart([b"", *command.frames()])
            count += 1
        self._pending += count
        return count

    def _collect(self, timeout_ms: int) -> None:
        while self._pending and self._socket.poll(timeout_ms):
            reply = self._socket.recv_multipart()[-1]
            if reply != b"ok":
                log.warning("meshcat server: %s", reply.decode(errors="replace"))
            self._pending -= 1

    def flush(self, timeout_s: float | None = None) -> None:
        """Wait until the server has handled every command sent.

        Raises:
            SimnavError: replies still missing after the timeout (the server is gone or stuck).
        """
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while self._pending and time.monotonic() < deadline:
            self._collect(int(max(deadline - time.monotonic(), 0.0) * 1000) + 1)
        if self._pending:
            raise SimnavError(f"meshcat: the server at {self.zmq_url} did not confirm {self._pending} commands")

    def scene_html(self) -> str:
        """The server's current scene (and animation) as one self-contained HTML page (meshcat's static HTML)."""
        self.flush()
        return self._request(b"get_scene").decode()

    def close(self) -> None:
        """Close the socket (unsent commands are dropped)."""
        self._socket.close(linger=0)

    def __enter__(self) -> MeshcatConnection:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextlib.contextmanager
def meshcat_connection(url: str | None = None, timeout_s: float = 20.0) -> Iterator[MeshcatConnection]:
    """A connection to the meshcat server at ``url`` (a ZMQ URL), or to a new server that stops on exit.

    The server and the socket are closed however the block ends (also on an exception or Ctrl-C).
    """
    with contextlib.ExitStack() as stack:
        if url is None:
            url = stack.enter_context(MeshcatServer(timeout_s)).zmq_url
        yield stack.enter_context(MeshcatConnection(url, timeout_s))
