"""``pfn-render`` through a resident server (``pfn-resident``): the same files and output as an in-process render,
the CLI's error conventions, strict messages, and in-process rendering whenever the server cannot run a job as the
client would (another code or environment).

One real server per module (``pfn-resident start --foreground`` in a temporary ``PFN_RESIDENT_DIR``); every client is
a real ``pfn-render`` process. Whether a job went through the server is read from its job count. Nothing here
depends on CPU speed or thread count: renders are compared bit for bit, and the one long job is interrupted.
"""

from __future__ import annotations

import json
import os
import pty
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from resident_helpers import (
    TINY,
    WAIT_S,
    Server,
    environment,
    private_folder,
    raw_exchange,
    raw_request,
    render,
    same_images,
    script,
)

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the resident server is Linux only")

from photon_fields.runtime.cli.render import _main as render_main  # noqa: E402
from photon_fields.runtime.resident.client import render_request  # noqa: E402
from photon_fields.runtime.resident.protocol import MAX_MESSAGE_BYTES, PROTOCOL  # noqa: E402


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server with the kernels warmed (the product's default start)."""
    folder = private_folder(tmp_path_factory.mktemp("resident") / "srv")
    srv = Server(folder)
    try:
        yield srv
    finally:
        srv.close()


def test_client_render_equals_in_process_render(server: Server, tmp_path: Path) -> None:
    """Through the server (relative --out: the client's folder) and with --no-resident in the client's process:
    the same EXR layers bit for bit and the same PNG bytes; two clients at once wait their turns."""
    args = [*TINY, "--seed", "3", "--method", "pt"]
    before = server.jobs()
    first = subprocess.Popen([script("pfn-render"), *args, "--out", "a/r.exr"], cwd=tmp_path,
                             env=environment(server.folder), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = render([*args, "--out", "b/r.exr"], tmp_path, server.folder)
    out, err = first.communicate(timeout=WAIT_S)
    assert first.returncode == 0 and second.returncode == 0, (err, second.stderr)
    assert server.jobs() == before + 2
    local = render([*args, "--out", "c/r.exr", "--no-resident"], tmp_path, server.folder)
    assert local.returncode == 0, local.stderr
    assert server.jobs() == before + 2  # --no-resident: not through the server
    for name in ("a", "b"):
        same_images(tmp_path / name / "r.exr", tmp_path / "c" / "r.exr")
        assert sorted(p.name for p in (tmp_path / name).iterdir()) == ["r.exr", "r.json", "r.png"]
    shape = re.compile(r"stages \(ms\): .*\nrendered in [\d.]+ s -> a/r\.exr, a/r\.png, a/r\.json\n")
    assert shape.fullmatch(out) and err == "", (out, err)


def test_a_field_render_through_the_server_equals_in_process(server: Server, tmp_path: Path) -> None:
    """The neural renderer (a small random field exported as a bundle of the builtin 'blobs'): the same files."""
    pytest.importorskip("torch")
    from conftest import make_model, make_run, small_field_config

    from photon_fields.runtime.scene.scene import builtin_scene
    from photon_fields.train.export.bundle import export_bundle

    scene = builtin_scene("blobs")
    medium = scene.medium()
    run = make_run(tmp_path / "run", make_model(small_field_config()), medium.bmin.tolist(), medium.bsize.tolist(),
                   scene.fingerprint())
    bundle = export_bundle(run, tmp_path / "f.pfn", scene=scene).path
    args = [*TINY, "--method", "field", "--bundle", str(bundle), "--seed", "2"]
    before = server.jobs()
    through = render([*args, "--out", "a/r.exr"], tmp_path, server.folder)
    local = render([*args, "--out", "b/r.exr", "--no-resident"], tmp_path, server.folder)
    assert through.returncode == local.returncode == 0, (through.stderr, local.stderr)
    assert server.jobs() == before + 1 and through.stderr == local.stderr
    same_images(tmp_path / "a" / "r.exr", tmp_path / "b" / "r.exr")


@pytest.mark.parametrize("bad", [["--scene", "nosuch"], ["--spp", "0"], ["--size", "16by16"], ["--bogus"]],
                         ids=["scene", "spp", "size", "unknown-option"])
def test_bad_input_is_the_same_line_and_status_2(server: Server, tmp_path: Path, bad: list[str],
                                                 capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    args = [*TINY, *bad, "--out", "r.exr"]
    before = server.jobs()
    proc = render(args, tmp_path, server.folder)
    assert server.jobs() == before + 1
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert render_main(args) == 2
    expected = capsys.readouterr().err
    assert len(expected.splitlines()) == 1 and expected.startswith("error: ")
    assert (proc.returncode, proc.stdout, proc.stderr) == (2, "", expected)
    assert list(tmp_path.iterdir()) == []


def test_no_replacement_without_force_through_the_server(server: Server, tmp_path: Path) -> None:
    """The render CLI's rule holds through the server: an existing image is refused, then replaced with --force."""
    (tmp_path / "r.exr").write_bytes(b"earlier")
    proc = render([*TINY, "--out", "r.exr"], tmp_path, server.folder)
    assert proc.returncode == 2 and "pass --force" in proc.stderr and len(proc.stderr.splitlines()) == 1
    assert (tmp_path / "r.exr").read_bytes() == b"earlier"
    assert render([*TINY, "--out", "r.exr", "--force"], tmp_path, server.folder).returncode == 0
    assert (tmp_path / "r.exr").read_bytes() != b"earlier"


def test_help_through_the_server_is_the_in_process_help(server: Server, tmp_path: Path) -> None:
    through = render(["--help"], tmp_path, server.folder)
    local = render(["--help", "--no-resident"], tmp_path, server.folder)
    assert through.returncode == local.returncode == 0
    assert through.stdout == local.stdout and "--no-resident" in through.stdout


def test_progress_follows_the_clients_streams(server: Server, tmp_path: Path) -> None:
    """A pipe gets the plain log lines (PFN_PROGRESS_SECONDS, a per-job variable, forwarded); a terminal gets tqdm's
    bar, as wide as that terminal (the server measures a stand-in of the client's size)."""
    args = ["--scene", "blobs", "--size", "16x16", "--spp", "2", "--batch-size", "128"]
    before = server.jobs()
    piped = render([*args, "--out", "p.exr"], tmp_path, server.folder, PFN_PROGRESS_SECONDS="0")
    assert piped.returncode == 0 and "\r" not in piped.stderr
    assert any(re.fullmatch(r"path tracing: \d+% \([\d.]+k?/512 spl\), [\d.]+ s, ~[\d.]+ s left", line)
               for line in piped.stderr.splitlines()), piped.stderr
    columns = 77
    code, text = _render_on_a_terminal([*args, "--out", "t.exr"], tmp_path, server.folder, columns)
    assert code == 0 and server.jobs() == before + 2
    bars = [part for part in text.replace("\r\n", "\n").split("\r") if part.startswith("path tracing:")]
    assert bars and all(len(bar) == columns - 1 for bar in bars), bars  # tqdm's width: the terminal's, less one


def _render_on_a_terminal(args: list[str], cwd: Path, folder: Path, columns: int) -> tuple[int, str]:
    """``pfn-render args`` with stdout and stderr on a pseudo-terminal ``columns`` wide; (status, what it showed)."""
    import fcntl
    import struct
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    proc = subprocess.Popen([script("pfn-render"), *args], cwd=cwd, env=environment(folder), stdin=subprocess.DEVNULL,
                            stdout=slave, stderr=slave)
    os.close(slave)
    chunks = []
    try:
        while True:
            ready, _, _ = select.select([master], [], [], WAIT_S)
            if not ready:
                raise AssertionError("no output for a minute")
            try:
                data = os.read(master, 1 << 16)
            except OSError:  # the terminal closed: every writer ended
                break
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(master)
    return proc.wait(timeout=WAIT_S), b"".join(chunks).decode()


@pytest.mark.parametrize("where", ["server", "in-process"])
def test_interrupting_the_client_interrupts_the_job(server: Server, tmp_path: Path, where: str) -> None:
    """Ctrl-C on the client while the server renders: 'error: interrupted', status 130, nothing written, as
    in-process (where Ctrl-C inside a numba call used to end in a SystemError traceback); the server serves the next
    job."""
    args = ["--scene", "blobs", "--size", "256x256", "--spp", "65536", "--out", "big.exr"]  # minutes on any machine
    if where == "in-process":
        args.append("--no-resident")
    before = server.jobs()
    # A client in a terminal's foreground: SIGINT at its default even when this run was started in the background
    # of a shell without job control (which starts it ignored, and an ignored SIGINT is inherited across exec).
    proc = subprocess.Popen([script("pfn-render"), *args], cwd=tmp_path,
                            env=environment(server.folder, PFN_PROGRESS_SECONDS="0"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stderr is not None
    ready, _, _ = select.select([proc.stderr], [], [], WAIT_S)
    first = proc.stderr.readline() if ready else ""
    assert first.startswith("path tracing:"), first  # the job runs in the server
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 130 and err.splitlines()[-1] == "error: interrupted", err
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []
    assert server.jobs() == before + (where == "server")
    assert render([*TINY, "--out", "after.exr"], tmp_path, server.folder).returncode == 0


# ----------------------------------------------------------------------------------------------------------
# messages


def _good_request(tmp_path: Path, argv: list[str]) -> dict:
    """A render request as pfn-render in this process would send it (same code and environment as the server)."""
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        return render_request(argv)
    finally:
        os.chdir(cwd)


def framed(body: bytes) -> bytes:
    """``body`` with its correct length prefix."""
    return len(body).to_bytes(4, "big") + body


@pytest.mark.parametrize(("data", "needle"), [
    (framed(b"{oops"), "not UTF-8 JSON"),
    (framed(b'{"request":"st\xffatus"}'), "not UTF-8 JSON"),
    ((MAX_MESSAGE_BYTES + 1).to_bytes(4, "big") + b"{}", "larger than"),
    (framed(b"[]"), "must be a JSON object"),
    (framed(b'{"request":"status","protocol":1,"protocol":1}'), "given twice"),
    (framed(b'{"request":"status","protocol":NaN}'), "NaN"),
    (framed(b'{"request":"status","protocol":1,"verbose":1}'), "unknown key 'verbose'"),
    (framed(b'{"request":"nap","protocol":1}'), "unknown request 'nap'"),
    (framed(b'{"request":"status"}'), "missing 'protocol'"),
], ids=["not-json", "not-utf8", "oversized", "not-an-object", "duplicate-key", "nan", "unknown-key",
        "unknown-request", "missing-key"])
def test_malformed_messages_get_one_error_line(server: Server, data: bytes, needle: str) -> None:
    reply = raw_exchange(server.folder, data)
    assert reply is not None and reply["type"] == "error", reply
    assert needle in reply["problem"] and "\n" not in reply["problem"], reply
    assert server.status() is not None  # serving on


@pytest.mark.parametrize(("change", "needle"), [
    ({"bogus": 1}, "unknown key 'bogus'"),
    ({"argv": "--spp 1"}, "'argv' must be a list"),
    ({"umask": 4096}, "'umask'"),
    ({"cwd": "relative/folder"}, "'cwd' must be an absolute path"),
    ({"stderr_isatty": 1}, "'stderr_isatty' must be true or false"),
    ({"stdout_size": [80]}, "'stdout_size'"),
    ({"job_env": {"NUMBA_NUM_THREADS": "1"}}, "not per-job variables"),
], ids=["unknown-key", "argv", "umask", "cwd", "isatty", "size", "job-env"])
def test_a_bad_render_request_is_refused_and_the_next_job_runs(server: Server, tmp_path: Path, change: dict,
                                                               needle: str) -> None:
    before = server.jobs()
    request = {**_good_request(tmp_path, [*TINY, "--out", "r.exr"]), **change}
    reply = raw_request(server.folder, request)
    assert reply is not None and reply["type"] == "error" and needle in reply["problem"], reply
    assert list(tmp_path.iterdir()) == [] and server.jobs() == before
    assert render([*TINY, "--out", "r.exr"], tmp_path, server.folder).returncode == 0
    assert server.jobs() == before + 1


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to connect as another user")
def test_a_client_of_another_user_is_refused(server: Server, tmp_path_factory: pytest.TempPathFactory) -> None:
    """The folder's mode keeps other users out; past it (a hard link to the socket in an open folder, here), the
    server checks the peer's uid and refuses in one line."""
    python = shutil.which("python3", path="/usr/bin:/bin")
    if python is None:
        pytest.skip("no system python3 that another user can run")
    code = ("import json, socket, sys\n"
            "s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1])\n"
            "body = json.dumps({'request': 'status', 'protocol': 1}).encode()\n"
            "try:\n"
            "    s.sendall(len(body).to_bytes(4, 'big') + body)\n"
            "except BrokenPipeError:\n"  # the server may refuse (reply and close) before the request is read
            "    pass\n"
            "n = int.from_bytes(s.recv(4), 'big'); data = b''\n"
            "while len(data) < n: data += s.recv(n)\n"
            "print(data.decode())\n")
    sock = server.folder / "render.sock"
    public = Path(tempfile.mkdtemp(prefix="pfn-peer-"))
    try:
        public.chmod(0o711)
        os.link(sock, public / "link.sock")
        sock.chmod(0o666)
        proc = subprocess.run([python, "-I", "-c", code, str(public / "link.sock")], user=65534, cwd="/",
                              capture_output=True, text=True, timeout=WAIT_S, check=False)
    except PermissionError:  # the interpreter itself is out of that user's reach
        pytest.skip(f"{python} cannot run as another user here")
    finally:
        sock.chmod(0o600)
        shutil.rmtree(public)
    assert proc.returncode == 0, proc.stderr
    reply = json.loads(proc.stdout)
    assert reply == {"type": "error", "problem": "refused: this server serves only its own user"}
    assert server.status() is not None


def test_another_protocol_is_incompatible(server: Server, tmp_path: Path) -> None:
    request = {**_good_request(tmp_path, [*TINY, "--out", "r.exr"]), "protocol": PROTOCOL + 1, "new": True}
    reply = raw_request(server.folder, request)
    assert reply is not None and reply["type"] == "incompatible", reply


# ----------------------------------------------------------------------------------------------------------
# compatibility: another code or environment renders in-process


def test_another_code_fingerprint_is_not_run(server: Server, tmp_path: Path) -> None:
    """A client whose installed code differs gets 'incompatible' (and renders in-process); the server, whose code on
    disk did not change, serves on."""
    before = server.jobs()
    reply = raw_request(server.folder, {**_good_request(tmp_path, [*TINY, "--out", "r.exr"]), "code": "0" * 32})
    assert reply is not None and reply["type"] == "incompatible" and "code" in reply["problem"], reply
    assert server.jobs() == before and list(tmp_path.iterdir()) == []
    status = server.status()
    assert status is not None and status["pid"] == server.pid


def test_another_environment_renders_in_process(server: Server, tmp_path: Path) -> None:
    """PFN_CACHE (read when the package loads) differs from the server's: the client renders in its own process,
    silently, to the same image."""
    before = server.jobs()
    args = [*TINY, "--seed", "5"]
    local = render([*args, "--out", "env/r.exr"], tmp_path, server.folder, PFN_CACHE=str(tmp_path / "cache"))
    assert local.returncode == 0 and local.stderr == "", local.stderr
    assert server.jobs() == before
    assert render([*args, "--out", "srv/r.exr"], tmp_path, server.folder).returncode == 0
    assert server.jobs() == before + 1
    same_images(tmp_path / "env" / "r.exr", tmp_path / "srv" / "r.exr")


def test_the_client_imports_only_the_standard_library(server: Server, tmp_path: Path) -> None:
    """pfn-render hands its job over before numpy, numba or anything of the renderer is imported."""
    before = server.jobs()
    proc = subprocess.run([sys.executable, "-X", "importtime", script("pfn-render"), *TINY, "--out", "r.exr"],
                          cwd=tmp_path, env=environment(server.folder), capture_output=True, text=True,
                          timeout=WAIT_S, check=False)
    assert proc.returncode == 0 and server.jobs() == before + 1, proc.stderr[-2000:]
    imported = {line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines() if line.startswith("import time:")}
    ours = ("photon_fields.runtime.cli.render", "photon_fields.models_spec", "photon_fields.runtime.errors")
    heavy = sorted(m for m in imported if m.split(".")[0] in ("numpy", "numba", "scipy", "onnxruntime", "tqdm", "PIL")
                   or (m.startswith(ours) and m != "photon_fields.runtime.cli.render_entry"))
    assert not heavy, heavy
    assert "photon_fields.runtime.resident.client" in imported
