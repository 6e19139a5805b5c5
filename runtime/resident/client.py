"""``pfn-render``'s side of the resident server: hand the command line to a running server, or say that none can
take it, in a few milliseconds.

:func:`render_through_server` connects to this user's server (:mod:`photon_fields.runtime.resident.paths`), checks
that it runs as this user, sends the argv, the folder, the umask, whether stdout and stderr are terminals (and
their encodings and sizes), the code fingerprint and the environment
(:mod:`photon_fields.runtime.resident.fingerprint`), then writes the job's output to this process's stdout and
stderr as it comes and returns the job's exit status. It returns None, having printed nothing, whenever no server
can take the job: no folder, no socket, a stale socket, a refused connection, a server of another user, another
protocol, code or environment, a malformed reply, or a server that stops before the job starts; the caller then
renders in its own process, exactly as without a server. Once the job has started there is no way back: a server
that dies then is reported in one line naming ``--no-resident`` (exit status 1).

Ctrl-C while the job runs closes this side of the connection, which interrupts the job in the server as Ctrl-C
interrupts an in-process render (``error: interrupted``, exit status 130); a second Ctrl-C leaves at once.

Standard library only, imported before numpy or numba (``python -X importtime``, tests/runtime/cli/test_resident.py).
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
from collections.abc import Mapping
from typing import IO, Any

from photon_fields.runtime.resident.fingerprint import code_fingerprint, job_environment, process_environment
from photon_fields.runtime.resident.paths import ResidentDirError, ResidentPaths, resident_paths
from photon_fields.runtime.resident.protocol import PROTOCOL, ProtocolError, check_reply, peer_uid, receive, send

#: Seconds to wait for a connection and the server's first answer (it answers at once; a server that does not is
#: not used), and for the end of an interrupted job.
ANSWER_TIMEOUT_S = 10.0
INTERRUPT_WAIT_S = 10.0


def connect(paths: ResidentPaths, timeout: float = ANSWER_TIMEOUT_S) -> socket.socket | None:
    """A connection to the server in ``paths`` run by this user, or None (no socket, stale, refused, a stranger)."""
    if not hasattr(socket, "AF_UNIX"):
        return None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.settimeout(timeout)
        sock.connect(paths.socket)
        if peer_uid(sock) != os.getuid():
            raise ConnectionRefusedError("the socket's server runs as another user")
    except OSError:
        sock.close()
        return None
    return sock


def _isatty(stream: IO[str] | None) -> bool:
    try:
        return stream is not None and stream.isatty()
    except (OSError, ValueError, AttributeError):
        return False


def _stream_facts(name: str, stream: IO[str] | None) -> dict[str, Any]:
    """Whether ``stream`` is a terminal, its encoding and its terminal's size (columns, lines; None if not one)."""
    isatty, size = _isatty(stream), None
    if isatty:
        try:
            columns, lines = os.get_terminal_size(stream.fileno())  # type: ignore[union-attr]
            size = [min(max(columns, 1), 0xFFFF), min(max(lines, 1), 0xFFFF)]
        except (OSError, ValueError, AttributeError):
            size = None
    return {f"{name}_isatty": isatty, f"{name}_encoding": getattr(stream, "encoding", None) or "utf-8",
            f"{name}_size": size}


def render_request(argv: list[str], environ: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The ``render`` request for ``argv`` from this process (:mod:`photon_fields.runtime.resident.protocol`)."""
    mask = os.umask(0)
    os.umask(mask)
    return {"request": "render", "protocol": PROTOCOL, "argv": list(argv), "cwd": os.getcwd(), "umask": mask,
            **_stream_facts("stdout", sys.stdout), **_stream_facts("stderr", sys.stderr), "code": code_fingerprint(),
            "process_env": process_environment(environ), "job_env": job_environment(environ)}


def _reply(sock: socket.socket) -> dict[str, Any] | None:
    """The server's next message, checked; None when it closed the connection."""
    data = receive(sock)
    if data is None:
        return None
    check_reply(data)
    return data


class _Sink:
    """One of this process's output streams; stops writing (and keeps following the job) once it fails, e.g.
    a pipe whose reader left."""

    def __init__(self, stream: IO[str] | None) -> None:
        self.stream = stream

    def write(self, text: str) -> None:
        if self.stream is None:
            return
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):
            self.stream = None


def render_through_server(argv: list[str], environ: Mapping[str, str] | None = None) -> int | None:
    """Run ``pfn-render argv`` on this user's resident server: its exit status, or None (nothing printed) when
    no server can take it (module docstring)."""
    try:
        paths = resident_paths(environ)
    except ResidentDirError:
        return None
    sock = connect(paths)
    if sock is None:
        return None
    try:
        try:
            send(sock, render_request(argv, environ))
            reply = _reply(sock)
        except (OSError, ProtocolError, ImportError):
            return None
        if reply is None or reply["type"] != "accepted":
            return None  # incompatible, refused, or the server is stopping: render in-process
        sock.settimeout(None)  # a job may wait its turn and run for hours
        return _follow(sock, reply["pid"], paths)
    finally:
        sock.close()


def _follow(sock: socket.socket, pid: int, paths: ResidentPaths) -> int | None:
    """Write the job's output here as it comes; its exit status (None: it never started, render in-process)."""
    out, err = _Sink(sys.stdout), _Sink(sys.stderr)
    started = interrupted = False
    while True:
        try:
            status, started = _next(sock, out, err, started)
        except KeyboardInterrupt:
            if started and not interrupted:
                interrupted = True
                _half_close(sock)  # the server interrupts the job; its "error: interrupted" and status follow
                sock.settimeout(INTERRUPT_WAIT_S)
                continue
            err.write("error: interrupted\n")
            return 130
        if isinstance(status, int):
            return status
        if status is None:
            continue
        if not started:
            return None  # the server stopped (or misbehaved) before the job began: nothing happened yet
        if interrupted:
            err.write("error: interrupted\n")
            return 130
        log = f" (its log: {paths.log})" if os.path.exists(paths.log) else ""
        err.write(f"error: resident render server (pid {pid}): {status} during the job{log}; run again, or pass "
                  "--no-resident to render in this process\n")
        return 1


def _next(sock: socket.socket, out: _Sink, err: _Sink, started: bool) -> tuple[int | str | None, bool]:
    """Handle the server's next message: (the exit status, or a problem in words that ends the job, or None to
    read on; whether the job has started)."""
    try:
        reply = _reply(sock)
    except (OSError, ProtocolError) as exc:
        return str(exc) or type(exc).__name__, started
    if reply is None:
        return "the connection closed", started
    kind = reply["type"]
    if kind == "started" and not started:
        return None, True
    if kind in ("stdout", "stderr") and started:
        (out if kind == "stdout" else err).write(reply["text"])
        return None, started
    if kind == "exit" and started:
        return int(reply["status"]), started
    return f"unexpected {kind!r} message", started


def _half_close(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_WR)


def ask(paths: ResidentPaths, request: str, timeout: float = ANSWER_TIMEOUT_S) -> dict[str, Any] | None:
    """Send a ``status`` or ``stop`` request: the server's reply, or None when no server answers; a
    :class:`ProtocolError` when one answers something this client cannot read (another version)."""
    sock = connect(paths, timeout)
    if sock is None:
        return None
    with sock:
        try:
            send(sock, {"request": request, "protocol": PROTOCOL})
            reply = _reply(sock)
        except OSError:
            return None
    if reply is not None and reply["type"] in ("error", "incompatible"):
        raise ProtocolError(f"the server refused the {request} request: {reply['problem']}")
    return reply
