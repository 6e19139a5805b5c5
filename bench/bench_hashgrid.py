"""Hash-grid encoding speed: forward and forward + backward of train.field.hashgrid.HashGridEncoding on the CPU.

Training (paper Sec. 3.5) evaluates the position (D=3) and direction (D=2) encodings of every batch and
back-propagates into their tables, so both directions matter. For each configuration below, ``--points``
uniform random points in [0, 1]^D are encoded; timed are

- ``corners``: the corner rows and weights alone (``HashGridEncoding.corners``, numba);
- ``forward``: ``enc(x)`` (corners + the fma gather);
- ``forward_backward``: ``enc(x).backward(g)`` from ``table.grad = None`` (so the gradient's allocation and
  zeroing count, as with ``zero_grad(set_to_none=True)``); ``backward`` = the difference.

Configurations: the paper's two (16 levels x 8 features, 2^19 tables, N_min 16, scale 2) and D=3 variants
with 8 / 12 levels, 2 / 4 features and 2^14 / 2^16 tables (one knob changed at a time).

Baseline (``torch_embedding_bag``, paper D=3 only, unless ``--no-baseline``): the same encoding in pure
torch, the index math in int64 tensors (uint32 wrap by masking, the float32 fma as float64 + round-to-odd)
and ``F.embedding_bag(..., per_sample_weights, mode="sum")`` with its dense autograd backward. Its output
is checked to be bit-identical to the module's (``baseline_matches``), so the two time the same function.

Every figure is the best of ``--repeats`` runs after one warm-up (numba kernels are compiled or loaded from
their cache there). Numba and torch both get ``--threads`` threads. Run on an idle machine: other processes
on the 2 cores slow the numba kernels (they synchronize per call) more than anything else; the load
average before and after and the cores other processes kept busy (``other_cores``) are recorded.

Parameters (command line)
-------------------------
--points N    points per call (default 2**16); figures are also given per 2^16 points
--repeats R   timed repetitions, best kept (default 5)
--threads T   numba and torch threads (default 2)
--no-baseline skip the pure-torch baseline (~20 s)
--seed S      data seed (default 0)
--out PATH    JSON output (default bench/results/hashgrid.json next to this script)

Output: a table on stdout and JSON with ``machine``, ``config`` and per configuration name: the
HashGridConfig, ``table_rows``, ``times_ms`` (every run per stage), ``best_ms``, ``per_2_16_ms`` and
``other_cores``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch

# bench/ is on sys.path when this file is run as a script, so the sibling module imports directly.
from common import Contention, load_average, machine_info

from photon_fields.models_spec.hashgrid import HASH_PRIMES, PAPER_DIRECTION, PAPER_POSITION, HashGridConfig, level_specs
from photon_fields.train.field.hashgrid import HashGridEncoding

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "hashgrid.json"
CONFIGS: dict[str, HashGridConfig] = {
    "paper_position_D3": PAPER_POSITION,
    "paper_direction_D2": PAPER_DIRECTION,
    "D3_L8": HashGridConfig(3, 8, 8, 19, 16, 2.0),
    "D3_L12": HashGridConfig(3, 12, 8, 19, 16, 2.0),
    "D3_F2": HashGridConfig(3, 16, 2, 19, 16, 2.0),
    "D3_F4": HashGridConfig(3, 16, 4, 19, 16, 2.0),
    "D3_T14": HashGridConfig(3, 16, 8, 14, 16, 2.0),
    "D3_T16": HashGridConfig(3, 16, 8, 16, 16, 2.0),
}
MASK = 0xFFFFFFFF


class TorchEmbeddingBagGrid:
    """The pure-torch scheme: index math on (n, L, D) / (n, L, 2^D) tensors, then one embedding_bag."""

    def __init__(self, enc: HashGridEncoding) -> None:
        cfg = enc.cfg
        specs = level_specs(cfg)
        self.cfg, self.table = cfg, enc.table
        self.scales = torch.tensor([float(s.scale) for s in specs], dtype=torch.float64)
        self.hashed = torch.tensor([s.hashed for s in specs])
        self.mult = torch.tensor([[int(HASH_PRIMES[d]) if s.hashed else s.dense_strides[d] for d in range(cfg.dims)]
                                  for s in specs], dtype=torch.int64)
        self.sizes = torch.tensor([s.table_size for s in specs], dtype=torch.int64)
        self.offsets = torch.tensor([s.offset for s in specs], dtype=torch.int64)

    @staticmethod
    def fma_f32(a: torch.Tensor, b: torch.Tensor, c: float) -> torch.Tensor:
        # float64 product is exact; the sum is rounded to odd (TwoSum error) before the float32 rounding.
        p = a * b
        s = p + c
        bb = s - p
        err = (p - (s - bb)) + (c - bb)
        fix = (err != 0) & ((s.view(torch.int64) & 1) == 0)
        s = torch.where(fix, torch.nextafter(s, torch.copysign(torch.full_like(s, float("inf")), err)), s)
        return s.to(torch.float32)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        cfg = self.cfg
        n, L, D = x.shape[0], cfg.levels, cfg.dims
        K = 1 << D
        pos = self.fma_f32(self.scales[:, None], x.double()[:, None, :], 0.5)  # (n, L, D)
        cell = torch.floor(pos)
        frac = pos - cell
        c = (cell.to(torch.int64).unsqueeze(-1) + torch.tensor([0, 1])) & MASK  # (n, L, D, 2)
        t = (c * self.mult[:, :, None]) & MASK
        # Corner j = bits (b_{D-1} .. b_0): dimension 0 is the last (fastest) axis.
        hx, ad = t[:, :, 0], t[:, :, 0]
        for d in range(1, D):
            shape_t = (n, L) + (2,) + (1,) * d
            shape_acc = (n, L) + (1,) + (2,) * d
            hx = t[:, :, d].reshape(shape_t) ^ hx.reshape(shape_acc)
            ad = t[:, :, d].reshape(shape_t) + ad.reshape(shape_acc)
        h = self.hashed.view((L,) + (1,) * D)
        idx = torch.where(h, hx, ad & MASK) % self.sizes.view((L,) + (1,) * D) + self.offsets.view((L,) + (1,) * D)
        W = torch.stack([1 - frac, frac], dim=-1)  # (n, L, D, 2)
        w = W[:, :, 0]
        for d in range(1, D):
            w = W[:, :, d].reshape((n, L) + (2,) + (1,) * d) * w.reshape((n, L) + (1,) + (2,) * d)
        out = torch.nn.functional.embedding_bag(idx.reshape(n * L, K), self.table,
                                                per_sample_weights=w.reshape(n * L, K), mode="sum")
        return out.view(n, L * cfg.features)


def best_of(fn: Callable[[], Any], repeats: int) -> list[float]:
    fn()  # warm-up: numba compile / cache load, first-touch of buffers
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return times


def time_encoder(encode: Callable[[torch.Tensor], torch.Tensor], table: torch.Parameter, x: torch.Tensor,
                 g: torch.Tensor, repeats: int, corners: Callable[[], Any] | None) -> dict[str, list[float]]:
    def fwd_bwd() -> None:
        table.grad = None
        encode(x).backward(g)

    times: dict[str, list[float]] = {}
    if corners is not None:
        times["corners"] = best_of(corners, repeats)
    with torch.no_grad():
        times["forward"] = best_of(lambda: encode(x), repeats)
    times["forward_backward"] = best_of(fwd_bwd, repeats)
    table.grad = None
    return times


def summarize(times: dict[str, list[float]], points: int) -> dict[str, Any]:
    best = {k: round(min(v), 2) for k, v in times.items()}
    best["backward"] = round(best["forward_backward"] - best["forward"], 2)
    per = {k: round(v * 2**16 / points, 2) for k, v in best.items()}
    return {"times_ms": {k: [round(t, 2) for t in v] for k, v in times.items()}, "best_ms": best, "per_2_16_ms": per}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=2**16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    if args.points < 1 or args.repeats < 1 or args.threads < 1:
        ap.error("--points, --repeats and --threads must be >= 1")

    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    torch.set_num_threads(args.threads)
    info = machine_info()
    info.update(torch=torch.__version__, torch_threads=torch.get_num_threads())
    rng = np.random.default_rng(args.seed)
    results: dict[str, dict[str, Any]] = {}

    print(f"{'config':20s} {'rows':>9s} {'corners':>9s} {'forward':>9s} {'backward':>9s} {'fwd+bwd':>9s}  "
          "(ms per 2^16 points, best of {})".format(args.repeats))
    for name, cfg in CONFIGS.items():
        enc = HashGridEncoding(cfg, seed=args.seed)
        x = torch.from_numpy(rng.random((args.points, cfg.dims), dtype=np.float32))
        g = torch.from_numpy(rng.standard_normal((args.points, cfg.output_dims), dtype=np.float32))
        with Contention() as busy:
            times = time_encoder(enc, enc.table, x, g, args.repeats, lambda enc=enc, x=x: enc.corners(x))
        res = {"hashgrid_config": cfg.to_dict(), "table_rows": int(enc.table.shape[0]), **summarize(times, args.points),
               "other_cores": busy.other_cores}
        p = res["per_2_16_ms"]
        print(f"{name:20s} {res['table_rows']:9d} {p['corners']:9.1f} {p['forward']:9.1f} {p['backward']:9.1f} "
              f"{p['forward_backward']:9.1f}")

        if name == "paper_position_D3" and not args.no_baseline:
            base = TorchEmbeddingBagGrid(enc)
            with torch.no_grad():
                matches = bool(torch.equal(base(x), enc(x)))
            with Contention() as busy:
                btimes = time_encoder(base, enc.table, x, g, max(1, min(args.repeats, 2)), None)
            bres = summarize(btimes, args.points)
            res["baseline_torch_embedding_bag"] = {**bres, "baseline_matches": matches, "other_cores": busy.other_cores}
            p = bres["per_2_16_ms"]
            print(f"{'  torch+embedding_bag':20s} {'':9s} {'':>9s} {p['forward']:9.1f} {p['backward']:9.1f} "
                  f"{p['forward_backward']:9.1f}  (bit-identical output: {matches})")
        results[name] = res
        del enc

    usable = info.get("usable_cores") or 1
    busy_runs = {k: r["other_cores"] for k, r in results.items() if (r["other_cores"] or 0) > 0.5 * usable}
    if busy_runs:
        print(f"warning: other processes kept cores busy during {busy_runs} (cores, of {usable}): "
              "those figures are pessimistic")
    info.update(load_avg_end=load_average(), machine_busy=bool(busy_runs),
                numba_threading_layer=numba.threading_layer())
    payload = {"machine": info,
               "config": {"points": args.points, "repeats": args.repeats, "threads": args.threads,
                          "seed": args.seed, "baseline": not args.no_baseline},
               "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
