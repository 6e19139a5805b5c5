"""The CPU record every benchmark JSON carries, and the resident-memory reading (photon_fields.runtime.eval.machine)."""

from __future__ import annotations

import mmap
import os
import re
import sys
from pathlib import Path

import pytest
from conftest import REPO

from photon_fields.runtime.eval.machine import (
    _proc_cpuinfo,
    cpu_info,
    cpu_summary,
    parse_cpuinfo,
    resident_memory_mb,
)

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC 7B13
flags\t\t: fpu sse4_2 avx avx2 fma f16c

processor\t: 1
vendor_id\t: GenuineIntel
model name\t: some other core
flags\t\t: avx512f avx512_vnni amx_tile
"""


def test_parse_cpuinfo_reads_the_first_processor(tmp_path: Path) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO)
    info = parse_cpuinfo(_proc_cpuinfo(path))
    assert info["model"] == "AMD EPYC 7B13" and info["vendor"] == "AuthenticAMD"
    assert info["isa"] == ["sse4_2", "avx", "avx2", "fma", "f16c"]  # in ISA_FLAGS order, none of CPU 1's
    assert "fpu" in info["flags"] and "avx512f" not in info["flags"]


def test_missing_cpuinfo_gives_a_record_not_an_error(tmp_path: Path) -> None:
    info = parse_cpuinfo(_proc_cpuinfo(tmp_path / "absent"))
    assert info["flags"] == [] and info["isa"] == [] and isinstance(info["model"], str)


def test_this_machine_and_the_bench_record() -> None:
    info = cpu_info()
    assert info["model"] and info["logical_cpus"] >= 1
    assert info["model"] in cpu_summary()
    if sys.platform == "linux" and Path("/proc/cpuinfo").is_file():
        assert info["flags"], "Linux exposes the CPU flags in /proc/cpuinfo"
    bench = REPO / "bench"
    sys.path.insert(0, str(bench))
    try:
        from common import machine_info
    finally:
        sys.path.remove(str(bench))
    assert machine_info()["cpu"] == info


def test_every_benchmark_records_the_machine() -> None:
    """Each bench script that writes JSON takes its machine record from bench/common.machine_info."""
    for script in sorted((REPO / "bench").glob("bench_*.py")):
        text = script.read_text()
        if re.search(r"write_report|json\.dump", text):
            assert "machine_info()" in text, f"{script.name} writes JSON without machine_info()"


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="no /proc on this system")
def test_resident_memory_grows_with_an_allocation_and_is_none_for_no_process() -> None:
    """VmRSS of this process in MB: it rises by about the size of 64 MB written into memory, reads the same by pid,
    and a pid no process has gives None. The block is a fresh anonymous mapping: a bytearray may reuse memory the
    allocator kept resident from earlier work (in a busy pytest worker VmRSS then did not move)."""
    before = resident_memory_mb()
    block = mmap.mmap(-1, 64 << 20)
    block[:: 4096] = b"\x01" * len(block[:: 4096])  # touch every page
    after = resident_memory_mb(os.getpid())
    block.close()
    assert before is not None and after is not None
    assert 48.0 < after - before < 96.0
    assert resident_memory_mb(2**22 + 12345) is None
