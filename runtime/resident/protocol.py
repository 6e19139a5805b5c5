"""The resident server's wire format: length-prefixed JSON messages over a Unix socket, checked strictly.

A message is a 4-byte big-endian length and that many bytes of UTF-8 JSON holding one object. Either side refuses
(:class:`ProtocolError`, one line) a length over :data:`MAX_MESSAGE_BYTES`, bytes that are not UTF-8 JSON, NaN or
infinities, a key given twice, a value of the wrong type, and any key its schema does not list (a misspelt key must
not fall back to a default). The server answers a refused request with an ``error`` message and keeps serving.

A client sends one request per connection (every key required; ``protocol`` is :data:`PROTOCOL`, and a request of
another protocol is answered ``incompatible``):

- ``{"request": "render", "protocol", "argv": [str], "cwd": absolute path, "umask": int, "stdout_isatty": bool,
  "stdout_encoding": str, "stdout_size": [columns, lines] or null, the same three for stderr, "code": the code
  fingerprint, "process_env": {name: value}, "job_env": {name: value}}``
  (:mod:`photon_fields.runtime.resident.fingerprint` says which variables go where); ``stdout_size``: the size of
  the terminal on the client's stdout, null when it is not one;
- ``{"request": "status", "protocol"}``, ``{"request": "stop", "protocol"}``.

The server answers a render request with:

- ``{"type": "accepted", "pid": int, "ahead": int}`` at once (``ahead``: jobs before it), or ``{"type":
  "incompatible", "problem": str}`` (another protocol, code or environment: the client renders in-process), or
  ``{"type": "error", "problem": str}`` (a refused request);
- ``{"type": "started"}`` when the job runs (jobs run one at a time; a client waits its turn);
- ``{"type": "stdout" | "stderr", "text": str}``: the job's output, in the order it was written;
- ``{"type": "exit", "status": int}``: the job's exit status, the last message.

After its request the client sends nothing; closing its side of the connection (Ctrl-C) interrupts the job, as
Ctrl-C interrupts an in-process render. ``status`` is answered with ``{"type": "status", ...}``
(:data:`STATUS_KEYS`) and ``stop`` with ``{"type": "stopping", "pid": int, "busy": bool}``.

Standard library only: ``pfn-render`` speaks it before numpy or numba are imported.
"""

from __future__ import annotations

import json
import math
import socket
import struct
from collections.abc import Callable
from typing import Any

PROTOCOL = 1
#: The largest message either side accepts (bytes of JSON). A render request is well under 64 KiB; output is
#: sent in pieces of at most :data:`TEXT_PIECE` characters.
MAX_MESSAGE_BYTES = 1 << 20
TEXT_PIECE = 1 << 15
#: The most command-line arguments, and environment variables of each kind, a request may carry.
MAX_ITEMS = 4096


class ProtocolError(ValueError):
    """A refused message; ``str(err)`` is one line saying what was wrong."""

    def __init__(self, problem: str) -> None:
        self.problem = " ".join(str(problem).split())[:400]
        super().__init__(self.problem)


class ProtocolMismatchError(ProtocolError):
    """A request of another protocol version: not refused as malformed, answered ``incompatible``."""


Check = Callable[[str, Any], None]


def _type_name(value: Any) -> str:
    return "null" if value is None else type(value).__name__


def _string(key: str, value: Any) -> None:
    if not isinstance(value, str):
        raise ProtocolError(f"'{key}' must be a string, got {_type_name(value)}")


def _boolean(key: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise ProtocolError(f"'{key}' must be true or false, got {_type_name(value)}")


def _integer(lo: int, hi: int) -> Check:
    def check(key: str, value: Any) -> None:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ProtocolError(f"'{key}' must be an integer, got {_type_name(value)}")
        if not lo <= value <= hi:
            raise ProtocolError(f"'{key}' must be an integer in [{lo}, {hi}]")

    return check


def _number(key: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ProtocolError(f"'{key}' must be a finite number, got {_type_name(value)}")


def _strings(key: str, value: Any) -> None:
    if not isinstance(value, list) or len(value) > MAX_ITEMS or not all(isinstance(v, str) for v in value):
        raise ProtocolError(f"'{key}' must be a list of at most {MAX_ITEMS} strings")


def _variables(key: str, value: Any) -> None:
    if (not isinstance(value, dict) or len(value) > MAX_ITEMS
            or not all(isinstance(k, str) and k and "=" not in k and "\0" not in k and isinstance(v, str)
                       and "\0" not in v for k, v in value.items())):
        raise ProtocolError(f"'{key}' must be an object of environment variables (name: string value)")


def _absolute_path(key: str, value: Any) -> None:
    _string(key, value)
    if not value.startswith("/") or "\0" in value:
        raise ProtocolError(f"'{key}' must be an absolute path")


def _terminal_size(key: str, value: Any) -> None:
    if value is None:
        return
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 0xFFFF for v in value)):
        raise ProtocolError(f"'{key}' must be null or [columns, lines], two integers in [1, 65535]")


def _optional_string(key: str, value: Any) -> None:
    if value is not None:
        _string(key, value)


_PROTOCOL = {"protocol": _integer(0, 1 << 31)}
#: Requests a client sends, by ``request``: every key required.
REQUESTS: dict[str, dict[str, Check]] = {
    "render": {**_PROTOCOL, "argv": _strings, "cwd": _absolute_path, "umask": _integer(0, 0o777),
               "stdout_isatty": _boolean, "stdout_encoding": _string, "stdout_size": _terminal_size,
               "stderr_isatty": _boolean, "stderr_encoding": _string, "stderr_size": _terminal_size,
               "code": _string, "process_env": _variables, "job_env": _variables},
    "status": dict(_PROTOCOL),
    "stop": dict(_PROTOCOL),
}
#: What ``status`` reports (:meth:`photon_fields.runtime.resident.server.ResidentServer.status`).
STATUS_KEYS: dict[str, Check] = {
    "pid": _integer(1, 1 << 31), "started_at": _number, "uptime_s": _number, "jobs": _integer(0, 1 << 62),
    "busy": _boolean, "queued": _integer(0, 1 << 31), "warm_up": _string, "idle_minutes": _number,
    "code": _string, "process_env": _variables, "socket": _string, "log": _optional_string,
    "rss_mb": _number, "python": _string,
}
#: Replies the server sends, by ``type``: every key required.
REPLIES: dict[str, dict[str, Check]] = {
    "accepted": {"pid": _integer(1, 1 << 31), "ahead": _integer(0, 1 << 31)},
    "incompatible": {"problem": _string},
    "error": {"problem": _string},
    "started": {},
    "stdout": {"text": _string},
    "stderr": {"text": _string},
    "exit": {"status": _integer(-(1 << 31), 1 << 31)},
    "status": STATUS_KEYS,
    "stopping": {"pid": _integer(1, 1 << 31), "busy": _boolean},
}


def _check_keys(data: dict[str, Any], schema: dict[str, Check], what: str) -> None:
    unknown = [k for k in data if k not in schema]
    if unknown:
        raise ProtocolError(f"{what}: unknown key{'s' if len(unknown) > 1 else ''} "
                            f"{', '.join(repr(k[:40]) for k in unknown[:5])}; allowed: {', '.join(sorted(schema))}")
    missing = [k for k in schema if k not in data]
    if missing:
        raise ProtocolError(f"{what}: missing {', '.join(repr(k) for k in missing)}")
    for key, check in schema.items():
        check(key, data[key])


def _tagged(data: Any, tag: str, schemas: dict[str, dict[str, Check]], what: str, known: bool) -> str:
    """The ``tag`` value of a message ``data`` valid under ``schemas`` (by that value); ``what``: "request" or "reply
    type" for the errors, ``known``: whether an unknown value's error lists the known ones."""
    if not isinstance(data, dict):
        raise ProtocolError(f"a {what.split()[0]} must be a JSON object, got {_type_name(data)}")
    kind = data.get(tag)
    if not isinstance(kind, str) or kind not in schemas:
        shown = repr(kind[:40]) if isinstance(kind, str) else _type_name(kind)
        raise ProtocolError(f"unknown {what} {shown}" + (f"; known: {', '.join(schemas)}" if known else ""))
    _check_keys({k: v for k, v in data.items() if k != tag}, schemas[kind], f"{what.split()[0]} {kind!r}")
    return kind


def check_request(data: Any) -> str:
    """The kind of a valid request (``render``, ``status``, ``stop``); :class:`ProtocolMismatchError` for another
    protocol, :class:`ProtocolError` for anything else wrong (module docstring)."""
    if isinstance(data, dict) and "protocol" in data and data["protocol"] != PROTOCOL:
        raise ProtocolMismatchError(f"protocol {data['protocol']!r}; this server speaks {PROTOCOL}")
    return _tagged(data, "request", REQUESTS, "request", known=True)


def check_reply(data: Any) -> str:
    """The type of a valid server message; :class:`ProtocolError` otherwise."""
    return _tagged(data, "type", REPLIES, "reply type", known=False)


# ----------------------------------------------------------------------------------------------------------
# framing


def encode(message: dict[str, Any]) -> bytes:
    """The length-prefixed bytes of ``message``."""
    # ASCII JSON: text that holds lone surrogates (undecodable file names) travels as JSON escapes.
    data = json.dumps(message, separators=(",", ":"), allow_nan=False).encode("ascii")
    if len(data) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message of {len(data)} bytes is larger than the {MAX_MESSAGE_BYTES} allowed")
    return len(data).to_bytes(4, "big") + data


def send(sock: socket.socket, message: dict[str, Any]) -> None:
    sock.sendall(encode(message))


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    chunks, got = [], 0
    while got < n:
        chunk = sock.recv(min(n - got, 1 << 16))
        if not chunk:
            break
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def _reject_constant(name: str) -> None:
    raise ProtocolError(f"not JSON: {name} is not a number JSON allows")


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ProtocolError(f"key {key[:40]!r} given twice")
        out[key] = value
    return out


def decode(data: bytes) -> Any:
    """The JSON value of a message body; :class:`ProtocolError` for anything that is not strict UTF-8 JSON."""
    try:
        return json.loads(data.decode("utf-8"), parse_constant=_reject_constant, object_pairs_hook=_no_duplicates)
    except ProtocolError:
        raise
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ProtocolError(f"not UTF-8 JSON: {exc}") from None


def receive(sock: socket.socket) -> Any:
    """The next message's JSON value; None when the peer closed the connection before a message began;
    :class:`ConnectionError` when it closed in the middle of one, :class:`ProtocolError` when it is malformed or
    longer than :data:`MAX_MESSAGE_BYTES` (its body is then not read)."""
    header = _recv_exact(sock, 4)
    if not header:
        return None
    if len(header) < 4:
        raise ConnectionError("the connection closed in the middle of a message")
    size = int.from_bytes(header, "big")
    if size > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message of {size} bytes is larger than the {MAX_MESSAGE_BYTES} allowed")
    body = _recv_exact(sock, size)
    if len(body) < size:
        raise ConnectionError("the connection closed in the middle of a message")
    return decode(body)


def text_pieces(text: str) -> list[str]:
    """``text`` cut into pieces that each fit a message (:data:`TEXT_PIECE` characters)."""
    return [text[i:i + TEXT_PIECE] for i in range(0, len(text), TEXT_PIECE)] if text else []


def peer_uid(sock: socket.socket) -> int | None:
    """The uid of the process at the other end of a connected Unix socket (Linux ``SO_PEERCRED``); None where the
    system cannot say, which both sides treat as a stranger."""
    option = getattr(socket, "SO_PEERCRED", None)
    if option is None:
        return None
    try:
        _pid, uid, _gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i")))
    except OSError:
        return None
    return uid
