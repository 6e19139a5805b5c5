"""Shared fixtures: small analytic media and scenes."""

from __future__ import annotations

import os

# torch's and numba's OpenMP pools spin after parallel regions and steal each other's core on 2 cores
# (train.fit); pfn-train sets this itself, the test process must set it before either library loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import pytest

from runtime.camera import Camera
from runtime.medium import build_medium
from runtime.transfer import TransferFunction
from runtime.volume import make_volume


def constant_tf(sigma: float, albedo: float | tuple[float, float, float] = 1.0) -> TransferFunction:
    """Extinction ``sigma`` and ``albedo`` wherever the normalized scalar is 1 (linear ramp from 0)."""
    a = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (3,))
    return TransferFunction(np.array([0.0, 1.0]), np.stack([a, a]), np.array([0.0, 1.0]), sigma, "test")


#: Albedo rows at normalized density 0, 0.5, 1 of :func:`coloured_tf`: every channel differs and each varies
#: with density, so a dropped, swapped or misplaced albedo factor changes the per-channel means (by 11-92 %
#: when the camera vertex's albedo is dropped, tests/test_light_kinds.py).
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
