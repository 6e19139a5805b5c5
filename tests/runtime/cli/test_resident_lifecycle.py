"""The resident server's life and the client's fallbacks: ``pfn-resident start / status / stop``, the idle exit, a
stale socket, a server that dies before or during a job, and the pieces that decide (the folder's checks, the code
fingerprint, ``--no-resident``).

Each server here has its own temporary ``PFN_RESIDENT_DIR`` and starts without warming the kernels (``--no-warm-up``):
these tests are about its life, not its speed. A stand-in server (a thread speaking the protocol) plays the one that
dies, so that nothing depends on when a real one would be killed.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from resident_helpers import (
    TINY,
    WAIT_S,
    Server,
    environment,
    private_folder,
    process_gone,
    render,
    script,
    wait_until,
)

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the resident server is Linux only")

from photon_fields.runtime.cli.render_entry import in_process_requested  # noqa: E402
from photon_fields.runtime.resident.fingerprint import (  # noqa: E402
    code_fingerprint,
    job_environment,
    process_environment,
)
from photon_fields.runtime.resident.paths import ResidentDirError, resident_paths  # noqa: E402
from photon_fields.runtime.resident.protocol import receive, send  # noqa: E402


def resident(args: list[str], folder: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([script("pfn-resident"), *args], env=environment(folder), capture_output=True, text=True,
                          timeout=WAIT_S * 2, check=False)


def test_start_status_stop(tmp_path: Path) -> None:
    """The background server: started once (a second start leaves it), reported by status (text and JSON), stopped
    by stop (its socket removed, its process ended); status says 'not running' with exit status 3."""
    folder = tmp_path / "srv"  # start creates it, private
    gone = resident(["status"], folder)
    assert gone.returncode == 3 and gone.stdout.startswith("pfn-resident: not running"), gone
    started = resident(["start", "--no-warm-up", "--idle-minutes", "5"], folder)
    pid = None
    try:
        assert started.returncode == 0 and started.stdout.startswith("pfn-resident: started (pid "), started
        pid = int(started.stdout.split("(pid ", 1)[1].split(")", 1)[0])
        assert (folder.stat().st_mode & 0o777, (folder / "render.sock").stat().st_mode & 0o777) == (0o700, 0o600)
        again = resident(["start"], folder)
        assert again.returncode == 0 and f"already running (pid {pid})" in again.stdout, again
        assert render([*TINY, "--out", "r.exr"], tmp_path, folder).returncode == 0
        status = resident(["status"], folder)
        assert status.returncode == 0, status
        text = status.stdout
        rows = {"pid": str(pid), "jobs served": "1", "code fingerprint": code_fingerprint(),
                "socket": str(folder / "render.sock"), "pfn-render": "uses it", "idle exit": "after 5 min without jobs",
                "log": str(folder / "resident.log")}
        for name, value in rows.items():
            assert f"  {name:<17} {value}\n" in text, (name, text)
        assert "  uptime  " in text and " MB resident" in text
        doc = json.loads(resident(["status", "--json"], folder).stdout)
        assert doc["running"] and doc["pid"] == pid and doc["jobs"] == 1 and doc["used_by_pfn_render"]
        stopped = resident(["stop"], folder)
        assert stopped.returncode == 0 and stopped.stdout.strip() == f"pfn-resident: stopped (pid {pid})", stopped
        assert not (folder / "render.sock").exists()
        wait_until(lambda: process_gone(pid), what="the stopped server's process to end")
        assert resident(["status"], folder).returncode == 3
        assert "job 1: pfn-render" in (folder / "resident.log").read_text()
    finally:
        if pid is not None and not process_gone(pid):
            resident(["stop"], folder)


def test_idle_exit(tmp_path: Path) -> None:
    """A server without a job for --idle-minutes ends by itself and removes its socket."""
    folder = private_folder(tmp_path / "srv")
    server = Server(folder, "--no-warm-up", "--idle-minutes", "0.01")
    try:
        assert server.proc.wait(timeout=WAIT_S) == 0
    finally:
        server.close()
    assert not (folder / "render.sock").exists()
    assert "stopping: no job for 0.01 min" in server.log.read_text()


def test_a_stale_socket_renders_in_process(tmp_path: Path) -> None:
    """A socket file left by a killed server (nothing listening): pfn-render renders in its own process, silently;
    and a new server replaces the stale socket."""
    folder = private_folder(tmp_path / "srv")
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(folder / "render.sock"))
    stale.close()  # the file stays, nothing listens
    proc = render([*TINY, "--out", "r.exr"], tmp_path, folder)
    assert (proc.returncode, proc.stderr) == (0, ""), proc.stderr
    assert sorted(p.name for p in tmp_path.glob("r.*")) == ["r.exr", "r.json", "r.png"]
    server = Server(folder, "--no-warm-up")
    try:
        status = server.status()
        assert status is not None and status["pid"] == server.pid
    finally:
        server.close()


def test_an_insecure_or_missing_folder_renders_in_process(tmp_path: Path) -> None:
    """A folder others may enter is not used by the client (and refused by start in one line)."""
    folder = tmp_path / "open"
    folder.mkdir()
    folder.chmod(0o755)
    with pytest.raises(ResidentDirError, match="lets other users in"):
        resident_paths({"PFN_RESIDENT_DIR": str(folder)})
    with pytest.raises(ResidentDirError, match="no such folder"):
        resident_paths({"PFN_RESIDENT_DIR": str(tmp_path / "missing")})
    refused = resident(["start", "--no-warm-up"], folder)
    assert refused.returncode == 2 and refused.stderr.startswith("error: resident folder: ")
    assert len(refused.stderr.splitlines()) == 1 and not (folder / "render.sock").exists()


class StandIn:
    """A server that answers one render request with ``replies`` and then closes the connection (it 'dies')."""

    def __init__(self, folder: Path, replies: list[dict]) -> None:
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.listener.bind(str(folder / "render.sock"))
        self.listener.listen(1)
        self.listener.settimeout(WAIT_S)
        self.request: dict | None = None
        self.thread = threading.Thread(target=self._serve, args=(replies,), daemon=True)
        self.thread.start()

    def _serve(self, replies: list[dict]) -> None:
        conn, _ = self.listener.accept()
        with conn, contextlib.suppress(OSError):  # a client that refuses a reply leaves at once
            self.request = receive(conn)
            for reply in replies:
                send(conn, reply)
        self.listener.close()


def test_a_server_that_dies_during_the_job_is_one_line(tmp_path: Path) -> None:
    """The job started, its first output arrived, then the connection ended without an exit status: the client
    prints what came and one line naming --no-resident, exit status 1, and does not render itself."""
    folder = private_folder(tmp_path / "srv")
    stand_in = StandIn(folder, [{"type": "accepted", "pid": 4242, "ahead": 0}, {"type": "started"},
                                {"type": "stderr", "text": "path tracing: 10%\n"}])
    proc = render([*TINY, "--out", "r.exr"], tmp_path, folder)
    stand_in.thread.join(WAIT_S)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 1 and lines[0] == "path tracing: 10%" and len(lines) == 2, proc.stderr
    assert lines[1].startswith("error: resident render server (pid 4242): the connection closed during the job")
    assert "--no-resident" in lines[1]
    assert list(tmp_path.glob("r.*")) == []
    assert stand_in.request is not None and stand_in.request["argv"] == [*TINY, "--out", "r.exr"]
    assert stand_in.request["cwd"] == str(tmp_path)


@pytest.mark.parametrize("replies", [
    [{"type": "accepted", "pid": 4242, "ahead": 1}],  # stopped while the job waited its turn
    [{"type": "incompatible", "problem": "the environment differs in NUMBA_NUM_THREADS"}],
    # a reply with a key this client does not know, then a job that 'ran' (a client that reads on writes nothing)
    [{"type": "accepted", "pid": 4242, "ahead": 0, "eta": 3}, {"type": "started"}, {"type": "exit", "status": 0}],
], ids=["stopped-before-the-job", "incompatible", "unknown-key"])
def test_no_job_started_renders_in_process(tmp_path: Path, replies: list[dict]) -> None:
    folder = private_folder(tmp_path / "srv")
    stand_in = StandIn(folder, replies)
    proc = render([*TINY, "--out", "r.exr"], tmp_path, folder)
    stand_in.thread.join(WAIT_S)
    assert (proc.returncode, proc.stderr) == (0, ""), proc.stderr
    assert sorted(p.name for p in tmp_path.glob("r.*")) == ["r.exr", "r.json", "r.png"]


# ----------------------------------------------------------------------------------------------------------
# the pieces


@pytest.mark.parametrize(("argv", "expected"), [
    (["--no-resident"], True), (["--spp", "1", "--no-res"], True), (["--no-r"], True),
    (["--no-"], False), (["--no-nee"], False), (["--", "--no-resident"], False), ([], False),
])
def test_no_resident_is_recognised_as_argparse_would(argv: list[str], expected: bool) -> None:
    assert in_process_requested(argv) is expected


def test_code_fingerprint_follows_the_files(tmp_path: Path) -> None:
    """Any file's size or mtime, an added file or another folder changes it; bytecode caches do not."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    roots = [(str(pkg), True)]
    first = code_fingerprint(roots)
    assert code_fingerprint(roots) == first
    (pkg / "__pycache__").mkdir()
    (pkg / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"cache")
    assert code_fingerprint(roots) == first
    changes: list[Callable[[], object]] = [
        lambda: os.utime(pkg / "sub" / "b.py", ns=(1, 1)),
        lambda: (pkg / "a.py").write_text("x = 10\n"),
        lambda: (pkg / "c.py").write_text(""),
    ]
    seen = {first}
    for change in changes:
        change()
        seen.add(code_fingerprint(roots))
    assert len(seen) == 4
    assert code_fingerprint([(str(pkg), False)]) != code_fingerprint(roots)  # sub/ counts only when recursive
    assert code_fingerprint() == code_fingerprint() and len(code_fingerprint()) == 32


def test_environment_split() -> None:
    env = {"NUMBA_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE", "PFN_CACHE": "/c", "PFN_PROGRESS_SECONDS": "0",
           "PFN_RESIDENT_DIR": "/r", "TQDM_MININTERVAL": "1", "COLUMNS": "90", "HOME": "/h", "PYTHONPATH": "/p"}
    assert process_environment(env) == {"NUMBA_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE", "PFN_CACHE": "/c",
                                        "PYTHONPATH": "/p"}
    assert job_environment(env) == {"COLUMNS": "90", "PFN_PROGRESS_SECONDS": "0", "TQDM_MININTERVAL": "1"}


def _job_request(cwd: Path, **change: object) -> dict:
    request = {"argv": ["--spp", "1"], "cwd": str(cwd), "umask": 0o027, "stdout_isatty": False,
               "stdout_encoding": "utf-8", "stdout_size": None, "stderr_isatty": True, "stderr_encoding": "utf-8",
               "stderr_size": [91, 17], "job_env": {"PFN_PROGRESS_SECONDS": "0"}}
    return {**request, **change}


@pytest.mark.parametrize(("ending", "status", "stderr_end"), [
    (None, 0, "err\n"), (SystemExit(3), 3, "err\n"), (SystemExit("bye"), 1, "bye\n"),
    (KeyboardInterrupt(), 130, "error: interrupted\n"), (ValueError("boom"), 1, "ValueError: boom\n"),
], ids=["ok", "exit-3", "exit-message", "interrupt", "exception"])
def test_a_job_runs_as_the_clients_process_and_leaves_the_server_as_it_was(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ending: BaseException | None, status: int,
        stderr_end: str) -> None:
    """Inside the job: the client's folder, umask, per-job variables, argv and streams (a terminal of its size on
    stderr); after it, whatever its ending: the server's own again, and numba's threads back to all of them."""
    from photon_fields.runtime.resident.job import TerminalStandIn, run_job

    threads: list[int] = []
    monkeypatch.setitem(sys.modules, "numba", type(sys)("numba"))
    sys.modules["numba"].config = type(sys)("config")  # type: ignore[attr-defined]
    sys.modules["numba"].config.NUMBA_NUM_THREADS = 7  # type: ignore[attr-defined]
    sys.modules["numba"].set_num_threads = threads.append  # type: ignore[attr-defined]
    monkeypatch.setenv("PFN_PROGRESS_SECONDS", "5")
    monkeypatch.delenv("COLUMNS", raising=False)
    seen: dict = {}

    def render_main(argv: list[str]) -> int:
        mask = os.umask(0)
        os.umask(mask)
        seen.update(cwd=os.getcwd(), umask=mask, every=os.environ.get("PFN_PROGRESS_SECONDS"), argv=list(sys.argv),
                    tty=(sys.stdout.isatty(), sys.stderr.isatty()),
                    size=tuple(os.get_terminal_size(sys.stderr.fileno())))
        print("out", *argv)
        print("err", file=sys.stderr)
        if ending is not None:
            raise ending
        return 0

    sent: list[dict] = []
    before = (os.getcwd(), sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__, list(sys.argv))
    mask = os.umask(0o022)
    try:
        got = run_job(_job_request(tmp_path), lambda m: sent.append(m) or True, render_main, contextlib.nullcontext,
                      (TerminalStandIn.make(), TerminalStandIn.make()))
        after_mask = os.umask(mask)
    finally:
        os.umask(mask)
    assert got == status
    assert seen == {"cwd": str(tmp_path), "umask": 0o027, "every": "0", "argv": ["pfn-render", "--spp", "1"],
                    "tty": (False, True), "size": (91, 17)}
    assert (os.getcwd(), sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__, sys.argv) == before
    assert after_mask == 0o022 and os.environ["PFN_PROGRESS_SECONDS"] == "5" and "COLUMNS" not in os.environ
    assert threads == [7]
    assert "".join(m["text"] for m in sent if m["type"] == "stdout") == "out --spp 1\n"
    err = "".join(m["text"] for m in sent if m["type"] == "stderr")
    assert err.startswith("err\n") and err.endswith(stderr_end), err
