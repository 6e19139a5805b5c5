"""Small inputs for the viewer tests: a 32^3 scene at a tiny frame size and an analytic stand-in for a photon
field's estimator (no torch, no training: the session logic is what these tests check)."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path
from typing import Any

import numpy as np
from conftest import tiny_scene_dict

from photon_fields.runtime.scene.scene import Scene, scene_from_dict
from photon_fields.runtime.viewer.launch import ViewerInputs
from photon_fields.runtime.viewer.messages import Message, validate
from photon_fields.runtime.viewer.retrain import RetrainSettings
from photon_fields.runtime.viewer.session import ViewerSession

SIZE = 24


def tiny_scene(size: int = SIZE) -> Scene:
    return scene_from_dict(tiny_scene_dict("blobs")).with_overrides(width=size, height=size)


#: The label scene's labels: background, a ball on the left, a cube on the right (side by side in the view).
BACKGROUND, BALL, CUBE = 0, 3, 7


def label_scene_file(folder: Path, size: int = SIZE) -> Path:
    """A label scene file in ``folder``: a 32^3 segmentation (``seg.npy``, uint8) of :data:`BACKGROUND`, a ball of
    :data:`BALL` and a cube of :data:`CUBE`, with ``{"preset": "labels"}`` (background transparent, each object its
    own colour) and a light from the camera's side, viewed at ``size`` x ``size``."""
    folder.mkdir(parents=True, exist_ok=True)
    x, y, z = np.meshgrid(*(np.arange(32) + 0.5,) * 3, indexing="ij")
    seg = np.full((32, 32, 32), BACKGROUND, np.uint8)
    seg[(x - 9) ** 2 + (y - 16) ** 2 + (z - 16) ** 2 < 7.5**2] = BALL
    seg[(abs(x - 24) < 6) & (abs(y - 16) < 6) & (abs(z - 16) < 6)] = CUBE
    np.save(folder / "seg.npy", seg)
    scene = {"name": "seg", "volume": {"path": "seg.npy"}, "transfer_function": {"preset": "labels"},
             "lights": [{"type": "directional", "direction": [-0.3, -0.5, -1.0], "power": 3.0}],
             "camera": {"eye": [0.0, 0.3, 1.6], "target": [0, 0, 0], "fov": 40, "width": size, "height": size}}
    path = folder / "seg.json"
    path.write_text(json.dumps(scene))
    return path


def label_scene(folder: Path, size: int = SIZE) -> Scene:
    """:func:`label_scene_file`'s scene, loaded as ``pfn-view`` loads it."""
    from photon_fields.runtime.scene.scene import load_scene

    return load_scene(label_scene_file(folder, size))


class AnalyticField:
    """Q(x, d, g) = (0.2 + 0.3 (1 + x_y)) (1 + 0.8 g d_x) per channel (tinted): smooth, positive, and different
    for every g, so a frame at another g must differ."""

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        base = (0.2 + 0.3 * (1.0 + x[1])) * (1.0 + 0.8 * g * d[0])
        return (np.stack([base, 0.8 * base, 0.6 * base]) * 0.5).astype(np.float32)


def tiny_transfer(scene: Scene) -> Any:
    """A PVRT transfer of ``scene`` that takes a fraction of a second: 12 basis lights, an 8^3 grid, 500 paths each,
    2 CPCA clusters (coarse L_i, but every frame of it is as exact a function of the lights as a real one's)."""
    from photon_fields.runtime.pvrt.transfer import precompute_transfer

    return precompute_transfer(scene, order=0, grid=8, paths=500, clusters=2, seed=0, progress=False)


def msg(kind: str, **fields: Any) -> Message:
    return validate({"type": kind, **fields})


def make_session(out_dir: Path, renderer: str = "neural", size: int = SIZE, scene: Scene | None = None,
                 **kw: Any) -> ViewerSession:
    """A session on ``scene`` (default: :func:`tiny_scene`) with the analytic field as its neural renderer's."""
    return ViewerSession(scene or tiny_scene(size), estimator=AnalyticField(), out_dir=out_dir, seed=5, width=size,
                         height=size, renderer=renderer, **kw)


def inputs(out_dir: Path, size: int = SIZE, renderer: str | None = "pt", scene: Scene | None = None,
           transfer: Any = None) -> ViewerInputs:
    """What ``pfn-view`` would load for ``scene`` (default: :func:`tiny_scene`) with the analytic field (and a PVRT
    ``transfer`` of it, if given)."""
    sc = scene or tiny_scene(size)
    return ViewerInputs(sc, AnalyticField(), None, out_dir, 5, size, size, renderer, {"bundle": None, "map": None},
                        transfer=transfer)


def split_frame(data: bytes) -> tuple[dict[str, Any], bytes]:
    """A binary frame message -> (header, image bytes)."""
    n = struct.unpack(">I", data[:4])[0]
    return json.loads(data[4:4 + n]), data[4 + n:]


# A stand-in for pfn-train: takes its arguments, writes its progress file, and fails or sleeps as told.
STAND_IN = '''
import json, sys, time
from pathlib import Path
from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.io.progress import ProgressFile
args = sys.argv[1:]
opt = lambda name: args[args.index(name) + 1]
mode = opt("--mode") if "--mode" in args else "slow"
atomic_write_text(Path(opt("--progress-file")).with_name("argv.json"), json.dumps(args))  # tests poll for it
pf = ProgressFile(opt("--progress-file"), ("trace", "fit", "export"), min_interval=0)
pf.update("trace", 1, 2)
if mode == "fail":
    print("error: --photons: too few photons for this scene", flush=True)
    pf.finish("failed", "error: --photons: too few photons for this scene")
    sys.exit(2)
if mode == "linger":  # done (a bundle folder and a done progress file), then a slow exit
    (Path(opt("--out")) / "field.pfn").mkdir(parents=True)
    pf.finish("done", "bundle written")
    time.sleep(4)
    sys.exit(0)
if mode == "crash":
    print("Segmentation fault (pretend)", flush=True)
    sys.exit(3)
pf.update("fit", 5, 10)
time.sleep(120)
'''


def stand_in_trainer(tmp_path: Path, mode: str, delay_s: float = 0.0) -> RetrainSettings:
    """Retrain settings whose trainer is :data:`STAND_IN` in ``mode``: slow (reports trace, then fit at 50 %, then
    sleeps), fail (a one-line error, exit 2), crash (exit 3 with nothing in the progress file) or linger (done, then 4 s
    before it exits). It writes the
    arguments it was given to ``argv.json`` beside its progress file (``pfn-train update`` takes no ``--mode``:
    slow)."""
    script = tmp_path / "trainer.py"
    script.write_text(STAND_IN)
    return RetrainSettings(command=(sys.executable, str(script)), extra=("--mode", mode), delay_s=delay_s)
