"""``pfn-resident``: start, stop or ask about this user's resident render server (docs/resident.md).

    pfn-resident start                   # in the background; pfn-render hands it its jobs from now on
    pfn-resident start --idle-minutes 60 # exits after an hour without jobs (default 15)
    pfn-resident status                  # pid, uptime, jobs served, memory, code fingerprint, socket
    pfn-resident stop

``start`` spawns the server as a new session (``start --foreground`` serves in this terminal until Ctrl-C), waits
until it listens and returns; it warms the kernels in the background. A server already running with this
installation's code and environment is left as it is; one of another code or environment is replaced. Bad input
is refused in one ``error:`` line with exit status 2; ``status`` exits with 3 when no server runs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from photon_fields.runtime.cli.common import OneLineArgumentParser, guarded
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.resident.client import ask
from photon_fields.runtime.resident.fingerprint import code_fingerprint, process_environment
from photon_fields.runtime.resident.paths import ENV_DIR, ResidentDirError, ResidentPaths, resident_paths
from photon_fields.runtime.resident.protocol import ProtocolError

DEFAULT_IDLE_MINUTES = 15.0
MAX_IDLE_MINUTES = 7 * 24 * 60.0
#: Seconds ``start`` waits for the new server to listen, and ``stop`` for the old one to end.
START_WAIT_S = 60.0
STOP_WAIT_S = 30.0
#: The log is started afresh (the old one kept as ``resident.log.old``) when it grows past this.
MAX_LOG_BYTES = 1 << 20
NOT_RUNNING = 3

TRADE_OFF = """A resident server makes each pfn-render ~1 s faster (numba's start-up is paid once) at the price of a
process that holds its memory while it waits (~250-300 MB with the kernels loaded; status shows it) until it has
had no job for --idle-minutes. It is per user and local: a Unix socket in a folder only you can enter (0700;
$XDG_RUNTIME_DIR/photon-fields, or ~/.cache/photon-fields/resident, or $PFN_RESIDENT_DIR), and it serves only
your uid. pfn-render uses it only when it runs the same code with the same environment (NUMBA_*, OMP_*, PFN_*,
...), else renders in its own process; pfn-render --no-resident always does."""


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="pfn-resident", description="Start, stop or ask about this user's resident "
                              "render server, which runs pfn-render's jobs with numba's kernels loaded "
                              "(docs/resident.md).", epilog=TRADE_OFF,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    start = sub.add_parser("start", help="start the server (in the background; it warms the kernels first)",
                           description="Start this user's resident render server.", epilog=TRADE_OFF,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    start.add_argument("--foreground", action="store_true", help="serve in this process (Ctrl-C stops it) and log "
                       "to stderr, instead of starting a background server that logs to resident.log")
    start.add_argument("--idle-minutes", type=float, default=DEFAULT_IDLE_MINUTES,
                       help=f"exit after this many minutes without a job (default {DEFAULT_IDLE_MINUTES:g}; at most "
                            f"{MAX_IDLE_MINUTES:g}): the server holds its memory while it waits")
    start.add_argument("--no-warm-up", action="store_true",
                       help="do not load the kernels at start (the first job of each renderer loads its own)")
    start.add_argument("--ready-fd", type=int, default=None, help=argparse.SUPPRESS)  # start's own child
    sub.add_parser("stop", help="stop the server (after the job in progress)", description="Stop this user's "
                   "resident render server; the job in progress finishes first.")
    status = sub.add_parser("status", help="is it running: pid, uptime, jobs served, memory, code fingerprint",
                            description="Show this user's resident render server; exit status 3 when none runs.")
    status.add_argument("--json", action="store_true", help="print the server's status as one JSON object")
    return p


def _paths(create: bool) -> ResidentPaths:
    try:
        return resident_paths(create=create)
    except ResidentDirError as err:
        raise InputError("resident folder", f"{err} ({ENV_DIR} sets another)") from None


def _ask(paths: ResidentPaths, request: str) -> dict[str, Any] | None:
    try:
        return ask(paths, request)
    except ProtocolError as err:
        raise InputError(f"resident server ({paths.socket})", str(err)) from None


def compatibility(reply: dict[str, Any]) -> str | None:
    """Why ``pfn-render`` run from here would not use the server of ``reply`` (a status), or None if it would."""
    if reply["code"] != code_fingerprint():
        return "its code differs from this installation's"
    here = process_environment()
    names = sorted(k for k in {*here, *reply["process_env"]} if here.get(k) != reply["process_env"].get(k))
    if names:
        return f"its environment differs from this shell's in {', '.join(names[:8])}"
    return None


def _wait_gone(paths: ResidentPaths, timeout: float) -> bool:
    """Wait until no server answers at ``paths``; whether it went within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not os.path.exists(paths.socket) or ask(paths, "status", timeout=1.0) is None:
            return True
        time.sleep(0.1)
    return False


def start(args: argparse.Namespace) -> int:
    minutes = args.idle_minutes
    if not (math.isfinite(minutes) and 0 < minutes <= MAX_IDLE_MINUTES):
        raise InputError("--idle-minutes", f"must be in (0, {MAX_IDLE_MINUTES:g}] minutes, got {minutes:g}")
    if args.ready_fd is not None and (args.ready_fd < 3 or not args.foreground):
        raise InputError("--ready-fd", "is start's own (a descriptor >= 3, with --foreground)")
    if not hasattr(socket, "AF_UNIX") or not hasattr(socket, "SO_PEERCRED"):
        raise InputError("pfn-resident", "needs Linux (Unix sockets with SO_PEERCRED); pfn-render renders "
                                         "in-process here")
    paths = _paths(create=True)
    running = _ask(paths, "status")
    if running is not None:
        problem = compatibility(running)
        if problem is None:
            print(f"pfn-resident: already running (pid {running['pid']}) on {paths.socket}")
            return 0
        _ask(paths, "stop")
        if not _wait_gone(paths, STOP_WAIT_S):
            raise InputError(f"resident server (pid {running['pid']})", f"{problem} and it did not stop within "
                             f"{STOP_WAIT_S:g} s (a job in progress?); try again later")
        print(f"pfn-resident: stopped the server of pid {running['pid']}: {problem}")
    if args.foreground:
        return serve(paths, args)
    return spawn(paths, args)


def serve(paths: ResidentPaths, args: argparse.Namespace) -> int:
    """``start --foreground``: bind, say so (on stdout, or on ``--ready-fd`` for ``start``), serve until stopped."""
    from photon_fields.runtime.resident.server import AlreadyRunningError, ResidentServer

    server = ResidentServer(paths, idle_minutes=args.idle_minutes, warm_up=not args.no_warm_up,
                            log_path=paths.log if args.ready_fd is not None else None)
    try:
        server.bind()
    except (AlreadyRunningError, OSError) as exc:
        err = InputError(f"resident server ({paths.socket})", f"cannot listen: {exc}")
        _ready(args.ready_fd, f"error: {err}")
        raise err from None
    line = (f"pfn-resident: serving (pid {server.pid}) on {paths.socket}; exits after {args.idle_minutes:g} min "
            "without jobs")
    _ready(args.ready_fd, line)
    return server.serve()


def _ready(fd: int | None, line: str) -> None:
    if fd is None:
        if not line.startswith("error:"):
            print(line, flush=True)
        return
    try:
        os.write(fd, (line + "\n").encode())
    finally:
        os.close(fd)


def spawn(paths: ResidentPaths, args: argparse.Namespace) -> int:
    """``start``: the server as a new session in the background, logging to ``resident.log``; returns once it
    listens (or with its one-line error)."""
    _rotate(paths.log)
    read_end, write_end = os.pipe()
    cmd = [sys.executable, "-m", "photon_fields.runtime.resident.cli", "start", "--foreground",
           "--ready-fd", str(write_end), "--idle-minutes", repr(args.idle_minutes)]
    if args.no_warm_up:
        cmd.append("--no-warm-up")
    fd = os.open(paths.log, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_CLOEXEC, 0o600)
    try:
        # cwd: the private folder, so that nothing importable sits on the server's sys.path[0].
        proc = subprocess.Popen(cmd, cwd=paths.folder, stdin=subprocess.DEVNULL, stdout=fd, stderr=fd,
                                pass_fds=(write_end,), start_new_session=True)
    finally:
        os.close(fd)
        os.close(write_end)
    text = _read_until_closed(read_end, START_WAIT_S).strip()
    if text.startswith("pfn-resident: serving"):
        warm = "" if args.no_warm_up else "; warming the kernels in the background"
        print(f"pfn-resident: started (pid {proc.pid}) on {paths.socket}{warm}; exits after {args.idle_minutes:g} min "
              f"without jobs; log: {paths.log}")
        proc.returncode = 0  # it runs on in its own session: not a child this process waits for
        return 0
    if text.startswith("error: "):
        print(text.splitlines()[0], file=sys.stderr)
        return 2
    raise InputError("resident server", f"did not start within {START_WAIT_S:g} s (see {paths.log})")


def _read_until_closed(fd: int, timeout: float) -> str:
    chunks = []
    deadline = time.monotonic() + timeout
    try:
        while (left := deadline - time.monotonic()) > 0:
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                break
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(fd)
    return b"".join(chunks).decode(errors="replace")


def _rotate(log: str) -> None:
    try:
        if os.path.getsize(log) > MAX_LOG_BYTES:
            os.replace(log, log + ".old")
    except OSError:
        pass


def stop(args: argparse.Namespace) -> int:
    try:
        paths = resident_paths()
    except ResidentDirError:
        print("pfn-resident: not running")
        return 0
    reply = _ask(paths, "stop")
    if reply is None:
        print(f"pfn-resident: not running (no server at {paths.socket})")
        return 0
    if _wait_gone(paths, STOP_WAIT_S):
        print(f"pfn-resident: stopped (pid {reply['pid']})")
    else:
        print(f"pfn-resident: stopping (pid {reply['pid']}) after the job in progress")
    return 0


def _duration(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def status(args: argparse.Namespace) -> int:
    try:
        paths = resident_paths()
    except ResidentDirError as err:
        reply, where = None, str(err)
    else:
        reply, where = _ask(paths, "status"), f"no server at {paths.socket}"
    if reply is None:
        if args.json:
            print(json.dumps({"running": False}))
        else:
            print(f"pfn-resident: not running ({where})")
        return NOT_RUNNING
    reply = {k: v for k, v in reply.items() if k != "type"}
    problem = compatibility(reply)
    if args.json:
        print(json.dumps({"running": True, **reply, "used_by_pfn_render": problem is None, "why_not": problem}))
        return 0
    waiting = f" with {reply['queued']} waiting" if reply["queued"] else ""
    queue = f", busy{waiting}" if reply["busy"] else ""
    rows = [("pid", str(reply["pid"])), ("uptime", _duration(reply["uptime_s"])),
            ("jobs served", f"{reply['jobs']}{queue}"), ("warm-up", reply["warm_up"]),
            ("memory", f"{reply['rss_mb']:.0f} MB resident"),
            ("idle exit", f"after {reply['idle_minutes']:g} min without jobs"),
            ("code fingerprint", reply["code"]),
            ("pfn-render", "uses it" if problem is None else f"renders in-process: {problem}"),
            ("socket", reply["socket"]), ("log", reply["log"] or "the terminal it was started in")]
    print("pfn-resident: running")
    for name, value in rows:
        print(f"  {name:<17} {value}")
    return 0


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return {"start": start, "stop": stop, "status": status}[args.command](args)


def main(argv: Sequence[str] | None = None) -> int:
    sys.exit(_main(argv))


if __name__ == "__main__":
    main()
