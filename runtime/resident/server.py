"""The resident render server: one process per user that runs ``pfn-render`` jobs with numba's kernels loaded.

:meth:`ResidentServer.bind` takes the folder's lock (one server per folder; a socket left by a killed server is
replaced) and listens on the Unix socket (mode 0600, in the 0700 folder of
:mod:`photon_fields.runtime.resident.paths`). :meth:`ResidentServer.serve` then runs in the main thread: it warms
the kernels (:mod:`photon_fields.runtime.resident.warmup`) and runs the queued jobs one at a time
(:func:`photon_fields.runtime.resident.job.run_job`), until it is stopped, idle for ``idle_minutes``, or finds that
the installed code changed under it.

A thread accepts connections and one thread per connection reads its request
(:mod:`photon_fields.runtime.resident.protocol`): it refuses a peer of another uid (``SO_PEERCRED``), answers a
malformed request with one ``error`` line and serves on, answers ``status`` and ``stop`` at once, and queues a
``render`` request whose code fingerprint and process environment equal the server's
(:mod:`photon_fields.runtime.resident.fingerprint`), answering ``incompatible`` otherwise (the client then renders
in-process). A client waiting in the queue that has left is skipped.

While a job runs a thread watches its connection: the client sends nothing after its request, so the end of its
side (Ctrl-C, or a client killed) interrupts the job with KeyboardInterrupt, as Ctrl-C interrupts an in-process
render (its files are written atomically, so nothing half-written is left). SIGTERM or SIGINT stop the server after
the job in progress; a second one interrupts that job too.
"""

from __future__ import annotations

import _thread
import contextlib
import fcntl
import gc
import os
import queue
import signal
import socket
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from typing import IO, Any

from photon_fields.runtime.eval.machine import resident_memory_mb
from photon_fields.runtime.resident.fingerprint import code_fingerprint, is_job_variable, process_environment
from photon_fields.runtime.resident.job import TerminalStandIn, run_job
from photon_fields.runtime.resident.paths import ResidentPaths
from photon_fields.runtime.resident.protocol import (
    ProtocolError,
    ProtocolMismatchError,
    check_request,
    peer_uid,
    receive,
    send,
)

#: Connections read at once (beyond: refused in one line), jobs waiting (beyond: the client renders in-process),
#: seconds a client has to send its request.
MAX_CONNECTIONS = 32
MAX_QUEUED = 32
REQUEST_TIMEOUT_S = 10.0
#: How often the accepting thread and the main loop look at the stop flag and the idle clock.
POLL_S = 0.25


class AlreadyRunningError(Exception):
    """Another server holds the folder's lock."""


class Job:
    """A queued render request and its connection."""

    __slots__ = ("conn", "request", "number")

    def __init__(self, conn: socket.socket, request: dict[str, Any], number: int) -> None:
        self.conn, self.request, self.number = conn, request, number


class _Sender:
    """Sends messages on a job's connection; once one fails the rest are dropped (the job runs on unheard until
    the watcher interrupts it)."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn, self.alive = conn, True

    def __call__(self, message: dict[str, Any]) -> bool:
        if self.alive:
            try:
                send(self.conn, message)
            except (OSError, ProtocolError):
                self.alive = False
        return self.alive


def _rss_mb() -> float:
    """This process's resident memory (MB; 0 where /proc is missing)."""
    rss = resident_memory_mb()
    return 0.0 if rss is None else round(rss, 1)


def _client_left(conn: socket.socket) -> bool:
    """Whether a queued client has closed its side (it sends nothing after its request)."""
    try:
        conn.setblocking(False)
        try:
            return conn.recv(1, socket.MSG_PEEK) == b""
        finally:
            conn.setblocking(True)
    except BlockingIOError:
        return False
    except OSError:
        return True


def _close(conn: socket.socket) -> None:
    with contextlib.suppress(OSError):
        conn.shutdown(socket.SHUT_RDWR)  # wakes a watcher blocked in recv
    conn.close()


class ResidentServer:
    """The server of one folder (module docstring). ``log``: where its own lines go (default stderr: the daemon's
    is its log file, ``log_path``, which ``status`` reports)."""

    def __init__(self, paths: ResidentPaths, *, idle_minutes: float, warm_up: bool = True,
                 log: IO[str] | None = None, log_path: str | None = None) -> None:
        self.paths, self.idle_minutes, self.warm_up_enabled = paths, float(idle_minutes), warm_up
        self._log_stream = log if log is not None else sys.stderr
        self.log_path = log_path
        self.code = code_fingerprint()
        self.process_env = process_environment()
        self.pid = os.getpid()
        self.started_at, self._t0 = time.time(), time.monotonic()
        self.jobs = 0
        self.busy = False
        self.warm_state = "pending" if warm_up else "off"
        self._queue: queue.Queue[Job] = queue.Queue()
        self._numbers = iter(range(1, 1 << 62))
        self._stopping: str | None = None
        self._last_active = time.monotonic()
        self._listener: socket.socket | None = None
        self._socket_inode: int | None = None
        self._lock_fd: int | None = None
        self._connections = threading.BoundedSemaphore(MAX_CONNECTIONS)
        # The job the client-left watcher may interrupt, and the job it asked to interrupt (see _on_interrupt).
        self._interruptible_job: int | None = None
        self._interrupt_for: int | None = None
        self._terminals: tuple[TerminalStandIn | None, TerminalStandIn | None] = (None, None)

    # ------------------------------------------------------------------------------------------------------
    # life cycle

    def log(self, text: str) -> None:
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        try:
            self._log_stream.write(f"{stamp} pfn-resident[{self.pid}]: {text}\n")
            self._log_stream.flush()
        except (OSError, ValueError):
            pass

    def bind(self) -> None:
        """Take the folder's lock and listen on its socket (replacing a stale one); :class:`AlreadyRunningError` when
        another server holds the lock, OSError when the socket cannot be made."""
        fd = os.open(self.paths.lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise AlreadyRunningError(f"another resident server holds {self.paths.lock}") from None
        self._lock_fd = fd
        os.ftruncate(fd, 0)
        os.write(fd, f"{self.pid}\n".encode())
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.paths.socket)  # stale: its server no longer holds the lock
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        previous = os.umask(0o177)
        try:
            listener.bind(self.paths.socket)
        except OSError:
            listener.close()
            raise
        finally:
            os.umask(previous)
        os.chmod(self.paths.socket, 0o600)
        listener.listen(MAX_CONNECTIONS)
        listener.settimeout(POLL_S)
        self._listener = listener
        self._socket_inode = os.stat(self.paths.socket).st_ino

    def stop(self, reason: str) -> None:
        """Stop after the job in progress (queued jobs are dropped: their clients render in-process)."""
        if self._stopping is None:
            self._stopping = reason
            self.log(f"stopping: {reason}")

    def serve(self) -> int:
        """Warm up, then run jobs until stopped (module docstring); must run in the main thread. Returns 0."""
        if self._listener is None:
            raise RuntimeError("bind() first")
        signal.signal(signal.SIGUSR1, self._on_interrupt)
        signal.signal(signal.SIGTERM, self._on_terminate)
        signal.signal(signal.SIGINT, self._on_terminate)
        self._terminals = (TerminalStandIn.make(), TerminalStandIn.make())
        acceptor = threading.Thread(target=self._accept_loop, name="pfn-resident-accept", daemon=True)
        acceptor.start()
        self.log(f"serving on {self.paths.socket}; code {self.code}; exits after {self.idle_minutes:g} min without "
                 "jobs")
        try:
            if self.warm_up_enabled:
                self._warm_up()
            while self._stopping is None:
                try:
                    job = self._queue.get(timeout=POLL_S)
                except queue.Empty:
                    if time.monotonic() - self._last_active > self.idle_minutes * 60:
                        self.stop(f"no job for {self.idle_minutes:g} min")
                    continue
                self._run(job)
        except KeyboardInterrupt:  # a second SIGTERM / SIGINT outside a job
            self.stop("interrupted")
        finally:
            self._shutdown()
            acceptor.join(timeout=2 * POLL_S + 1)
        return 0

    def _shutdown(self) -> None:
        if self._stopping is None:
            self._stopping = "ended"
        # The socket first, so that new clients find no server (and render in-process) at once.
        with contextlib.suppress(OSError):
            if os.stat(self.paths.socket).st_ino == self._socket_inode:
                os.unlink(self.paths.socket)
        if self._listener is not None:
            self._listener.close()
        while True:
            try:
                _close(self._queue.get_nowait().conn)
            except queue.Empty:
                break
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
        self.log(f"stopped after {self.jobs} jobs ({self._stopping})")

    def _on_terminate(self, signum: int, frame: Any) -> None:
        if self._stopping is None:
            # Not stop(): no log line from a signal handler, which may run inside a write to the same log. The
            # reason is logged when the server stops.
            self._stopping = f"signal {signal.Signals(signum).name}"
            return
        raise KeyboardInterrupt  # a second one: interrupt the job in progress (or the warm-up) too

    def _on_interrupt(self, signum: int, frame: Any) -> None:
        job = self._interruptible_job
        if job is not None and job == self._interrupt_for:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def _interruptible(self, number: int) -> Iterator[None]:
        self._interruptible_job = number
        try:
            yield
        finally:
            self._interruptible_job = None

    def _warm_up(self) -> None:
        from photon_fields.runtime.resident.warmup import warm_up

        self.warm_state = "running"
        t0 = time.perf_counter()
        try:
            done = warm_up()
        except Exception as exc:  # a failed warm-up costs the first jobs time, nothing else: serve on
            self.warm_state = f"failed: {' '.join(str(exc).split()) or type(exc).__name__}"
            self.log(f"warm-up failed:\n{traceback.format_exc()}")
        else:
            self.warm_state = f"done in {time.perf_counter() - t0:.1f} s ({', '.join(done)})"
            self.log(f"warm-up {self.warm_state}")
        self._last_active = time.monotonic()

    # ------------------------------------------------------------------------------------------------------
    # connections

    def _accept_loop(self) -> None:
        assert self._listener is not None
        while self._stopping is None:
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                if self._stopping is None:
                    time.sleep(POLL_S)
                continue
            if not self._connections.acquire(blocking=False):
                self._refuse(conn, "error", f"busy: {MAX_CONNECTIONS} connections are open")
                continue
            try:
                threading.Thread(target=self._handle, args=(conn,), name="pfn-resident-request", daemon=True).start()
            except RuntimeError:
                self._connections.release()
                _close(conn)

    def _refuse(self, conn: socket.socket, kind: str, problem: str) -> None:
        with contextlib.suppress(OSError, ProtocolError):
            conn.settimeout(1.0)
            send(conn, {"type": kind, "problem": problem})
        _close(conn)

    def _handle(self, conn: socket.socket) -> None:
        """Read one request and answer it (module docstring)."""
        queued = False
        try:
            conn.settimeout(REQUEST_TIMEOUT_S)
            if peer_uid(conn) != os.getuid():
                self.log("refused a connection from another user")
                self._refuse(conn, "error", "refused: this server serves only its own user")
                return
            try:
                data = receive(conn)
                if data is None:
                    return
                kind = check_request(data)
            except ProtocolMismatchError as exc:
                self._refuse(conn, "incompatible", exc.problem)
                return
            except ProtocolError as exc:
                self.log(f"refused a request: {exc.problem}")
                self._refuse(conn, "error", f"request refused: {exc.problem}")
                return
            if kind == "status":
                send(conn, {"type": "status", **self.status()})
            elif kind == "stop":
                send(conn, {"type": "stopping", "pid": self.pid, "busy": self.busy})
                self.stop("a stop request")
            else:
                queued = self._queue_job(conn, data)
        except OSError:
            pass  # the client left or timed out
        finally:
            self._connections.release()
            if not queued:
                _close(conn)

    def _queue_job(self, conn: socket.socket, request: dict[str, Any]) -> bool:
        """Queue a render request the server can run as the client would; answer otherwise. Whether queued."""
        problem = self._incompatibility(request)
        if problem is not None:
            send(conn, {"type": "incompatible", "problem": problem})
            return False
        foreign = sorted(k for k in request["job_env"] if not is_job_variable(k))
        if foreign:
            send(conn, {"type": "error", "problem": f"request refused: 'job_env' holds {', '.join(foreign[:5])}, "
                        "which are not per-job variables"})
            return False
        ahead = self._queue.qsize() + (1 if self.busy else 0)
        if self._stopping is not None or ahead >= MAX_QUEUED:
            why = "the server is stopping" if self._stopping is not None else f"{ahead} jobs are waiting"
            send(conn, {"type": "incompatible", "problem": why})
            return False
        conn.settimeout(None)
        send(conn, {"type": "accepted", "pid": self.pid, "ahead": ahead})
        self._last_active = time.monotonic()
        self._queue.put(Job(conn, request, next(self._numbers)))
        return True

    def _incompatibility(self, request: dict[str, Any]) -> str | None:
        """Why this server cannot run ``request`` as its client would, or None."""
        if request["code"] != self.code:
            if code_fingerprint() != self.code:
                self.stop("the installed code changed since the server started")
            return "another code fingerprint: the code or the installed packages differ from the server's"
        theirs, ours = request["process_env"], self.process_env
        if theirs != ours:
            names = sorted(k for k in {*theirs, *ours} if theirs.get(k) != ours.get(k))
            return f"the environment differs in {', '.join(names[:8])}"
        return None

    def status(self) -> dict[str, Any]:
        """What ``pfn-resident status`` shows (:data:`photon_fields.runtime.resident.protocol.STATUS_KEYS`)."""
        return {"pid": self.pid, "started_at": self.started_at, "uptime_s": round(time.monotonic() - self._t0, 3),
                "jobs": self.jobs, "busy": self.busy, "queued": self._queue.qsize(), "warm_up": self.warm_state,
                "idle_minutes": self.idle_minutes, "code": self.code, "process_env": self.process_env,
                "socket": self.paths.socket, "log": self.log_path, "rss_mb": _rss_mb(),
                "python": sys.version.split()[0]}

    # ------------------------------------------------------------------------------------------------------
    # jobs

    def _render_main(self) -> Callable[[list[str]], int]:
        from photon_fields.runtime.cli.render import _main

        return _main

    def _run(self, job: Job) -> None:
        """Run one queued job in this (the main) thread and send its exit status."""
        conn, request = job.conn, job.request
        if _client_left(conn):
            _close(conn)
            return
        sender = _Sender(conn)
        if not os.path.isdir(request["cwd"]):  # closed unstarted: the client renders in-process, where it shows
            _close(conn)
            return
        if not sender({"type": "started"}):
            _close(conn)
            return
        self.busy = True
        watcher = threading.Thread(target=self._watch, args=(conn, job.number), name="pfn-resident-watch",
                                   daemon=True)
        watcher.start()
        t0 = time.perf_counter()
        try:
            status = run_job(request, sender, self._render_main(), lambda: self._interruptible(job.number),
                             self._terminals)
        except Exception as exc:  # the job's set-up failed (e.g. its folder vanished): the client hears one line
            sender({"type": "stderr", "text": f"error: resident render server: {exc}\n"})
            status = 1
            self.log(f"job {job.number} failed to start:\n{traceback.format_exc()}")
        finally:
            self.busy = False
        sender({"type": "exit", "status": status})
        _close(conn)
        self.jobs += 1
        self._last_active = time.monotonic()
        self.log(f"job {job.number}: pfn-render {' '.join(request['argv'])} (in {request['cwd']}): exit {status} in "
                 f"{time.perf_counter() - t0:.2f} s")
        gc.collect()

    def _watch(self, conn: socket.socket, number: int) -> None:
        """Interrupt job ``number`` when its client closes its side of the connection (module docstring)."""
        with contextlib.suppress(OSError):
            conn.recv(1)
        if self._interruptible_job == number:
            self._interrupt_for = number
            _thread.interrupt_main(signal.SIGUSR1)
