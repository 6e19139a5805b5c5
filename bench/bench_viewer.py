"""pfn-view (runtime/viewer) driven over its websocket, as a page would: start-up, frame rate while dragging and
input-to-image latency.

Starts ``pfn-view SCENE [--bundle B] --size WxH --no-browser`` as a child process (the real command, so start-up
includes imports, loading the scene and the bundle, and the kernels warming in the background) and connects to
its websocket like the page does. Per renderer (``--renderers``, default: neural when ``--bundle`` is given,
and pt):

- **dragging**: a sender thread sends an ``orbit`` message every ``1 / --input-hz`` s (default 60 Hz, a mouse
  drag) for ``--drag-seconds`` (default 8 s); frames/s is frames received over the window, and each frame's
  latency is its arrival minus the send time of the newest input it includes (its header's ``seq``);
- **at a reduced size** (``--drag-scales 1,0.5``): the drag and the moves from rest again, moving frames
  rendered at that fraction of the size (``pfn-view --drag-scale``);
- with the preview on a volume over 128 voxels a side, each change's first frame marches the volume's coarser
  level (``--interactive-level``, passed to ``pfn-view``; default auto, ``0`` for the full volume throughout);
- **first frame after a move**: ``--moves`` times (default 10), the camera rests for a random time between
  ``--rest`` and twice that (default 0.6 s; the view refines meanwhile, and the move lands at a random point of
  the frame in flight), then one ``orbit`` message; the time until the first frame that includes it.
  This is the issue's "<= 150 ms from input event to image" without the browser's JPEG decode and draw (a few ms
  for 512x512).

Goals (issue 15): >= 8 frames/s while dragging at 512x512 with the neural renderer at 1 spp per frame, on 2
cores; first frame after a camera move <= 150 ms. Also reported: the server's own per-frame split (render,
denoise, encode; medians), the cores the viewer process used and the foreign load during each phase (other
processes than the bench and the viewer; another busy process on the machine halves a 2-core figure).

    .venv/bin/python bench/bench_viewer.py --bundle /tmp/viewer_run/field.pfn            # ~1 min
    .venv/bin/python bench/bench_viewer.py --renderers pt --drag-seconds 4              # no bundle
    .venv/bin/python bench/bench_viewer.py --bundle RUN/field.pfn --renderers neural --drag-scales 1,auto --retrain 0.7

``--transfer NAME.pvrt`` adds the pvrt renderer (``pfn-view --transfer``): after its camera phases above, the same two
phases with the light instead of the camera (issue 18: relighting): a drag of light 0's azimuth slider (``light``
messages at ``--input-hz``) and single light changes from rest, each timed to the first frame that includes it;
the share of those frames relit from the kept camera samples (no march) is reported.

    .venv/bin/python bench/bench_viewer.py --transfer vortex.pvrt --renderers pvrt --drag-seconds 4 --moves 14

``--retrain SCALE`` (last): a transfer-function edit (every opacity times SCALE) as the page's editor sends it;
frames/s while dragging (at the last of ``--drag-scales``) during the background retrain, and the time from the
edit to the swapped-in field (issue 15: >= 4 frames/s at 512x512 while a retrain runs). A bundle inside its run
folder (``pfn-train all``'s ``RUN/field.pfn``) is fine-tuned with ``pfn-train update``, else trained afresh.

Output: a table on stdout and JSON (default ``bench/results/viewer.json``) with ``cpu_record()``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import random
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common import Contention, finish_info, machine_info, write_report
from websockets.sync.client import ClientConnection, connect

from photon_fields.runtime.eval.machine import cpu_record, resident_memory_mb

REPO = Path(__file__).resolve().parents[1]


def split(data: bytes) -> dict[str, Any]:
    n = struct.unpack(">I", data[:4])[0]
    return json.loads(data[4:4 + n])


class Client:
    """The page's side of the websocket: a reader thread timestamps every frame; ``send`` numbers inputs."""

    def __init__(self, url: str) -> None:
        self.ws: ClientConnection = connect(url, max_size=None, open_timeout=60)
        self.frames: queue.Queue[tuple[float, dict[str, Any]]] = queue.Queue()
        self.texts: queue.Queue[dict[str, Any]] = queue.Queue()
        self.sent: dict[int, float] = {}
        self.seq = 0
        self.lock = threading.Lock()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        try:
            for m in self.ws:
                now = time.perf_counter()
                if isinstance(m, bytes):
                    self.frames.put((now, split(m)))
                else:
                    self.texts.put(json.loads(m))
        except Exception:  # noqa: BLE001  (closed)
            return

    def send(self, msg: dict[str, Any]) -> int:
        with self.lock:
            self.seq += 1
            msg = {**msg, "seq": self.seq}
            self.sent[self.seq] = time.perf_counter()
            self.ws.send(json.dumps(msg))
            return self.seq

    def drain(self) -> None:
        while not self.frames.empty():
            self.frames.get_nowait()

    def wait_frame(self, pred: Any, timeout: float = 300.0) -> tuple[float, dict[str, Any]]:
        end = time.perf_counter() + timeout
        while True:
            t, h = self.frames.get(timeout=max(0.01, end - time.perf_counter()))
            if pred(h):
                return t, h

    def close(self) -> None:
        self.ws.close()


def process_cpu_seconds(pid: int) -> float | None:
    """CPU seconds (user + system, all threads) of process ``pid`` so far, from /proc (None elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Foreign:
    """Cores kept busy by processes other than this bench and the viewer it drives (``common.Contention``
    counts the viewer, a child process, as foreign)."""

    def __init__(self, pid: int) -> None:
        self.pid, self.contention = pid, Contention()
        self.other_cores: float | None = None
        self.viewer_cores: float | None = None

    def __enter__(self) -> Foreign:
        self.t, self.cpu = time.perf_counter(), process_cpu_seconds(self.pid)
        self.contention.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.contention.__exit__(*exc)
        wall, cpu = time.perf_counter() - self.t, process_cpu_seconds(self.pid)
        if cpu is not None and self.cpu is not None and wall > 0:
            self.viewer_cores = round((cpu - self.cpu) / wall, 3)
            if self.contention.other_cores is not None:
                self.other_cores = round(max(self.contention.other_cores - self.viewer_cores, 0.0), 3)


def median(xs: list[float]) -> float | None:
    return round(statistics.median(xs), 2) if xs else None


def p90(xs: list[float]) -> float | None:
    return round(sorted(xs)[int(0.9 * (len(xs) - 1))], 2) if xs else None


Input = Callable[[int], dict[str, Any]]


def orbit(step: float) -> Input:
    """The ``i``-th input of a camera drag: an orbit by ``step`` degrees."""
    return lambda i: {"type": "orbit", "dx": step, "dy": 0.0}


DRAG_ORBIT, MOVE_ORBIT = orbit(0.5), orbit(2.0)  # a mouse drag's step, a single move's


def turn_light(step: float) -> Input:
    """The ``i``-th input of a light drag: light 0's azimuth slider, ``step`` degrees a message from where the scene
    has it (wrapping at 180, as the page's slider cannot but the message allows)."""
    base = STATE["lights"][0]["azimuth"]
    return lambda i: {"type": "light", "index": 0, "azimuth": round((base + step * (i + 1) + 180) % 360 - 180, 3)}


def drag(client: Client, seconds: float, hz: float, pid: int, make: Input = DRAG_ORBIT) -> dict[str, Any]:
    """Inputs (``make(i)``; default: orbit messages) at ``hz`` for ``seconds``; frames/s and per-frame latency
    (arrival - newest input sent)."""
    stop = threading.Event()

    def sender() -> None:
        period = 1.0 / hz
        nxt = time.perf_counter()
        i = 0
        while not stop.is_set():
            client.send(make(i))
            i += 1
            nxt += period
            time.sleep(max(0.0, nxt - time.perf_counter()))

    client.drain()
    with Foreign(pid) as load:
        t0 = time.perf_counter()
        thread = threading.Thread(target=sender, daemon=True)
        thread.start()
        arrivals, lat, headers = [], [], []
        while time.perf_counter() - t0 < seconds:
            try:
                t, h = client.frames.get(timeout=1.0)
            except queue.Empty:
                continue
            if h["seq"] is None or t - t0 < 0.5:  # skip the first half second (the drag starting)
                continue
            arrivals.append(t)
            headers.append(h)
            lat.append((t - client.sent[h["seq"]]) * 1e3)
        stop.set()
        thread.join()
    span = arrivals[-1] - arrivals[0] if len(arrivals) > 1 else float("nan")
    return {"frames_per_s": round((len(arrivals) - 1) / span, 2) if len(arrivals) > 1 else 0.0,
            "frames": len(arrivals), "latency_ms_median": median(lat), "latency_ms_p90": p90(lat),
            "spp_max": max((h["spp"] for h in headers), default=None), **relit_share(headers),
            "server_ms_median": {k: median([h[k] for h in headers if k in h])
                                 for k in ("render_ms", "denoise_ms", "encode_ms", "total_ms")},
            "other_cores": load.other_cores, "viewer_cores": load.viewer_cores}


def relit_share(headers: list[dict[str, Any]]) -> dict[str, Any]:
    """For pvrt frames: how many were relit from kept camera samples (no march); nothing for other renderers."""
    pvrt = [h["pvrt"] for h in headers if h.get("pvrt")]
    return {"relit_frames": sum(p["relit"] for p in pvrt), "pvrt_frames": len(pvrt)} if pvrt else {}


def first_after_move(client: Client, moves: int, rest: float, pid: int, make: Input = MOVE_ORBIT) -> dict[str, Any]:
    """From rest: one input (``make(i)``; default: an orbit message), then the time to the first frame that
    includes it."""
    lat, headers = [], []
    rng = random.Random(1)
    with Foreign(pid) as load:
        for i in range(moves):
            # A random rest in [rest, 2 rest]: a fixed one would send every move at the same phase of the frame
            # in flight, and the latency would depend on that phase rather than on the viewer.
            time.sleep(rest * (1.0 + rng.random()))
            client.drain()
            seq = client.send(make(i))
            t, h = client.wait_frame(lambda h, s=seq: h["seq"] is not None and h["seq"] >= s)
            lat.append((t - client.sent[seq]) * 1e3)
            headers.append(h)
    return {"latency_ms": [round(x, 1) for x in lat], "latency_ms_median": median(lat), "latency_ms_p90": p90(lat),
            "server_ms_median": {k: median([h[k] for h in headers if k in h]) for k in ("render_ms", "total_ms")},
            **relit_share(headers), "other_cores": load.other_cores, "viewer_cores": load.viewer_cores}


def retrain_cycle(client: Client, scale: float, seconds: float, hz: float, pid: int) -> dict[str, Any]:
    """A transfer-function edit (every opacity times ``scale``) as the page's editor sends it, then: dragging while
    the background retrain runs (issue 15: >= 4 frames/s), and the edit cycle, from the edit to the ``done``
    message of the swapped-in field, and the first frame after it (no longer stale)."""
    while not client.texts.empty():
        client.texts.get_nowait()
    points = [{**p, "opacity": min(1.0, p["opacity"] * scale)} for p in STATE["transfer"]["points"]]
    t_edit = time.perf_counter()
    client.send({"type": "transfer", "points": points, "density_scale": STATE["transfer"]["density_scale"]})
    statuses: list[dict[str, Any]] = []

    def wait_status(states: set[str], timeout: float = 1800.0) -> dict[str, Any]:
        end = time.perf_counter() + timeout
        while True:
            m = client.texts.get(timeout=max(0.01, end - time.perf_counter()))
            if m.get("type") == "retrain":
                statuses.append({**m, "t_s": round(time.perf_counter() - t_edit, 2)})
                if m["state"] in states:
                    return m

    wait_status({"running"})
    while True:  # the job has loaded torch and is tracing or fitting
        m = wait_status({"running", "failed"})
        if m["state"] == "failed" or m.get("stage") in ("trace", "fit"):
            break
    d = drag(client, seconds, hz, pid) if m["state"] == "running" else None
    done = wait_status({"done", "failed", "cancelled", "unavailable"})
    cycle = time.perf_counter() - t_edit
    _, h = client.wait_frame(lambda h: not h.get("stale", False))
    return {"drag_while_retraining": d, "state": done["state"], "message": done.get("message"),
            "edit_cycle_s": round(cycle, 1), "server_cycle_s": done.get("cycle_s"),
            "first_frame_after": {k: h.get(k) for k in ("renderer", "stale", "spp")},
            "statuses": [{k: st.get(k) for k in ("state", "stage", "fraction", "t_s")} for st in statuses]}


STATE: dict[str, Any] = {}


def soak(client: Client, seconds: float, pid: int) -> dict[str, Any]:
    """A long session (issue 15: memory stays bounded over 10 minutes): cycles of a 2 s drag at 30 Hz, a zoom, a
    g change, a layer change, an exposure change and a rest of 3 s, for ``seconds``; the viewer's resident memory
    sampled every cycle. Reported: first, largest and last RSS, and the growth over the second half (a leak grows
    steadily; caches settle in the first minutes)."""
    t0, samples, cycle = time.perf_counter(), [], 0
    while time.perf_counter() - t0 < seconds:
        end = time.perf_counter() + 2.0
        while time.perf_counter() < end:
            client.send({"type": "orbit", "dx": 1.5, "dy": 0.2 * math.sin(cycle)})
            time.sleep(1 / 30)
        client.send({"type": "zoom", "factor": 0.97 if cycle % 2 else 1.03})
        client.send({"type": "set", "control": "g", "value": round(0.5 * math.sin(cycle / 3), 2)})
        client.send({"type": "set", "control": "layer", "value": ("L", "L_i", "L_d")[cycle % 3]})
        client.send({"type": "set", "control": "exposure", "value": 0.1 * (cycle % 5)})
        time.sleep(3.0)
        client.drain()
        while not client.texts.empty():
            client.texts.get_nowait()
        samples.append((round(time.perf_counter() - t0, 1), resident_memory_mb(pid)))
        cycle += 1
    rss = [m for _, m in samples if m is not None]
    half = [m for t, m in samples if m is not None and t >= seconds / 2]
    return {"seconds": seconds, "cycles": cycle, "rss_mb_first": rss[0] if rss else None,
            "rss_mb_max": max(rss, default=None), "rss_mb_last": rss[-1] if rss else None,
            "rss_mb_growth_second_half": round(half[-1] - half[0], 1) if len(half) > 1 else None,
            "samples": samples}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", default="vortex")
    p.add_argument("--bundle", default=None, help="a bundle of the scene (enables the neural renderer)")
    p.add_argument("--transfer", default=None, help="a PVRT transfer of the scene (enables the pvrt renderer and its "
                   "light phases)")
    p.add_argument("--renderers", default=None, help="comma list of neural, pt, preview, pvrt (default: neural if "
                   "--bundle, pt)")
    p.add_argument("--size", default="512x512")
    p.add_argument("--drag-scales", default="1",
                   help="comma list of drag scales to measure dragging at (pfn-view --drag-scale; 1: full size, "
                        "always measured first; auto: the size chosen for ~8 frames/s)")
    p.add_argument("--drag-seconds", type=float, default=8.0)
    p.add_argument("--input-hz", type=float, default=60.0)
    p.add_argument("--moves", type=int, default=10)
    p.add_argument("--rest", type=float, default=0.6)
    p.add_argument("--interactive-level", default="auto",
                   help="pfn-view's --interactive-level (the preview's volume level for each change's first frame)")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--retrain", type=float, default=None, metavar="SCALE",
                   help="last: a transfer-function edit (opacities times SCALE, e.g. 0.7) and its background retrain: "
                        "frames/s dragging meanwhile and the edit-to-new-field time (needs the train extra)")
    p.add_argument("--retrain-photons", default="1M")
    p.add_argument("--soak", type=float, default=None, metavar="SECONDS",
                   help="last: a long session of drags, zooms and control changes; the viewer's memory over it")
    p.add_argument("--out", default=str(REPO / "bench" / "results" / "viewer.json"))
    args = p.parse_args()
    renderers = args.renderers.split(",") if args.renderers else ((["neural"] if args.bundle else []) + ["pt"]
                                                                   + (["pvrt"] if args.transfer else []))
    scales: list[float | str] = [x if x == "auto" else float(x) for x in args.drag_scales.split(",")]
    if "neural" in renderers and not args.bundle:
        raise SystemExit("the neural renderer needs --bundle")
    if "pvrt" in renderers and not args.transfer:
        raise SystemExit("the pvrt renderer needs --transfer")
    info = machine_info()
    view = [sys.executable, "-m", "photon_fields.runtime.viewer.cli", args.scene, "--size", args.size, "--no-browser",
            "--quiet", "--drag-scale", "1", "--interactive-level", args.interactive_level,
            "--out", tempfile.mkdtemp(prefix="bench_viewer_")]
    if args.bundle:
        view += ["--bundle", args.bundle]
    if args.transfer:
        view += ["--transfer", args.transfer]
    if args.threads:
        view += ["--threads", str(args.threads)]
    view += ["--retrain-photons", args.retrain_photons]
    t_spawn = time.perf_counter()
    proc = subprocess.Popen(view, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    results: dict[str, Any] = {}
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        if "http://" not in line:
            raise SystemExit(f"pfn-view did not print its address: {line!r}")
        url = line.split()[1].replace("http://", "ws://") + "ws"
        t_address = time.perf_counter() - t_spawn
        client = Client(url)
        STATE.update(client.texts.get(timeout=60))  # the page's controls, the transfer function among them
        t_first, _ = client.wait_frame(lambda h: True)
        startup = {"address_printed_s": round(t_address, 2), "first_frame_s": round(t_first - t_spawn, 2)}
        print(f"start-up: address after {startup['address_printed_s']} s, first frame after "
              f"{startup['first_frame_s']} s")
        for name in renderers:
            client.send({"type": "set", "control": "renderer", "value": name})
            client.wait_frame(lambda h, n=name: h["renderer"] == n and h["spp"] >= (1 if n == "pvrt" else 2))
            d = drag(client, args.drag_seconds, args.input_hz, proc.pid)
            m = first_after_move(client, args.moves, args.rest, proc.pid)
            results[name] = {"drag": d, "first_frame_after_move": m}
            for scale in scales:
                if scale == 1.0:
                    continue
                client.send({"type": "set", "control": "drag_scale", "value": scale})
                ds = drag(client, args.drag_seconds, args.input_hz, proc.pid)
                ms = first_after_move(client, args.moves, args.rest, proc.pid)
                results[name][f"drag_at_scale_{scale}"] = ds
                results[name][f"first_frame_after_move_at_scale_{scale}"] = ms
                print(f"{name:7s} dragging at {scale} of the size: {ds['frames_per_s']:5.1f} frames/s (input->image "
                      f"median {ds['latency_ms_median']} ms; server per frame {ds['server_ms_median']}); first frame "
                      f"after a move: median {ms['latency_ms_median']} ms, p90 {ms['latency_ms_p90']} ms")
            client.send({"type": "set", "control": "drag_scale", "value": 1.0})
            print(f"{name:7s} dragging: {d['frames_per_s']:5.1f} frames/s (input->image median "
                  f"{d['latency_ms_median']} ms, p90 {d['latency_ms_p90']} ms; server per frame "
                  f"{d['server_ms_median']}; other cores {d['other_cores']})")
            print(f"{name:7s} first frame after a move: median {m['latency_ms_median']} ms, p90 "
                  f"{m['latency_ms_p90']} ms (other cores {m['other_cores']})")
            if name == "pvrt":  # relighting: the light moves, the camera rests
                results[name]["light_drag"] = ld = drag(client, args.drag_seconds, args.input_hz, proc.pid,
                                                        turn_light(1.0))
                results[name]["first_frame_after_light_change"] = lm = first_after_move(
                    client, args.moves, args.rest, proc.pid, turn_light(15.0))
                print(f"pvrt    dragging the light: {ld['frames_per_s']:5.1f} frames/s (input->image median "
                      f"{ld['latency_ms_median']} ms, p90 {ld['latency_ms_p90']} ms; server per frame "
                      f"{ld['server_ms_median']}; relit {ld.get('relit_frames')} of {ld.get('pvrt_frames')}; other "
                      f"cores {ld['other_cores']})")
                print(f"pvrt    first frame after a light change: median {lm['latency_ms_median']} ms, p90 "
                      f"{lm['latency_ms_p90']} ms (server {lm['server_ms_median']}; relit {lm.get('relit_frames')} of "
                      f"{lm.get('pvrt_frames')}; other cores {lm['other_cores']})")
        if args.retrain is not None:
            client.send({"type": "set", "control": "renderer", "value": renderers[0]})
            client.send({"type": "set", "control": "drag_scale", "value": scales[-1]})  # the last one measured
            r = retrain_cycle(client, args.retrain, args.drag_seconds, args.input_hz, proc.pid)
            results["retrain"] = {**r, "drag_scale": scales[-1]}
            d = r["drag_while_retraining"] or {}
            print(f"retrain after a transfer-function edit: {r['state']} ({r['message']}); edit to new field "
                  f"{r['edit_cycle_s']} s; dragging meanwhile {d.get('frames_per_s')} frames/s (input->image median "
                  f"{d.get('latency_ms_median')} ms); first frame after: {r['first_frame_after']}")
        if args.soak is not None:
            r = soak(client, args.soak, proc.pid)
            results["soak"] = r
            print(f"soak: {r['cycles']} cycles in {r['seconds']:.0f} s; viewer RSS first {r['rss_mb_first']:.0f} MB, "
                  f"max {r['rss_mb_max']:.0f} MB, last {r['rss_mb_last']:.0f} MB, growth over the second half "
                  f"{r['rss_mb_growth_second_half']} MB")
        client.close()
    finally:
        proc.terminate()
        proc.wait(30)
    config = {"scene": args.scene, "bundle": args.bundle, "transfer": args.transfer, "size": args.size,
              "renderers": renderers,
              "drag_seconds": args.drag_seconds, "input_hz": args.input_hz, "moves": args.moves, "rest_s": args.rest,
              "threads": args.threads, "drag_scales": scales, "retrain": args.retrain,
              "interactive_level": args.interactive_level,
              "retrain_photons": args.retrain_photons, "soak_s": args.soak}
    phases = {f"{n}.{k}": v for n, r in results.items() if n not in ("retrain", "soak") for k, v in r.items()}
    write_report(Path(args.out), "viewer", {**finish_info(info, phases), "cpu_record": cpu_record()}, config,
                 startup=startup, results=results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
