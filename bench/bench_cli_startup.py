"""CLI start-up (issue 17, item 5): wall time of a tiny ``pfn-render`` and what the interpreter spends before it.

Each case is a fresh process (what a user or a script pays per call), run ``--repeats`` times after one warm-up run
(which fills numba's cache), median wall seconds:

- ``python``: the interpreter alone (``python -c pass``): the floor no product code can go below;
- ``import numpy`` and ``import numba``: the libraries every render needs;
- ``numba ready``: numba imported and its typing/target context initialized by the cached kernels of one tiny
  medium (4^3 voxels): the cost of using numba at all, before any work of ours (what ``pfn-render pt`` spends
  beyond it is ours: the scene, the render, the files);
- ``pfn-render pt``: ``--scene blobs --size 16x16 --spp 1 --method pt`` (the issue's case; goal <= 0.7 s);
- ``pfn-render field``: the same with ``--method field --bundle B`` when ``--bundle`` is given (goal <= 1 s).

Output: a table and JSON (default ``bench/results/cli_startup.json``) with the machine record. Run it on a quiet
machine: the figures are wall times of short processes.
"""

from __future__ import annotations

import argparse
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


def _wall(cmd: list[str], repeats: int) -> float:
    """Median wall seconds of ``cmd`` over ``repeats`` runs after one warm-up run; exits on a failed run."""
    times = []
    for r in range(repeats + 1):
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed: {proc.stderr.strip().splitlines()[-1:]}")
        if r:
            times.append(time.perf_counter() - t0)
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
    cases = {
        "python": [sys.executable, "-c", "pass"],
        "import numpy": [sys.executable, "-c", "import numpy"],
        "import numba": [sys.executable, "-c", "import numba"],
        "numba ready": [sys.executable, "-c", NUMBA_READY],
        "pfn-render pt": [render, *tiny, "--method", "pt", "--out", str(out_dir / "pt.exr")],
    }
    if args.bundle is not None:
        cases["pfn-render field"] = [render, *tiny, "--method", "field", "--bundle", str(args.bundle),
                                     "--out", str(out_dir / "field.exr")]
    results = {}
    print(f"{'case':<20} {'median s':>9}")
    for name, cmd in cases.items():
        results[name] = {"wall_s": round(_wall(cmd, args.repeats), 4)}
        print(f"{name:<20} {results[name]['wall_s']:>9.3f}")
    shutil.rmtree(out_dir, ignore_errors=True)
    write_report(args.out, "cli_startup", finish_info(info, {}), {"repeats": args.repeats,
                                                                  "bundle": str(args.bundle) if args.bundle else None},
                 results=results)


if __name__ == "__main__":
    main()
