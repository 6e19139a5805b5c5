"""Shared fixtures: small analytic media and scenes."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np  # noqa: E402
import pytest
from hypothesis import settings

from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import build_medium

# No deadline for any property test: a deadline is a timed assertion, and on a busy 2-core machine one example's
# first call (numba dispatch, imports) took 393 ms against hypothesis's default 200 ms.
settings.register_profile("photon-fields", deadline=None)
settings.load_profile("photon-fields")

#: The repository's root (the tests live in tests/<package>/...).
REPO = Path(__file__).resolve().parents[1]

# The console scripts the tests run never hand their work to a developer's resident render server (pfn-resident):
# a folder that cannot exist. The tests of the server start their own (tests/runtime/cli/test_resident.py).
os.environ["PFN_RESIDENT_DIR"] = os.path.join(os.devnull, "photon-fields-resident")


def constant_tf(sigma: float, albedo: float | tuple[float, float, float] = 1.0) -> TransferFunction:
    """Extinction ``sigma`` and ``albedo`` wherever the normalized scalar is 1 (linear ramp from 0)."""
    a = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (3,))
    return TransferFunction(np.array([0.0, 1.0]), np.stack([a, a]), np.array([0.0, 1.0]), sigma, "test")


#: Albedo rows at normalized density 0, 0.5, 1 of :func:`coloured_tf`: every channel differs and each varies
#: with density, so a dropped, swapped or misplaced albedo factor changes the per-channel means (by 11-92 %
#: when the camera vertex's albedo is dropped, tests/runtime/photons/test_light_kinds.py).
COLOURED_ALBEDO = np.array([[0.35, 0.6, 0.9], [0.9, 0.45, 0.7], [0.97, 0.9, 0.3]])


def coloured_tf(sigma: float = 8.0) -> TransferFunction:
    """Extinction ramping linearly to ``sigma`` at normalized density 1, with the coloured, density-dependent
    albedo :data:`COLOURED_ALBEDO`."""
    return TransferFunction(np.array([0.0, 0.5, 1.0]), COLOURED_ALBEDO, np.array([0.0, 0.5, 1.0]), sigma, "coloured")


def smooth_field(n: int = 24) -> np.ndarray:
    """A smooth heterogeneous field in [0.1, 1] (no empty space, gentle gradients)."""
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return 0.55 + 0.45 * np.sin(2.0 * np.pi * X) * np.cos(3.0 * np.pi * Y) * np.sin(np.pi * Z + 0.3)


@pytest.fixture(scope="session")
def homogeneous_medium():  # noqa: ANN201
    vol = make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0))
    return build_medium(vol, constant_tf(3.0))


@pytest.fixture(scope="session")
def smooth_volume():  # noqa: ANN201
    return make_volume(smooth_field(), window=(0.0, 1.0), name="smooth")


def small_camera(size: int = 24, fov: float = 30.0) -> Camera:
    return Camera([0.3, 0.4, 2.4], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], fov, size, size)


def tiny_scene_dict(name: str = "blobs") -> dict:
    return {"name": f"{name}32", "volume": {"builtin": name, "resolution": 32},
            "transfer_function": {"preset": "cloud" if name == "blobs" else name},
            "lights": [{"type": "directional", "direction": [-0.5, -0.8, 0.3], "color": [1, 0.95, 0.85],
                        "power": 3.0}],
            "camera": {"eye": [1.25, 0.75, 1.45], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 38,
                       "width": 32, "height": 32}}


#: pfn-train fit options of a run that takes seconds (the CLI tests' runs).
TINY_FIT = ["--preset", "tiny", "--steps", "3", "--batch", "256", "--k", "32", "--quiet"]


@pytest.fixture(scope="module")
def tiny_scene_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """:func:`tiny_scene_dict` written as a scene file (one per test module)."""
    path = tmp_path_factory.mktemp("scene") / "blobs32.json"
    path.write_text(json.dumps(tiny_scene_dict()))
    return path


# ----------------------------------------------------------------------------------------------------------
# The Henyey-Greenstein cosine distribution in closed form (chi-square tests of the samplers)


def hg_cdf(g: float, mu: np.ndarray) -> np.ndarray:
    """Closed-form CDF of the HG scattering cosine: integral of 2 pi p_g over [-1, mu]."""
    if abs(g) < 1e-9:
        return (mu + 1) / 2
    return (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * mu) - 1 / (1 + g))


def equal_probability_edges(g: float, bins: int) -> np.ndarray:
    """Bin edges in the scattering cosine holding equal HG probability (the CDF inverted numerically)."""
    # Invert the CDF on a grid refined towards both poles, where |g| near 1 puts all the mass.
    t = np.geomspace(1e-9, 1.0, 20000)
    grid = np.unique(np.concatenate([-1 + t, 1 - t, [-1.0, 1.0]]))
    edges = np.interp(np.linspace(0, 1, bins + 1), hg_cdf(g, grid), grid)
    edges[0], edges[-1] = -1.0, 1.0
    return edges


# ----------------------------------------------------------------------------------------------------------
# Small fields and run folders for the bundle tests (torch is imported only when they are used)

PHASES = (-0.75, 0.0, 0.75)
FP = "f" * 64


def small_field_config():  # noqa: ANN201  (models_spec.encoding.FieldConfig)
    """Position: levels 0-2 dense, 3-5 hashed (2^9 rows); direction: dense then hashed; odd scale factors."""
    from photon_fields.models_spec.encoding import FieldConfig
    from photon_fields.models_spec.hashgrid import HashGridConfig

    return FieldConfig(HashGridConfig(3, 6, 2, 9, 4, 1.7), HashGridConfig(2, 4, 4, 6, 3, 1.9), 32, 3, 5.0, PHASES)


def make_model(cfg, seed: int = 0):  # noqa: ANN001, ANN201  (FieldConfig -> the torch field)
    """The torch field of ``cfg`` with its hash tables uniform in [-1, 1], its tent columns (which start at
    zero) random and, for a field with the surface input, a random grid, so errors cannot hide."""
    import numpy as np
    import torch

    from photon_fields.train.field.network import TorchPhotonField as TorchField

    model = TorchField(cfg, seed=seed)
    gen = torch.Generator().manual_seed(seed + 100)
    with torch.no_grad():
        for t in model.table_parameters():
            t.copy_(torch.rand(t.shape, generator=gen) * 2 - 1)
        first = model.matrix_parameters()[0]
        phase_end = cfg.input_dims - cfg.surface_dims
        tents = first[:, phase_end - cfg.phase_dims + 1:phase_end]
        tents.copy_(torch.rand(tents.shape, generator=gen) - 0.5)
    if cfg.surface is not None:
        rng = np.random.default_rng(seed + 200)
        model.set_surface(rng.integers(-127, 128, (*cfg.surface, 3)).astype(np.int8))
    return model.eval()


def make_run(folder: Path, model, bmin: list[float], bsize: list[float], fp: str = FP) -> Path:  # noqa: ANN001
    """A run folder as ``pfn-train fit`` leaves it (checkpoint, version 1 domain.json, log.json)."""
    import json

    from photon_fields.train.export.bundle import RUN_DOMAIN_FORMAT
    from photon_fields.train.fit.checkpoint import save_checkpoint

    folder.mkdir(parents=True, exist_ok=True)
    save_checkpoint(folder / "checkpoint.pt", model, fp, 40,
                     {"final_loss": 0.05, "wall_s": 12.5, "final_validation": {"step": 40, "val_loss": 0.06}})
    (folder / "domain.json").write_text(json.dumps({"format": RUN_DOMAIN_FORMAT, "version": 1, "scene": "test",
                                                    "scene_fingerprint": fp, "bmin": bmin, "bsize": bsize}))
    (folder / "log.json").write_text(json.dumps({"scene_fingerprint": fp,
                                                 "settings": {"preset": "tiny", "batch": 512}}))
    return folder


# ----------------------------------------------------------------------------------------------------
# Hash-grid cases shared by the torch (tests/models_spec) and runtime (tests/runtime/field) encoder tests

def hashgrid_configs():  # noqa: ANN201  (name -> models_spec.hashgrid.HashGridConfig)
    """Small configs (D, levels, F, log2 T, N_min, b) covering dense and hashed levels, non-power-of-two
    scales, every F and both D."""
    from photon_fields.models_spec.hashgrid import HashGridConfig as C

    return {
        # One dense level: scale 4 (a power of two, so grid vertices x = (2k - 1) / 8 are exact floats),
        # res 5, 5^3 = 125 entries -> 128 (multiple of 8), strides (1, 5, 25).
        "DENSE": C(3, 1, 2, 12, 5, 2.0),
        # One hashed level: scale 8, res 9, 9^3 = 729 > 2^6 = 64 entries; the stride loop stops at 81 > 64.
        "HASHED": C(3, 1, 1, 6, 9, 2.0),
        "SMALL3": C(3, 4, 2, 10, 5, 1.7),
        "SMALL2": C(2, 5, 4, 8, 3, 1.5),
        # N_min = 1: level 0 has scale 0 (one vertex per axis); F = 1 with D = 2.
        "TINY2": C(2, 3, 1, 4, 1, 1.3),
        "WIDE3": C(3, 6, 8, 9, 3, 2.3),
    }


def random_table(cfg, seed: int = 0) -> np.ndarray:  # noqa: ANN001
    """Hash-grid table rows uniform in [-1, 1) (float32), seeded."""
    from photon_fields.models_spec.hashgrid import total_table_rows

    rng = np.random.default_rng(seed)
    return rng.random((total_table_rows(cfg), cfg.features), dtype=np.float32) * np.float32(2) - np.float32(1)


def edge_points(cfg, rng: np.random.Generator, n_random: int = 300, per_level: int = 30) -> np.ndarray:  # noqa: ANN001
    """Random points, the box's corners (0 and 1), grid vertices and their float neighbours per level."""
    from photon_fields.models_spec.hashgrid import level_scale

    D = cfg.dims
    pts = [rng.random((n_random, D), dtype=np.float32),
           np.array(np.meshgrid(*[[0.0, 1.0]] * D, indexing="ij")).reshape(D, -1).T.astype(np.float32)]
    for level in range(cfg.levels):
        s = float(level_scale(cfg, level))
        if s == 0.0:
            continue  # a single vertex: every x is on it
        k = rng.integers(0, int(s) + 2, size=(per_level, D))
        v = ((k - 0.5) / s).astype(np.float32)  # pos = k (up to float32 rounding of x)
        pts += [v, np.nextafter(v, np.float32(np.inf)), np.nextafter(v, np.float32(-np.inf))]
    return np.clip(np.concatenate(pts), 0.0, 1.0).astype(np.float32)


def pole_and_seam_directions(rng: np.random.Generator, n_random: int = 300) -> np.ndarray:
    """Random unit directions, then the poles, both sides of the azimuth seam (d_y = +-0 and +-1e-12 with
    d_x < 0) and the axes: the direction encoding's edge cases."""
    v = rng.standard_normal((n_random, 3))
    return np.concatenate([v / np.linalg.norm(v, axis=1, keepdims=True),
                           [[0, 0, 1], [0, 0, -1], [-1, 0.0, 0], [-1, -0.0, 0], [1, 0, 0], [0, 1, 0],
                            [-0.6, 0.0, 0.8], [-0.6, -0.0, -0.8], [-1, 1e-12, 0], [-1, -1e-12, 0]]])


def block_means(img: np.ndarray, b: int = 6) -> np.ndarray:
    """Means over b x b pixel blocks of an (H, W, C) image (the units of the block z-score tests)."""
    h, w = img.shape[:2]
    return img[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b, -1).mean(axis=(1, 3))


def mean_and_error(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per block: the mean over independent renders and its standard error."""
    blocks = np.stack([block_means(img) for img in images])
    return blocks.mean(0), blocks.std(0, ddof=1) / math.sqrt(len(images))


def assert_estimates_agree(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], what: str) -> None:
    """Two independent estimators of one image (per block: mean, standard error) converge to one mean: block
    z-scores (98th percentile < 4.5, max < 6) and the whole image's z-score (< 5)."""
    (ma, sa), (mb, sb) = a, b
    z = np.abs(ma - mb) / np.sqrt(sa**2 + sb**2 + 1e-12)
    # Whole-image means: the sharpest check of a missing fraction of the light.
    zm = abs(ma.mean() - mb.mean()) / math.sqrt(np.mean(sa) ** 2 / 4 + np.mean(sb) ** 2 / 4 + 1e-12)
    assert np.percentile(z, 98) < 4.5 and z.max() < 6.0, (what, float(np.percentile(z, 98)), float(z.max()))
    assert zm < 5.0, (what, float(ma.mean()), float(mb.mean()), zm)
