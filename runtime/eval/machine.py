"""What CPU a figure was measured on: model name, vendor and the instruction-set extensions that change
which kernels numba, numpy and onnxruntime run.

Every benchmark JSON and every report with timings records this, so figures from different machines
(an Intel CPU with AMX, an AMD EPYC with AVX2 only, ...) are never compared by accident. Nothing in the
product's results may depend on it: only speed does.
"""

from __future__ import annotations

import os
import platform
from functools import lru_cache
from pathlib import Path
from typing import Any

#: Instruction-set flags (as /proc/cpuinfo spells them) that select different SIMD or matrix kernels.
ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512bw", "avx512vl", "avx512_vnni", "avx_vnni",
             "avx512_bf16", "avx512_fp16", "amx_tile", "amx_int8", "amx_bf16")


def _proc_cpuinfo(path: Path = Path("/proc/cpuinfo")) -> dict[str, str]:
    """The first processor's ``key: value`` lines (Linux), else empty."""
    fields: dict[str, str] = {}
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return fields
    for line in text.splitlines():
        if not line.strip():
            if fields:
                break  # end of the first processor's block
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def parse_cpuinfo(fields: dict[str, str]) -> dict[str, Any]:
    """Model, vendor, all flags and the ISA extensions of :data:`ISA_FLAGS` present, from cpuinfo fields."""
    flags = sorted(set(fields.get("flags", fields.get("Features", "")).split()))
    return {"model": fields.get("model name") or fields.get("Model") or platform.processor() or platform.machine(),
            "vendor": fields.get("vendor_id", ""),
            "isa": [f for f in ISA_FLAGS if f in flags],
            "flags": flags}


@lru_cache(maxsize=1)
def cpu_info() -> dict[str, Any]:
    """This machine's CPU: ``model``, ``vendor``, ``isa`` (the extensions that matter), ``flags`` (all of
    them), ``logical_cpus`` and ``machine`` (the architecture)."""
    info = parse_cpuinfo(_proc_cpuinfo())
    return {**info, "logical_cpus": os.cpu_count(), "machine": platform.machine()}


def cpu_summary() -> str:
    """One line for logs and reports: model and the ISA extensions, e.g. ``AMD EPYC (avx2, avx512f, ...)``."""
    info = cpu_info()
    return f"{info['model']} ({', '.join(info['isa']) or 'no SIMD extensions detected'})"


def cpu_record() -> dict[str, Any]:
    """The short form for reports with timings (renders, demo, evaluation): model and ISA extensions."""
    info = cpu_info()
    return {"model": info["model"], "isa": info["isa"], "logical_cpus": info["logical_cpus"]}


def resident_memory_mb(pid: int | str = "self") -> float | None:
    """Resident memory (VmRSS) of process ``pid`` in MB, from /proc; None where /proc does not say."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        return None
    return None
