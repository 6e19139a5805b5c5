"""Where a frame's CPU time goes, by compiled function: ``perf`` over warm frames, numba's kernels named.

Samples the process with Linux ``perf record`` while it renders ``--frames`` warm frames of the neural renderer
(with its depth maps and the WRLS denoiser, as the viewer renders them; ``--no-denoise`` for the render alone), then
prints each function's CPU milliseconds per frame: numba's kernels under their own names, grouped as ``library |
function`` (a parallel loop's body is numba's ``__numba_parfor_gufunc_...``, shown under the kernel it belongs to),
the C libraries' functions (libm's ``log``, onnxruntime, numpy, the kernel's page faults) under theirs.

Why a tool: perf sees numba's code only as anonymous addresses, and numba keeps no symbols of kernels loaded from
its cache. Before the warm-up, :func:`record_numba_objects` makes numba keep every object file it loads or
compiles; :func:`write_perf_map` then reads their ELF symbol tables, asks numba where each function was loaded and
writes ``/tmp/perf-PID.map``, which ``perf report`` reads for JIT code.

```sh
.venv/bin/python bench/profile_frame.py --scene head --bundle /tmp/hb/head/field.pfn --size 512 --camera forced
```

Needs ``perf`` (Debian: ``linux-perf``) and permission to sample this process (``kernel.perf_event_paranoid`` <= 2
for one's own processes); without them it says so in one line and exits 2. Output: the table on stdout, and
JSON (``--out``, default ``bench/results/profile_frame.json``) with the machine record. Figures are CPU time
summed over threads, so a frame's row sums to about twice its wall time on two busy cores.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

_OBJECTS: dict[int, tuple[Any, bytes]] = {}


def record_numba_objects() -> None:
    """Keep a copy of every object file numba loads from its cache or compiles from now on (call before the first
    kernel runs): numba drops them once loaded, and their symbol tables are what names the code."""
    from numba.core import codegen

    library = codegen.JITCodeLibrary
    set_object = library._set_compiled_object

    def keep_loaded(self: Any, value: bytes) -> None:  # a kernel loaded from numba's cache
        _OBJECTS[id(self)] = (self, bytes(value))
        set_object(self, value)

    compiled_hook = library._object_compiled_hook.__func__

    def keep_compiled(cls: Any, ll_module: Any, buf: bytes) -> None:  # a kernel compiled in this process
        compiled_hook(cls, ll_module, buf)
        owner = getattr(ll_module, "_CPUCodeLibrary__library", None)
        if owner is not None:
            _OBJECTS[id(owner)] = (owner, bytes(buf))

    library._set_compiled_object = keep_loaded
    library._object_compiled_hook = classmethod(keep_compiled)


def elf_functions(obj: bytes) -> list[tuple[str, int]]:
    """(name, size) of the functions an ELF64 little-endian object file defines (its .symtab)."""
    if obj[:4] != b"\x7fELF":
        return []
    (shoff,) = struct.unpack_from("<Q", obj, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", obj, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", obj, shoff + i * shentsize) for i in range(shnum)]
    out = []
    for sec in sections:
        if sec[1] != 2:  # SHT_SYMTAB
            continue
        strtab_offset = sections[sec[6]][4]
        offset, size, entsize = sec[4], sec[5], sec[9]
        for k in range(size // entsize):
            name, info, _, shndx, _, sym_size = struct.unpack_from("<IBBHQQ", obj, offset + k * entsize)
            if info & 0xF == 2 and shndx != 0:  # STT_FUNC, defined here
                start = strtab_offset + name
                out.append((obj[start:obj.index(b"\0", start)].decode(), sym_size))
    return out


def short_name(mangled: str) -> str:
    """numba's Itanium-style mangled name -> its last two components (``module.function``)."""
    rest = mangled[mangled.index("_ZN") + 3:] if "_ZN" in mangled else ""
    parts = []
    while rest[:1].isdigit():
        digits = re.match(r"\d+", rest).group(0)  # type: ignore[union-attr]
        n = int(digits)
        parts.append(rest[len(digits):len(digits) + n])
        rest = rest[len(digits) + n:]
    name = ".".join(parts[-2:]) if parts else mangled
    return "parallel loop" if "__numba_parfor_gufunc" in name else name


def write_perf_map(pid: int) -> int:
    """Write ``/tmp/perf-PID.map`` for the numba functions recorded so far; returns how many."""
    symbols = {}
    for library, obj in list(_OBJECTS.values()):
        for name, size in elf_functions(obj):
            try:
                address = library.get_pointer_to_function(name)
            except Exception:  # a symbol numba did not load (e.g. a discarded duplicate)
                continue
            if address:  # helpers every module defines (NRT_incref, ...) resolve to one copy: no owner named
                owner = f"{library.name} | " if "_ZN" in name else ""
                label = f"{owner}{short_name(name)}".replace(" ", "_")
                symbols[address] = (label, max(size, 1))
    with open(f"/tmp/perf-{pid}.map", "w") as f:
        for address in sorted(symbols):
            label, size = symbols[address]
            f.write(f"{address:x} {size:x} {label}\n")
    return len(symbols)


def parse_report(text: str) -> dict[str, float]:
    """``perf report --stdio --sort dso,sym --field-separator ;`` -> {"dso: symbol": share of samples}; numba's
    code (perf's ``[JIT] tid N``) as ``numba: library | function``, unnamed addresses pooled per library."""
    shares: dict[str, float] = defaultdict(float)
    for line in text.splitlines():
        fields = line.split(";")
        if line.startswith("#") or len(fields) != 3 or not fields[0].strip().endswith("%"):
            continue
        share, dso, sym = float(fields[0].strip()[:-1]) / 100, fields[1].strip(), fields[2].strip()
        sym = re.sub(r"^\[.\]\s*", "", sym)
        if sym.startswith("0x"):
            sym = "(unnamed)"
        if dso.startswith("[JIT]"):
            dso, sym = "numba", sym.replace("_|_", " | ")
        shares[f"{dso}: {sym}"] += share
    return dict(shares)


def find_function(part: str) -> tuple[Any, bytes, str, int, int] | None:
    """The recorded numba function whose mangled name contains ``part`` (the largest if several): (library, object
    file, symbol, size, load address)."""
    best = None
    for library, obj in list(_OBJECTS.values()):
        for name, size in elf_functions(obj):
            if part not in name or "_ZN" not in name or name.startswith(("cpython", "cfunc")):
                continue
            try:
                address = library.get_pointer_to_function(name)
            except Exception:
                continue
            if address and (best is None or size > best[3]):
                best = (library, obj, name, size, address)
    return best


def annotate(perf: str, data: Path, part: str, top: int) -> list[str]:
    """Hot instructions of one numba function: perf's sampled addresses as offsets into its code, next to objdump's
    disassembly of its object file; then its hottest 256-byte windows (a window full of float loads right after an
    index computation is a lookup waiting on memory; ``vdivsd`` / ``vsqrtsd`` / calls are named per window)."""
    found = find_function(part)
    objdump = shutil.which("objdump")
    if found is None or objdump is None:
        return [f"annotate: no function matching {part!r} recorded" if found is None else "annotate: no objdump"]
    _, obj, name, size, address = found
    ips = subprocess.run([perf, "script", "-i", str(data), "-F", "ip"], capture_output=True, text=True,
                         check=True).stdout.split()
    hits = Counter(int(ip, 16) - address for ip in ips if 0 <= int(ip, 16) - address < size)
    total = max(1, sum(hits.values()))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "kernel.o"
        path.write_bytes(obj)
        listing = subprocess.run([objdump, "-d", "--no-show-raw-insn", f"--disassemble={name}", str(path)],
                                 capture_output=True, text=True, check=True).stdout
    code = [line.split(":", 1) for line in listing.splitlines() if re.match(r"\s+[0-9a-f]+:", line)]
    if not code:
        return [f"annotate: objdump found no code for {name[:80]}"]
    start = int(code[0][0], 16)
    instructions = {int(o, 16) - start: text.strip() for o, text in code}
    out = [f"{short_name(name)}: {total} samples ({len(ips)} in all), {size} bytes; hottest instructions:"]
    out += [f"  {c / total * 100:5.1f}%  {o:6x}  {instructions.get(o, '?')}" for o, c in hits.most_common(top)]
    windows = Counter()
    for o, c in hits.items():
        windows[o // 256] += c
    out.append("hottest 256-byte windows (and the divisions, square roots and calls in them):")
    for w, c in windows.most_common(top // 2):
        notable = [t for o, t in instructions.items() if o // 256 == w and re.search(r"div|sqrt|call", t)]
        out.append(f"  {c / total * 100:5.1f}%  {w * 256:6x}  {'; '.join(notable[:4])}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="head")
    ap.add_argument("--bundle", default=None, help="the scene's field bundle (pfn-train all SCENE --out DIR); needed "
                    "by the neural renderer")
    ap.add_argument("--renderer", choices=("neural", "preview"), default="neural",
                    help="neural (the default) or the preview (the ray marcher with its light volume)")
    ap.add_argument("--resolution", type=int, default=None, help="voxels per side of the builtin volume")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--camera", default="forced", help="camera estimator (forced, marched, delta, auto)")
    ap.add_argument("--frames", type=int, default=60, help="frames sampled (after 3 warm-up frames)")
    ap.add_argument("--no-denoise", action="store_true", help="the render alone, no depth maps or WRLS")
    ap.add_argument("--top", type=int, default=30, help="rows printed")
    ap.add_argument("--annotate", metavar="NAME", default=None,
                    help="also the hot instructions of the numba function whose name contains NAME (needs objdump)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "profile_frame.json")
    args = ap.parse_args(argv)
    if args.renderer == "neural" and args.bundle is None:
        print("profile_frame: --bundle: the neural renderer needs the scene's field", file=sys.stderr)
        return 2
    perf = shutil.which("perf")
    if perf is None:
        print("profile_frame: perf not found (Debian: apt install linux-perf)", file=sys.stderr)
        return 2
    record_numba_objects()
    sys.path.insert(0, str(Path(__file__).parent))
    from common import machine_info, write_report

    from photon_fields.runtime.denoise.depth import DepthEstimator
    from photon_fields.runtime.denoise.wrls import WRLSDenoiser
    from photon_fields.runtime.field.field import PhotonField
    from photon_fields.runtime.renderers.neural import render_neural
    from photon_fields.runtime.renderers.orbit import orbit_camera
    from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
    from photon_fields.runtime.scene.scene import builtin_scene

    info = machine_info()
    base = builtin_scene(args.scene) if args.resolution is None else builtin_scene(args.scene, args.resolution)
    scene = base.with_overrides(width=args.size, height=args.size)
    estimator = PhotonField.load(args.bundle).estimator() if args.bundle else None
    denoiser = WRLSDenoiser(args.size, args.size)
    depth = DepthEstimator(scene.medium())

    def frame(i: int) -> None:
        cam = orbit_camera(scene.camera, i)
        if args.renderer == "preview":
            result = render_ray_marched(scene.with_overrides(camera=cam), seed=i, progress=False)
        else:
            result = render_neural(scene.with_overrides(camera=cam), estimator, spp=1, seed=i, progress=False,
                                   camera=args.camera)
        if not args.no_denoise:
            denoiser.denoise(result.layers["L"], camera=cam, depth=depth.depth(cam))

    for i in range(3):
        frame(i)
    symbols = write_perf_map(os.getpid())
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        rec = subprocess.Popen([perf, "record", "-F", "999", "-p", str(os.getpid()), "-o", str(data), "-q"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(0.5)  # perf attaches
        if rec.poll() is not None:
            print(f"profile_frame: perf record failed: {rec.stderr.read().decode().strip().splitlines()[-1:]}",
                  file=sys.stderr)
            return 2
        t0 = time.perf_counter()
        for i in range(3, 3 + args.frames):
            frame(i)
        wall = time.perf_counter() - t0
        rec.send_signal(2)  # SIGINT: perf writes its data and exits
        rec.wait()
        report = subprocess.run([perf, "report", "-i", str(data), "--stdio", "--no-children", "--sort", "dso,sym",
                                 "--field-separator", ";"],
                                capture_output=True, text=True, check=True).stdout
        total_samples = re.search(r"# Samples: (\d+)(K?)", report)
        annotated = annotate(perf, data, args.annotate, args.top) if args.annotate else []
    shares = parse_report(report)
    n = int(total_samples.group(1)) * (1000 if total_samples.group(2) else 1) if total_samples else 0
    cpu_ms_per_frame = n / 999 * 1e3 / args.frames  # samples at 999 Hz on every busy thread
    rows = sorted(((s * cpu_ms_per_frame, name) for name, s in shares.items()), reverse=True)
    frame_ms = wall / args.frames * 1e3
    what = args.camera if args.renderer == "neural" else args.renderer
    print(f"{args.scene} {args.size}^2 {what}{'' if args.no_denoise else ' + WRLS'}: {frame_ms:.1f} ms a "
          f"frame (wall, while sampled), {cpu_ms_per_frame:.1f} CPU ms; {symbols} numba functions named "
          f"({info['cpu'].get('model', '?')})")
    for ms, name in rows[:args.top]:
        print(f"{ms:8.2f}  {name}")
    if annotated:
        print("\n" + "\n".join(annotated))
    config = vars(args) | {"out": str(args.out), "bundle": args.bundle and str(args.bundle)}
    write_report(args.out, "profile_frame", info, config,
                 frame_ms=frame_ms, cpu_ms_per_frame=cpu_ms_per_frame,
                 functions=[{"cpu_ms": ms, "name": name} for ms, name in rows], annotated=annotated)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
