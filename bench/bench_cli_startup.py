"""CLI start-up (issue 17, item 5): wall time of a tiny ``pfn-render`` and what the interpreter spends before it.

Each case is a fresh process (what a user or a script pays per call), run ``--repeats`` times after one warm-up run
(which fills numba's cache), median wall seconds:

- ``python``: the interpreter alone (``python -c pass``): the floor no product code can go below;
- ``import numpy`` and ``import numba``: the libraries every render needs;
- ``numba ready``: numba imported and its typing/target context initialized by the cached kernels of one tiny
  medium (4^3 voxels): the cost of using numba at all, before any work of ours (what ``pfn-render pt`` spends
  beyond it is ours: the scene, the render, the files);
- ``pfn-render pt``: ``--scene blobs --size 16x16 --spp 1 --method pt`` (the issue's case; goal <= 0.7 s);
- ``pfn-render field``: the same with ``--method field --bundle B`` when ``--bundle`` is given (goal <= 1 s);
- ``client import``: ``python -c 'import photon_fields.runtime.resident.client'``, what ``pfn-render`` imports before
  it knows whether a resident server takes the job;
- ``pfn-render pt (resident)`` and ``pfn-render field (resident)``: the same renders handed to a warm resident server
  (``pfn-resident start --foreground`` in a temporary ``PFN_RESIDENT_DIR``, its warm-up finished; docs/resident.md).

The in-process cases run with ``PFN_RESIDENT_DIR`` set to a folder that does not exist, so that a server of the user's
own is never measured by mistake. Also recorded: the client's code fingerprint (median ms of 21 calls in this
process) and the server's resident memory after the runs.

Output: a table and JSON (default ``bench/results/cli_startup.json``) with the machine record. Run it on a quiet
machine: the figures are wall times of short processes.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import finish_info, machine_info, write_report

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "cli_startup.json"
NUMBA_READY = ("import numpy as np\n"
               "from photon_fields.runtime.scene.transfer import TransferFunction\n"
               "from photon_fields.runtime.scene.volume import make_volume\n"
               "from photon_fields.runtime.transport.medium import build_medium\n"
               "tf = TransferFunction(np.array([0.0, 1.0]), np.ones((2, 3)), np.array([0.0, 1.0]), 1.0)\n"
               "build_medium(make_volume(np.ones((4, 4, 4)), window=(0.0, 1.0)), tf)")


def _wall(cmd: list[str], repeats: int, env: dict[str, str] | None = None) -> float:
    """Median wall seconds of ``cmd`` over ``repeats`` runs after one warm-up run; exits on a failed run."""
    times = []
    for r in range(repeats + 1):
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed: {proc.stderr.strip().splitlines()[-1:]}")
        if r:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def start_server(folder: Path) -> subprocess.Popen[str]:
    """A warm resident server in ``folder`` (``pfn-resident start --foreground``, its warm-up finished)."""
    script = shutil.which("pfn-resident", path=str(Path(sys.executable).parent))
    if script is None:
        raise SystemExit("pfn-resident is not installed beside this python (pip install -e .)")
    env = {**os.environ, "PFN_RESIDENT_DIR": str(folder)}
    proc = subprocess.Popen([script, "start", "--foreground"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 120)
    if not ready or not proc.stdout.readline().startswith("pfn-resident: serving"):
        proc.kill()
        raise SystemExit("the resident server did not start")
    deadline = time.monotonic() + 300
    while not server_status(folder).get("warm_up", "").startswith(("done", "failed")):
        if time.monotonic() > deadline:
            proc.kill()
            raise SystemExit("the resident server's warm-up did not finish in 5 min")
        time.sleep(0.2)
    return proc


def server_status(folder: Path) -> dict:
    script = shutil.which("pfn-resident", path=str(Path(sys.executable).parent))
    out = subprocess.run([str(script), "status", "--json"], env={**os.environ, "PFN_RESIDENT_DIR": str(folder)},
                         capture_output=True, text=True, check=False).stdout
    return json.loads(out) if out.strip() else {}


def fingerprint_ms() -> float:
    """Median milliseconds of the client's code fingerprint (the stat of the package's files), in this process."""
    from photon_fields.runtime.resident.fingerprint import code_fingerprint

    times = []
    for _ in range(21):
        t0 = time.perf_counter()
        code_fingerprint()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--bundle", type=Path, default=None, help="a field bundle (NAME.pfn) for the field case")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()
    render = shutil.which("pfn-render", path=str(Path(sys.executable).parent))
    if render is None:
        raise SystemExit("pfn-render is not installed beside this python (pip install -e .)")
    info = machine_info()
    out_dir = Path(tempfile.mkdtemp(prefix="pfn-startup-"))
    tiny = ["--scene", "blobs", "--size", "16x16", "--spp", "1", "--quiet", "--force"]
    pt = [render, *tiny, "--method", "pt", "--out", str(out_dir / "pt.exr")]
    field = [render, *tiny, "--method", "field", "--bundle", str(args.bundle), "--out", str(out_dir / "field.exr")] \
        if args.bundle is not None else []
    no_server = {**os.environ, "PFN_RESIDENT_DIR": str(out_dir / "no-server")}
    server_dir = out_dir / "resident"
    server_dir.mkdir(mode=0o700)
    with_server = {**os.environ, "PFN_RESIDENT_DIR": str(server_dir)}
    cases: dict[str, tuple[list[str], dict[str, str]]] = {
        "python": ([sys.executable, "-c", "pass"], no_server),
        "import numpy": ([sys.executable, "-c", "import numpy"], no_server),
        "import numba": ([sys.executable, "-c", "import numba"], no_server),
        "numba ready": ([sys.executable, "-c", NUMBA_READY], no_server),
        "client import": ([sys.executable, "-c", "import photon_fields.runtime.resident.client"], no_server),
        "pfn-render pt": (pt, no_server),
    }
    if args.bundle is not None:
        cases["pfn-render field"] = (field, no_server)
    cases["pfn-render pt (resident)"] = (pt, with_server)
    if args.bundle is not None:
        cases["pfn-render field (resident)"] = (field, with_server)
    server = start_server(server_dir)
    results: dict[str, dict] = {}
    try:
        print(f"{'case':<28} {'median s':>9}")
        for name, (cmd, env) in cases.items():
            jobs = server_status(server_dir).get("jobs")
            results[name] = {"wall_s": round(_wall(cmd, args.repeats, env), 4)}
            served = server_status(server_dir).get("jobs") != jobs
            if served != name.endswith("(resident)"):
                raise SystemExit(f"{name}: {'ran' if served else 'did not run'} through the resident server")
            print(f"{name:<28} {results[name]['wall_s']:>9.3f}")
        status = server_status(server_dir)
    finally:
        server.terminate()
        server.wait(timeout=60)
    client = {"fingerprint_ms": round(fingerprint_ms(), 3)}
    resident = {k: status.get(k) for k in ("rss_mb", "warm_up", "jobs")}
    print(f"client code fingerprint: {client['fingerprint_ms']:.2f} ms; server after {resident['jobs']} jobs: "
          f"{resident['rss_mb']} MB resident, warm-up {resident['warm_up']}")
    shutil.rmtree(out_dir, ignore_errors=True)
    write_report(args.out, "cli_startup", finish_info(info, {}), {"repeats": args.repeats,
                                                                  "bundle": str(args.bundle) if args.bundle else None},
                 results=results, client=client, resident=resident)


if __name__ == "__main__":
    main()
