"""Helpers of the resident-server tests: the console scripts as real processes, a server in its own folder, raw
requests on its socket, and the checks of a render's files."""

from __future__ import annotations

import os
import select
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from photon_fields.runtime.io.images import read_exr
from photon_fields.runtime.resident.client import ask
from photon_fields.runtime.resident.paths import ResidentPaths
from photon_fields.runtime.resident.protocol import encode, receive

#: A render that takes well under a second once the kernels are loaded.
TINY = ["--scene", "blobs", "--size", "16x16", "--spp", "1", "--quiet"]
LAYERS = ("L", "L_d", "L_i", "L_e")
#: Seconds a test waits for a server to start, answer or end before it fails (generous: never a measurement).
WAIT_S = 60.0


def script(name: str) -> str:
    """The installed console script ``name`` beside this interpreter (skips the test when it is missing)."""
    exe = Path(sys.executable).parent / name
    found = str(exe) if exe.is_file() else shutil.which(name)
    if found is None:
        pytest.skip(f"the {name} console script is not installed (pip install -e .)")
    return found


def private_folder(path: Path) -> Path:
    """``path`` created with mode 0700, as the server's folder must be."""
    path.mkdir(parents=True, exist_ok=True)
    path.chmod(0o700)
    return path


def environment(folder: Path, **extra: str) -> dict[str, str]:
    """This process's environment with the server's folder (and ``extra``): the server's and its clients'."""
    return {**os.environ, "PFN_RESIDENT_DIR": str(folder), "PYTHONWARNINGS": "ignore", **extra}


class Server:
    """A ``pfn-resident start --foreground`` process serving ``folder`` (its log in ``log``)."""

    def __init__(self, folder: Path, *args: str) -> None:
        self.folder, self.paths = folder, ResidentPaths(str(folder))
        self.log = folder.parent / f"{folder.name}.log"
        with open(self.log, "w") as log:
            # cwd: its own folder, so that a job that ignored the client's folder would write nowhere that matters
            self.proc = subprocess.Popen([script("pfn-resident"), "start", "--foreground", *args], cwd=folder.parent,
                                         env=environment(folder), stdout=subprocess.PIPE, stderr=log, text=True)
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], WAIT_S)
        line = self.proc.stdout.readline() if ready else ""
        if not line.startswith("pfn-resident: serving"):
            self.close()
            raise AssertionError(f"the server did not start: {line!r}; log: {self.log.read_text()}")
        self.pid = self.proc.pid

    def status(self) -> dict[str, Any] | None:
        return ask(self.paths, "status")

    def jobs(self) -> int:
        reply = self.status()
        assert reply is not None, "the server is not answering"
        return reply["jobs"]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=WAIT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def render(args: list[str], cwd: Path, folder: Path, timeout: float = 300, **extra: str
           ) -> subprocess.CompletedProcess[str]:
    """``pfn-render args`` as a real process in ``cwd``, with the server folder ``folder``."""
    return subprocess.run([script("pfn-render"), *args], cwd=cwd, env=environment(folder, **extra),
                          capture_output=True, text=True, timeout=timeout, check=False)


def raw_exchange(folder: Path, data: bytes) -> dict[str, Any] | None:
    """Send ``data`` as it is on a new connection to the server of ``folder``; its first reply (None: it closed)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(WAIT_S)
        sock.connect(str(folder / "render.sock"))
        sock.sendall(data)
        return receive(sock)


def raw_request(folder: Path, message: dict[str, Any]) -> dict[str, Any] | None:
    return raw_exchange(folder, encode(message))


def same_images(a: Path, b: Path) -> None:
    """Two renders' EXR layers equal bit for bit, and their PNGs byte for byte."""
    la, _ = read_exr(a)
    lb, _ = read_exr(b)
    assert set(la) == set(lb) >= set(LAYERS)
    for name in la:
        assert np.array_equal(la[name], lb[name]), name
        assert la[name].tobytes() == lb[name].tobytes(), name
    assert a.with_suffix(".png").read_bytes() == b.with_suffix(".png").read_bytes()


def wait_until(condition: Any, timeout: float = WAIT_S, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def process_gone(pid: int) -> bool:
    """Whether ``pid`` has ended (a zombie that no one reaped counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except (FileNotFoundError, ProcessLookupError):
        return True
