"""numba's on-disk cache must hit in a new process: every cached kernel's index key is the same in two processes.

numba keys a cached function by its signature, the machine and hashes of its bytecode and, for a closure, of a
pickle of its cells (``numba.core.caching._CacheImpl._index_key``). A cell that pickles differently in each process
(a captured dispatcher carries a uuid4 of its own process) makes every new process miss the cache and compile the
kernel again: from 2026-11-27 to 11-30 NEE's item loops were made by a factory that captured ``direct_light``, and
every command-line path-traced render compiled them anew (bench/README.md, ``bench_cli_startup.py``)."""

from __future__ import annotations

import json
import subprocess
import sys

_KEYS = r"""
import hashlib, importlib, json, pkgutil, sys
from numba.core.dispatcher import Dispatcher
from numba.core.serialize import dumps

keys = {}
for root in ("photon_fields.runtime", "photon_fields.models_spec", "photon_fields.train"):
    package = importlib.import_module(root)
    for info in pkgutil.walk_packages(package.__path__, root + "."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if not isinstance(obj, Dispatcher) or type(obj._cache).__name__ == "NullCache":
                continue
            cells = obj.py_func.__closure__
            blob = b"" if cells is None else dumps(tuple(c.cell_contents for c in cells))
            keys[f"{info.name}.{name}"] = [cells is not None, hashlib.sha256(blob).hexdigest()]
json.dump(keys, sys.stdout)
"""


def _cache_keys() -> dict[str, list]:
    out = subprocess.run([sys.executable, "-c", _KEYS], check=True, capture_output=True, text=True, timeout=300)
    return json.loads(out.stdout)


def test_every_cached_kernel_has_the_same_cache_key_in_a_new_process() -> None:
    first, second = _cache_keys(), _cache_keys()
    assert len(first) > 100, f"only {len(first)} cached kernels found: the scan missed the package"
    assert first.keys() == second.keys()
    moved = sorted(name for name in first if first[name] != second[name])
    assert not moved, f"cached kernels whose cache key changes between processes (compiled anew in each): {moved}"


_WARM_AGAIN = r"""
import json, sys
from numba.core import event
from photon_fields.runtime.resident.warmup import warm_up

compiled = []


class Compiles(event.Listener):  # numba fires numba:compile only when it compiles (a cache miss)
    def on_start(self, ev):
        d = ev.data["dispatcher"]
        compiled.append(f"{d.py_func.__module__}.{d.py_func.__qualname__}")

    def on_end(self, ev):
        pass


event.register("numba:compile", Compiles())
warm_up()
json.dump(sorted(set(compiled)), sys.stdout)
"""


def test_a_second_process_loads_every_kernel_the_first_compiled() -> None:
    """What a new process loads (the resident server's warm-up: a path-traced and a ray-marched render through the
    command line's main, the neural renderer's kernels, the hash encoders made per grid), twice, in the suite's numba
    cache: the first process fills it where needed, and the second compiles nothing (no ``numba:compile`` event:
    numba fires it only on a cache miss)."""
    runs = [subprocess.run([sys.executable, "-c", _WARM_AGAIN], check=True, capture_output=True, text=True,
                           timeout=1500) for _ in range(2)]
    second = json.loads(runs[1].stdout)
    assert not second, f"kernels compiled again in a second process (their cache missed): {second}"
