"""Render timings as in the paper's Table 2: the neural renderer against the reference path tracer.

Used by ``bench/bench_render.py`` and ``pfn-eval``. At 1 spp, best of ``repeats`` renders after a warm-up
(numba compilation, onnxruntime start-up), in one process so the ratios compare like with like:

- neural L_d: first interactions + NEE only (``render_neural(estimator=None)``);
- neural L_i: first interactions + field only (``direct=False``), with the field's split into hash
  encoding (position, direction), MLP inference and decoding;
- neural L: both, the product's frame;
- path tracer L_d: paths of one scattering vertex (``max_depth=1``: single scattering with NEE);
- path tracer L (``max_depth``, default 16): also the time of its L_i, which a path tracer cannot
  compute without tracing whole paths.

Speedups are path tracer / neural. ``other_cores`` is the load other processes put on the machine
meanwhile (figures taken under load are pessimistic).
"""

from __future__ import annotations

import os
import time
from typing import Any

from photon_fields.runtime.field.field import PhotonField
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.scene.scene import Scene


def _busy_cpu_seconds() -> float | None:
    """CPU seconds spent busy by the whole machine since boot (Linux /proc/stat), else None."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = fields
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


class Contention:
    """Measures how many cores *other* processes kept busy while the block ran (machine busy time
    minus this process's CPU time, over wall time): ``with Contention() as c: ...; c.other_cores``.
    Numba's prange kernels synchronize at the end of every stage, so one descheduled worker stalls
    the stage: even half a core of foreign load distorts the numba figures far more than numpy's."""

    def __enter__(self) -> Contention:
        self.other_cores: float | None = None
        self._t, self._busy, self._own = time.perf_counter(), _busy_cpu_seconds(), _own_cpu_seconds()
        return self

    def __exit__(self, *exc: object) -> None:
        busy = _busy_cpu_seconds()
        wall = time.perf_counter() - self._t
        if busy is not None and self._busy is not None and wall > 0:
            other = (busy - self._busy) - (_own_cpu_seconds() - self._own)
            self.other_cores = round(max(other, 0.0) / wall, 3)


def _own_cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system  # all threads of this process, numba's workers included



def timed(fn: Any, repeats: int) -> tuple[float, Any]:
    """Best wall time of ``repeats`` calls (after the caller's warm-up) and the last result."""
    best, result = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def time_renderers(scene: Scene, field: PhotonField, size: tuple[int, int], repeats: int = 3,
                   max_depth: int = 16) -> dict[str, Any]:
    """Paper Table 2 for one scene and size at 1 spp: neural L_d / L_i / L against the path tracer (module
    docstring), best of ``repeats`` after a warm-up, with the field's time split and compaction stats."""
    sc = scene.with_overrides(width=size[0], height=size[1])
    est = field.estimator()
    # One camera estimator for every column (auto would probe with each estimator, None's and the field's, and could
    # time L_d and L with different ones): forced, the first interaction of the paper's Alg. 2.
    kw: dict[str, Any] = {"spp": 1, "seed": 0, "progress": False}
    nkw: dict[str, Any] = {**kw, "camera": "forced"}
    render_neural(sc.with_overrides(width=32, height=32), est, **nkw)  # warm-up: compile, start sessions
    render_path_traced(sc.with_overrides(width=32, height=32), max_depth=max_depth, **kw)
    with Contention() as c:
        t_nd, _ = timed(lambda: render_neural(sc, None, **nkw), repeats)
        field.timers.reset()
        t_ni, res_i = timed(lambda: render_neural(sc, est, direct=False, **nkw), repeats)
        split = {k: v / repeats for k, v in field.timers.to_dict().items() if k.endswith("_s")}
        t_n, res = timed(lambda: render_neural(sc, est, **nkw), repeats)
        t_pd, _ = timed(lambda: render_path_traced(sc, max_depth=1, **kw), repeats)
        t_p, _ = timed(lambda: render_path_traced(sc, max_depth=max_depth, **kw), repeats)
    samples = res.stats["samples_in_volume"]
    return {
        "size": list(size), "spp": 1, "max_depth": max_depth, "repeats": repeats, "other_cores": c.other_cores,
        "neural": {"L_d_s": t_nd, "L_i_s": t_ni, "L_s": t_n, "stages_ms": res.timings_ms,
                   "L_i_stages_ms": res_i.timings_ms, "field_split_s_per_render": split,
                   "samples_in_volume": samples, "rays_in_box": res.stats["rays_in_volume"],
                   "compaction_removed": res.stats["compaction_removed"],
                   "pixels_missing_box": 1.0 - res.stats["rays_in_volume"] / (size[0] * size[1]),
                   "field_queries_per_s": samples / max(split.get("total_s", 0.0), 1e-12)},
        "path_tracer": {"L_d_s": t_pd, "L_i_s": t_p, "L_s": t_p},
        "speedup": {"L_d": t_pd / t_nd, "L_i": t_p / t_ni, "L": t_p / t_n},
    }
