"""PVRT: lighting bases (Sec. 5, 6.1, 8.2) and the transfer file (models_spec/pvrt_transfer.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.pvrt.basis import make_basis
from photon_fields.runtime.pvrt.dsf import fibonacci_sphere
from photon_fields.runtime.pvrt.sh import sh_basis
from photon_fields.runtime.pvrt.transfer import Transfer, load_transfer, save_transfer


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def test_sh_orthonormal() -> None:
    q = fibonacci_sphere(1 << 15)
    y = sh_basis(4, q)
    gram = y.T @ y * (4 * math.pi / len(q))
    assert np.abs(gram - np.eye(25)).max() < 2e-3


@pytest.mark.parametrize("order", [0, 1, 2])
def test_dsf_interpolates_and_partitions_unity(order: int) -> None:
    b = make_basis("dsf", order)
    assert np.allclose(b.dsf.evaluate(b.dsf.dirs), np.eye(b.size))  # Eq. 8: interpolation property
    w = b.evaluate(fibonacci_sphere(4000))
    assert np.allclose(w.sum(axis=1), 1.0) and np.all(w >= 0)  # Eq. 7: normalized weights everywhere
    assert np.allclose(b.project_sky(lambda d: np.ones((len(d), 3))), 1.0)  # a constant sky is exact


@pytest.mark.parametrize(("kind", "order", "tol"), [("sh", 3, 1e-3), ("dsf", 2, 0.12)])
def test_rotation_matches_projection_of_rotated_sky(kind: str, order: int, tol: float) -> None:
    b = make_basis(kind, order)
    r = _rotation([0.3, 1.0, -0.2], 1.1)

    def sky(d: np.ndarray) -> np.ndarray:
        return np.stack([1 + d[:, 0], 2 + 0.5 * d[:, 2] ** 2, np.exp(d[:, 1])], axis=1)

    rotated = b.rotate(b.project_sky(sky), r)
    direct = b.project_sky(lambda d: sky(d @ r))
    assert np.abs(rotated - direct).max() < tol


@pytest.mark.parametrize(("kind", "order"), [("sh", 3), ("dsf", 1), ("dsf", 2)])
def test_directional_light_keeps_flux_and_direction(kind: str, order: int) -> None:
    b = make_basis(kind, order)
    w = np.array([0.3, 0.8, -0.52])
    w /= np.linalg.norm(w)
    c = b.project_directional(w, np.array([2.0, 1.0, 0.5]))
    q = fibonacci_sphere(1 << 15)
    lum = b.reconstruct(c, q)[:, 0] * (4 * math.pi / len(q))
    assert lum.sum() == pytest.approx(2.0, rel=1e-3)  # irradiance E: the delta's flux
    centroid = (q * lum[:, None]).sum(axis=0)
    assert np.dot(centroid / np.linalg.norm(centroid), w) > 0.98


def test_basis_order_out_of_range() -> None:
    with pytest.raises(InputError, match="order"):
        make_basis("dsf", 7)
    with pytest.raises(InputError, match="unknown basis"):
        make_basis("srbf", 1)


def _tiny_transfer() -> Transfer:
    rng = np.random.default_rng(0)
    v, k, n, d = 8, 2, 1, 12 * 4 * 1
    manifest = {"format": "photon-fields/pvrt-transfer", "version": 1, "scene_name": "t",
                "scene_parts": {"volume": "a" * 64, "transfer_function": "b" * 64}, "g": 0.0,
                "basis": {"kind": "dsf", "order": 0}, "exitance_order": 0, "parts": ["direct", "ms_r", "ms_g", "ms_b"],
                "grid": [2, 2, 2], "box": {"min": [-0.5] * 3, "size": [1.0] * 3},
                "cpca": {"clusters": k, "bases": n, "relative_error": 0.0},
                "photons": {"paths_per_basis": 1, "seed": 0, "max_bounces": 16, "kernel_c": 1.5}}
    return Transfer(rng.integers(-1, k, v).astype(np.int32), rng.random(v).astype(np.float32),
                    rng.random((v, n)).astype(np.float32), rng.random((k, d)).astype(np.float32),
                    rng.random((k, n, d)).astype(np.float32), manifest)


def test_file_round_trip_and_refusals(tmp_path) -> None:  # noqa: ANN001
    t = _tiny_transfer()
    p = save_transfer(t, tmp_path / "t.pvrt")
    back = load_transfer(p)
    for name in ("cluster", "mass", "weights", "mean", "basis_matrices"):
        assert np.array_equal(getattr(back, name), getattr(t, name))
    with pytest.raises(InputError, match="--force"):
        save_transfer(t, p)
    save_transfer(t, p, force=True)
    for change, match in [({"version": 2}, "version 2"), ({"extra": 1}, "unknown key"),
                          ({"basis": {"kind": "dsf", "order": 9}}, "order")]:
        bad = _tiny_transfer()
        bad.manifest.update(change)
        q = tmp_path / f"bad{len(change)}{match[:3]}.pvrt"
        save_transfer(bad, q)
        with pytest.raises(InputError, match=match):
            load_transfer(q)
    arrays = {"cluster": t.cluster, "mass": t.mass, "weights": t.weights, "mean": t.mean, "basis": t.basis_matrices,
              "pickle": np.array([1]), "manifest": np.frombuffer(json.dumps(t.manifest).encode(), np.uint8)}
    np.savez(tmp_path / "x.pvrt.npz", **arrays)
    (tmp_path / "x.pvrt.npz").rename(tmp_path / "x.pvrt")
    with pytest.raises(InputError, match="unknown array"):
        load_transfer(tmp_path / "x.pvrt")


@pytest.mark.parametrize("kind", ["sh", "dsf"])
def test_environment_map_projects_like_the_sky_it_shows(kind: str) -> None:
    """An environment map in a PVRT lighting: a constant map gives the coefficients of the constant environment
    of the same radiance, and the lighting's sky (what escaping rays see) is the map itself, turned with the
    lighting: a map bright above the horizon, turned so that its zenith faces +x, is bright at a direction
    slightly below the horizon towards +x (dark without the turn) and dark towards -x."""
    from photon_fields.runtime.pvrt.lighting import scene_lighting
    from photon_fields.runtime.scene.lights import EnvironmentLight, EnvironmentMap

    basis = make_basis(kind, 1)
    flat = EnvironmentMap("flat", [0.5, 1.0, 2.0], 1.5, image=np.ones((8, 16, 3)))
    const = EnvironmentLight([0.5, 1.0, 2.0], 1.5)
    a, b = scene_lighting((flat,), basis), scene_lighting((const,), basis)
    np.testing.assert_allclose(a.coeffs, b.coeffs, rtol=1e-9)
    np.testing.assert_allclose(a.direct_coeffs, b.direct_coeffs, rtol=1e-9)
    img = np.zeros((8, 16, 3))
    img[:4] = 1.0  # the upper half of the image: the hemisphere around +y (the zenith)
    half = EnvironmentMap("half", image=img)
    w = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    np.testing.assert_allclose(scene_lighting((half,), basis).sky(w)[:, 1], [1.0, 0.0])
    rot = _rotation([0.0, 0.0, 1.0], -math.pi / 2)  # the lighting turned: +y goes to +x
    tilted = np.array([[1.0, -0.3, 0.0], [-1.0, 0.3, 0.0]]) / math.sqrt(1.09)
    assert np.allclose(scene_lighting((half,), basis).sky(tilted)[:, 1], [0.0, 1.0])  # unturned: the other way
    turned = scene_lighting((half,), basis, rotation=rot).sky(tilted)
    np.testing.assert_allclose(turned[:, 1], [1.0, 0.0])
