"""Photon-field queries per second in the runtime (no torch at query time): encode + MLP + decode.

For each architecture (``--archs``: ``cpu``, the default preset's field, 45 -> 64x3 -> 3; ``paper``, Sec. 3.4's
16x8 / 2^19 encodings, 257 -> 64x4 -> 3) a bundle is exported (``train.export.bundle``) from a field with random
tables (uniform in [-1, 1]) and Xavier weights: speed does not depend on the values. It is loaded with
``runtime.field.field.PhotonField.load`` and queried end to end with ``query`` (world positions uniform in the
box, uniform random unit directions, g uniform in [-1, 1]: the worst case for the caches), at each batch
(``--batches``, default 2^14, 2^16, 2^18), reporting queries/s and the split of the time into the
field's own stage timers: position encoding (``normalize_position`` + hash grid), direction encoding
(``direction_input`` + hash grid), inference (onnxruntime) and decode (Eq. 7).

Variants at the largest batch (``--variant-batch``, default 2^18):

- ``threads``: 1 and 2 threads (numba and onnxruntime both);
- ``spinning``: onnxruntime's idle workers spinning (its default) or sleeping (our default);
- ``pipeline``: ``PhotonField.load(pipeline=True)``, onnxruntime on chunk k in a worker thread while numba
  encodes chunk k + 1, with 1 and 2 threads for each;
- ``chunk``: queries per onnxruntime call (2^12 .. 2^16);
- ``precision``: fp32 (exact), int8 (onnxruntime dynamic quantization, removed from the runtime: measured
  here with its max error on L', since its kernels and accuracy depend on the CPU's VNNI), fp16 MLP (float16
  weights and activations in onnxruntime, casts at both ends: measured to decide whether to offer it) and
  fp16 tables (same speed expected: the runtime widens them at load);
- ``rays`` (coherent queries: 64 samples along each camera ray in raster order, as a renderer's batch).

A ``stages`` section times each step alone at ``--variant-batch`` in one chunk-sized loop (normalize, hash,
spherical coordinates, hash, g column, onnxruntime, decode) to show where the time goes.

Every figure is the best of ``--repeats`` calls after a warm-up call; ``other_cores`` records how many
cores other processes kept busy (bench/common.py), and ``cpu_s_per_mquery`` the CPU seconds this process
spent per million queries (all threads; what a query costs whatever else runs: on two idle cores the
wall-clock rate is at most 2e6 / cpu_s_per_mquery). Run on an idle machine; the figures vary 2x with load.

Parameters: ``--archs cpu,paper`` ``--batches 16384,65536,262144`` ``--variant-batch 262144``
``--repeats 3`` ``--threads 2`` (default run) ``--quick`` (cpu only, 2^14/2^16, no paper) ``--out PATH``
(default bench/results/field.json).
"""

from __future__ import annotations

import argparse
import os

# Before numba / torch load their OpenMP runtime (see train.fit.loop): passive waiting when pools alternate.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import json  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402

# bench/ is on sys.path when this file is run as a script, so the sibling module imports directly.
from common import Contention, finish_info, machine_info, write_report  # noqa: E402

from photon_fields.models_spec.encoding import decode_radiance, direction_input, normalize_position  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.field.hashgrid import encode  # noqa: E402
from photon_fields.runtime.field.session import make_session  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "field.json"
BMIN, BSIZE = [-0.5, -0.35, -0.45], [1.0, 0.7, 0.9]


def make_bundle(arch: str, folder: Path, tables_dtype: str = "float32") -> Path:
    """Export a random field of the preset's architecture (torch is only needed here, not to query)."""
    import torch

    from photon_fields.train.export.bundle import RUN_DOMAIN_FORMAT, export_bundle
    from photon_fields.train.field.network import TorchPhotonField as TorchField
    from photon_fields.train.fit.checkpoint import save_checkpoint
    from photon_fields.train.fit.presets import PRESETS, field_config_for

    run = folder / f"run_{arch}"
    if not (run / "checkpoint.pt").is_file():
        run.mkdir(parents=True, exist_ok=True)
        model = TorchField(field_config_for(PRESETS[arch], (-0.75, 0.0, 0.75), volume_shape=(96, 96, 96)), seed=0)
        gen = torch.Generator().manual_seed(1)
        with torch.no_grad():
            for t in model.table_parameters():
                t.copy_(torch.rand(t.shape, generator=gen) * 2 - 1)
        fp = "0" * 64
        save_checkpoint(run / "checkpoint.pt", model, fp, 0, {})
        (run / "domain.json").write_text(json.dumps({"format": RUN_DOMAIN_FORMAT, "version": 1, "scene": "bench",
                                                     "scene_fingerprint": fp, "bmin": BMIN, "bsize": BSIZE}))
        del model
    return export_bundle(run, folder / f"{arch}_{tables_dtype}.pfn", tables_dtype=tables_dtype, force=True,
                         verify=False).path


def fp16_mlp(path: Path) -> bytes:
    """The bundle's MLP with float16 weights and activations (Cast to float16 in, to float32 out)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    m = onnx.load(str(path / "field.onnx"))
    g = m.graph
    for init in g.initializer:
        init.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(init).astype(np.float16), init.name))
    inp, out = g.input[0].name, g.output[0].name
    for node in g.node:
        node.input[:] = [f"{i}_h" if i == inp else i for i in node.input]
        node.output[:] = [f"{o}_h" if o == out else o for o in node.output]
    g.node.insert(0, helper.make_node("Cast", [inp], [f"{inp}_h"], to=TensorProto.FLOAT16))
    g.node.append(helper.make_node("Cast", [f"{out}_h"], [out], to=TensorProto.FLOAT))
    onnx.checker.check_model(m)
    return m.SerializeToString()


def int8_mlp(path: Path) -> bytes:
    """The bundle's MLP with int8 weights (onnxruntime dynamic quantization, activations quantized per
    call): the variant the runtime no longer offers, measured for speed and error on this CPU."""
    import logging
    import tempfile

    from onnxruntime.quantization import QuantType, quantize_dynamic

    with tempfile.TemporaryDirectory(prefix="pfn-int8-") as tmp:
        dst = Path(tmp) / "int8.onnx"
        logging.getLogger().setLevel(logging.ERROR)  # a "consider pre-processing" warning per model
        quantize_dynamic(path / "field.onnx", dst, weight_type=QuantType.QInt8)
        return dst.read_bytes()


def queries(n: int, rng: np.random.Generator, kind: str = "random") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    bmin, bsize = np.asarray(BMIN), np.asarray(BSIZE)
    if kind == "rays":
        # A pinhole camera's rays through a square pixel grid in raster order, 64 samples along each inside
        # the box: neighbouring queries share grid cells, as in a renderer's batch.
        samples = 64
        rays = n // samples
        side = max(1, int(np.sqrt(rays)))
        iy, ix = np.divmod(np.arange(rays), side)
        d = np.stack([((ix + 0.5) / side - 0.5) * 0.8, ((iy + 0.5) / side - 0.5) * 0.8, np.ones(rays)], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        t = 1.5 + (np.arange(samples) + 0.5) / samples
        u = np.clip((np.array([0.5, 0.5, -1.5]) + d[:, None, :] * t[None, :, None]).reshape(-1, 3), 0, 1)
        x = bmin + u * bsize
        d = np.repeat(d, samples, axis=0)
    else:
        x = bmin + rng.random((n, 3)) * bsize
        d = rng.standard_normal((n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    return x, d, rng.uniform(-1, 1, len(x))


def run_query(field: PhotonField, x: np.ndarray, d: np.ndarray, g: np.ndarray, repeats: int) -> dict[str, Any]:
    field.query(x[:1024], d[:1024], g[:1024])  # warm-up: kernels, session, buffers
    best: dict[str, Any] | None = None
    walls, cpus = [], []
    with Contention() as busy:
        for _ in range(repeats):
            field.timers.reset()
            c0 = _cpu_seconds()
            t0 = time.perf_counter()
            field.query(x, d, g)
            wall = time.perf_counter() - t0
            walls.append(wall)
            cpus.append(_cpu_seconds() - c0)
            if best is None or wall < best["wall_s"]:
                best = {"wall_s": wall, **{k: v for k, v in field.timers.to_dict().items() if k.endswith("_s")}}
    assert best is not None
    n = len(x)
    split = {k.removesuffix("_s"): round(best[k] / best["wall_s"], 3)
             for k in ("encode_position_s", "encode_direction_s", "inference_s", "decode_s")}
    # CPU seconds per million queries (all threads of this process): what the work costs, whatever the
    # other processes on the machine do; on 2 idle cores the wall-clock rate is at best 2e6 / this.
    return {"queries_per_s": round(n / best["wall_s"], 1), "best": {k: round(v, 5) for k, v in best.items()},
            "share": split, "walls_s": [round(w, 5) for w in walls],
            "cpu_s_per_mquery": round(float(np.median(cpus)) / n * 1e6, 3), "other_cores": busy.other_cores}


def _cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


def load(path: Path, **kw: Any) -> PhotonField:
    return PhotonField.load(path, **kw)


def stages(field: PhotonField, x: np.ndarray, d: np.ndarray, g: np.ndarray, repeats: int) -> dict[str, float]:
    """Each step of a query alone, over the batch in chunk-sized pieces: best seconds."""
    cfg, chunk = field.config, field.chunk
    buf = np.empty((chunk, cfg.input_dims), np.float32)
    n = len(x)
    pos = normalize_position(x, field.bmin, field.bsize)
    uv = direction_input(d)
    lp = np.empty((n, 3), np.float32)

    def each(fn) -> float:  # noqa: ANN001
        fn(0, min(n, chunk))
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for a in range(0, n, chunk):
                fn(a, min(n, a + chunk))
            times.append(time.perf_counter() - t0)
        return round(min(times), 5)

    sess = field.session
    with Contention() as busy:
        out = {
            "normalize_position": each(lambda a, b: normalize_position(x[a:b], field.bmin, field.bsize)),
            "hash_position": each(lambda a, b: encode(cfg.position, field.position_table, pos[a:b], out=buf[:b - a])),
            "direction_input": each(lambda a, b: direction_input(d[a:b])),
            "hash_direction": each(lambda a, b: encode(cfg.direction, field.direction_table, uv[a:b], out=buf[:b - a],
                                                       col=cfg.position.output_dims)),
            "g_column": each(lambda a, b: buf[:b - a, -1].__setitem__(slice(None), g[a:b])),
            "onnxruntime": each(lambda a, b: lp.__setitem__(slice(a, b), sess.run(None, {"features": buf[:b - a]})[0])),
            "decode": each(lambda a, b: decode_radiance(lp[a:b], cfg.psi)),
        }
    out["total"] = round(sum(out.values()), 5)
    out["queries_per_s_sum"] = round(n / out["total"], 1)
    out["other_cores"] = busy.other_cores
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--archs", default="cpu,paper")
    ap.add_argument("--batches", default="16384,65536,262144")
    ap.add_argument("--variant-batch", type=int, default=1 << 18)
    ap.add_argument("--threads", type=int, default=2, help="threads of the main figures")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="cpu architecture, 2^14 and 2^16, variant batch 2^16")
    ap.add_argument("--keep", type=Path, default=None, help="folder for the bundles (default: a temporary one)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    if args.quick:
        args.archs, args.batches, args.variant_batch = "cpu", "16384,65536", 1 << 16
    archs = [a for a in args.archs.split(",") if a]
    batches = [int(b) for b in args.batches.split(",") if b]
    threads = min(args.threads, numba.config.NUMBA_NUM_THREADS)
    info = machine_info()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="pfn-bench-field-"))
    rng = np.random.default_rng(args.seed)
    results: dict[str, Any] = {}
    contention: dict[str, dict[str, Any]] = {}
    t_start = time.perf_counter()
    try:
        for arch in archs:
            t0 = time.perf_counter()
            path = make_bundle(arch, folder)
            res: dict[str, Any] = {"bundle_mb": round(sum(p.stat().st_size for p in path.iterdir()) / 1e6, 1),
                                   "export_s": round(time.perf_counter() - t0, 2)}
            field = load(path, threads=threads)
            res["field"] = field.config.to_dict()
            res["input_width"] = field.input_width
            print(f"\n{arch}: input width {field.input_width}, bundle {res['bundle_mb']} MB, {threads} threads, "
                  f"chunk {field.chunk}")
            print(f"  {'what':28s} {'M q/s':>7s} {'pos':>6s} {'dir':>6s} {'mlp':>6s} {'dec':>6s} {'cpu-s/Mq':>9s}"
                  "  other_cores")

            def show(label: str, r: dict[str, Any], arch: str = arch) -> None:
                s = r["share"]
                print(f"  {label:28s} {r['queries_per_s'] / 1e6:7.2f} {s['encode_position']:6.0%} "
                      f"{s['encode_direction']:6.0%} {s['inference']:6.0%} {s['decode']:6.0%} "
                      f"{r['cpu_s_per_mquery']:9.2f}  {r['other_cores']}",
                      flush=True)
                contention[f"{arch}/{label}"] = {"other_cores": r["other_cores"]}

            res["batches"] = {}
            for b in batches:
                x, d, g = queries(b, rng)
                r = run_query(field, x, d, g, args.repeats)
                res["batches"][str(b)] = r
                show(f"batch 2^{b.bit_length() - 1}", r)

            nv = args.variant_batch
            x, d, g = queries(nv, rng)
            var: dict[str, Any] = {}
            for t in sorted({1, threads}):
                var[f"threads_{t}"] = r = run_query(load(path, threads=t), x, d, g, args.repeats)
                show(f"threads {t}", r)
            var["spinning"] = r = run_query(load(path, threads=threads, spinning=True), x, d, g, args.repeats)
            show("onnxruntime spinning", r)
            for t in sorted({1, threads}):
                var[f"pipeline_threads_{t}"] = r = run_query(load(path, threads=t, pipeline=True), x, d, g,
                                                             args.repeats)
                show(f"pipelined, {t} thread(s) each", r)
            for c in (1 << 12, 1 << 13, 1 << 15, 1 << 16):
                var[f"chunk_{c}"] = r = run_query(load(path, threads=threads, chunk=c), x, d, g, args.repeats)
                show(f"chunk 2^{c.bit_length() - 1}", r)
            i8 = load(path, threads=threads)
            i8.session = make_session(int8_mlp(path), "int8", threads, False)
            var["int8"] = r = run_query(i8, x, d, g, args.repeats)
            r["max_abs_err_Lprime"] = float(np.abs(i8.query_encoded(x[:65536], d[:65536], g[:65536])
                                                   - load(path, threads=threads).query_encoded(
                                                       x[:65536], d[:65536], g[:65536])).max())
            show("int8 MLP (not offered)", r)
            f16 = load(path, threads=threads)
            f16.session = make_session(fp16_mlp(path), "fp16", threads, False)
            var["fp16_mlp"] = r = run_query(f16, x, d, g, args.repeats)
            r["max_abs_diff_Lp"] = float(np.abs(f16.query_encoded(x[:4096], d[:4096], g[:4096])
                                                - field.query_encoded(x[:4096], d[:4096], g[:4096])).max())
            show("fp16 MLP", r)
            half = make_bundle(arch, folder, "float16")
            var["fp16_tables"] = r = run_query(load(half, threads=threads), x, d, g, args.repeats)
            show("fp16 tables", r)
            shutil.rmtree(half, ignore_errors=True)
            xr, dr, gr = queries(nv, rng, "rays")
            var["rays"] = r = run_query(field, xr, dr, gr, args.repeats)
            show("ray-ordered queries", r)
            res["variants"] = {"batch": nv, **var}
            res["stages"] = st = stages(field, x, d, g, args.repeats)
            print(f"  stages alone (s at 2^{nv.bit_length() - 1}): "
                  + ", ".join(f"{k} {v:.4f}" for k, v in st.items() if k not in ("queries_per_s_sum", "other_cores")))
            results[arch] = res
            del field, f16
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    info = finish_info(info, contention)
    write_report(args.out, "field", info, {"archs": archs, "batches": batches, "variant_batch": args.variant_batch,
                                           "threads": threads, "repeats": args.repeats, "seed": args.seed,
                                           "wall_s": round(time.perf_counter() - t_start, 1)},
                 archs=results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
