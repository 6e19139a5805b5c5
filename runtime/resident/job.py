"""One ``pfn-render`` job inside the resident server, run as a fresh process would run it.

The server calls ``pfn-render``'s own main (:func:`photon_fields.runtime.cli.render._main`) with the client's argv,
in the client's folder, with its umask and its per-job environment variables
(:func:`photon_fields.runtime.resident.fingerprint.job_environment`), and with ``sys.stdout`` and ``sys.stderr``
(and ``sys.__stdout__``, ``sys.__stderr__``) replaced by :class:`ForwardedStream` s, which send every write to the
client and answer ``isatty()`` and ``encoding`` as the client's own streams do: progress is a tqdm bar on the
client's terminal and plain lines in its log, as in-process (runtime/progress.py). Where the client's stream is a
terminal, the stream's ``fileno()`` is a pseudo-terminal of the same size (:class:`TerminalStandIn`), so that tqdm
and ``shutil.get_terminal_size`` (the width of ``--help``) measure the client's terminal; where it is not, ``fileno()``
is unsupported, as for any stream that is not a file. Bytes written to that descriptor directly, bypassing the
stream, are discarded.

What a process would start afresh is reset around the job: the warnings registry (a warning shown once per
process is shown once per job), numba's thread count (``--threads`` sets it for the rest of a process),
``sys.argv``, the folder, umask and environment. What it keeps is the point of the server: numba's loaded kernels,
the imported modules, the cached builtin volumes (runtime/scene/scene.py).

The exit status follows the in-process conventions: ``_main``'s own (0; 2 for bad input, with one ``error:`` line;
130 for an interrupt), ``SystemExit``'s code (``--help``), and 1 with the traceback on stderr for an unexpected
exception, as Python reports an uncaught one; the server keeps serving after any of them.
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import os
import struct
import sys
import termios
import threading
import traceback
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager
from typing import Any

from photon_fields.runtime.resident.fingerprint import is_job_variable
from photon_fields.runtime.resident.protocol import text_pieces

#: Sends one message to the client; False once the connection failed (the job then runs on, unheard).
Send = Callable[[dict[str, Any]], bool]


class TerminalStandIn:
    """A pseudo-terminal given the size of a client's terminal, for :meth:`ForwardedStream.fileno` (module
    docstring). A thread reads and discards what is written to it directly, so such a write never blocks."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        os.set_inheritable(self.master, False)
        os.set_inheritable(self.slave, False)
        threading.Thread(target=self._drain, name="pfn-resident-terminal", daemon=True).start()

    def _drain(self) -> None:
        with contextlib.suppress(OSError):
            while os.read(self.master, 1 << 16):
                pass

    def resize(self, size: Sequence[int]) -> None:
        """Columns and lines, as the client's terminal has them."""
        fcntl.ioctl(self.master, termios.TIOCSWINSZ, struct.pack("HHHH", size[1], size[0], 0, 0))

    @classmethod
    def make(cls) -> TerminalStandIn | None:
        """One, or None where this system has no pseudo-terminals (streams then have no ``fileno()``)."""
        try:
            return cls()
        except OSError:
            return None


class ForwardedStream(io.TextIOBase):
    """A text stream whose writes go to the client as ``stdout`` or ``stderr`` messages (module docstring)."""

    def __init__(self, kind: str, send: Send, *, isatty: bool, encoding: str,
                 terminal: TerminalStandIn | None = None) -> None:
        super().__init__()
        self._kind, self._send, self._isatty, self._encoding = kind, send, isatty, encoding
        self._terminal = terminal if isatty else None
        self._open = True

    def write(self, text: str) -> int:
        if not isinstance(text, str):
            raise TypeError(f"write() argument must be str, not {type(text).__name__}")
        if self._open:
            for piece in text_pieces(text):
                self._send({"type": self._kind, "text": piece})
        return len(text)

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return self._isatty

    def fileno(self) -> int:
        if self._terminal is None:
            raise io.UnsupportedOperation("fileno")
        return self._terminal.slave

    def flush(self) -> None:
        pass  # every write is sent at once

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return self._encoding

    @property
    def errors(self) -> str:  # type: ignore[override]
        return "strict"

    def end(self) -> None:
        """The job is over: later writes (a late tqdm close) go nowhere."""
        self._open = False


@contextlib.contextmanager
def _environment(job_env: dict[str, str]) -> Iterator[None]:
    """The process's per-job variables replaced by the client's for the duration."""
    saved = {k: v for k, v in os.environ.items() if is_job_variable(k)}
    try:
        for k in saved:
            del os.environ[k]
        os.environ.update(job_env)
        yield
    finally:
        for k in [k for k in os.environ if is_job_variable(k)]:
            del os.environ[k]
        os.environ.update(saved)


@contextlib.contextmanager
def _standard_streams(out: ForwardedStream, err: ForwardedStream) -> Iterator[None]:
    saved = sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__
    sys.stdout = sys.__stdout__ = out  # type: ignore[misc]
    sys.stderr = sys.__stderr__ = err  # type: ignore[misc]
    try:
        yield
    finally:
        sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__ = saved  # type: ignore[misc]


@contextlib.contextmanager
def _folder_and_umask(cwd: str, umask: int) -> Iterator[None]:
    home = os.getcwd()
    os.chdir(cwd)
    previous = os.umask(umask)
    try:
        yield
    finally:
        os.umask(previous)
        os.chdir(home)


def exit_status(code: Any) -> int:
    """The status a process exits with for ``SystemExit(code)`` (a message is printed and gives 1)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    print(code, file=sys.stderr)
    return 1


def reset_threads() -> None:
    """numba's worker threads back to all of them (``pfn-render --threads`` changed them for the process)."""
    numba = sys.modules.get("numba")
    if numba is not None:
        numba.set_num_threads(int(numba.config.NUMBA_NUM_THREADS))


def _stream(kind: str, request: dict[str, Any], send: Send, terminal: TerminalStandIn | None) -> ForwardedStream:
    isatty, size = request[f"{kind}_isatty"], request[f"{kind}_size"]
    if terminal is not None and isatty and size is not None:
        terminal.resize(size)
    else:
        terminal = None
    return ForwardedStream(kind, send, isatty=isatty, encoding=request[f"{kind}_encoding"], terminal=terminal)


def run_job(request: dict[str, Any], send: Send, render_main: Callable[[list[str]], int],
            interruptible: Callable[[], AbstractContextManager[None]],
            terminals: tuple[TerminalStandIn | None, TerminalStandIn | None] = (None, None)) -> int:
    """Run ``render_main(request["argv"])`` as the client's process would (module docstring) and return its exit
    status. ``interruptible()``: the region in which the server may raise KeyboardInterrupt (the client left);
    ``terminals``: the stand-ins for the client's stdout and stderr terminals."""
    out = _stream("stdout", request, send, terminals[0])
    err = _stream("stderr", request, send, terminals[1])
    argv = list(request["argv"])
    saved_argv = sys.argv
    try:
        with (_folder_and_umask(request["cwd"], request["umask"]), _environment(request["job_env"]),
              _standard_streams(out, err), warnings.catch_warnings()):
            sys.argv = ["pfn-render", *argv]
            try:
                with interruptible():
                    status = render_main(argv)
            except SystemExit as exc:
                status = exit_status(exc.code)
            except KeyboardInterrupt:  # after render's own handler (guarded) had returned: still an interrupt
                print("error: interrupted", file=sys.stderr)
                status = 130
            except BaseException:  # what Python prints for an uncaught exception; the server serves on
                traceback.print_exc()
                status = 1
    finally:
        sys.argv = saved_argv
        out.end()
        err.end()
        reset_threads()
    return status
