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


def _sky_with_sun(h: int, sun_v: float, sun_u: float, radius_px: float, sun: float = 2000.0) -> np.ndarray:
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(2 * h) + 0.5) / (2 * h)
    vv, uu = np.meshgrid(v, u, indexing="ij")
    disc = ((vv - sun_v) * h) ** 2 + ((uu - sun_u) * h) ** 2 < radius_px**2
    base = np.where(vv < 0.5, 1.2 - vv, 0.15)
    return base[..., None] * np.array([0.5, 0.7, 1.0]) + sun * disc[..., None] * np.array([1.0, 0.9, 0.8])


def test_a_sun_the_basis_cannot_resolve_becomes_a_directional_light_and_the_maps_power_is_kept() -> None:
    """split_suns: a small bright disc is one sun at the disc's direction with the disc's irradiance, the rest of
    the map keeps everything else (sun + rest = the map's power, per channel); a bright region wider than the
    basis resolves, or no region bright enough, stays in the map."""
    from photon_fields.runtime.pvrt.suns import row_solid_angles, split_suns

    h = 64
    img = _sky_with_sun(h, 0.3, 0.6, 2.0)
    omega = np.broadcast_to(row_solid_angles(h, 2 * h)[:, None], (h, 2 * h))
    assert omega.sum() == pytest.approx(4 * math.pi, rel=1e-12)
    resolution = make_basis("dsf", 2).resolution
    suns, rest = split_suns(img, resolution)
    assert len(suns) == 1
    towards, irradiance = suns[0]
    theta, phi = 0.3 * math.pi, 0.6 * 2 * math.pi  # the disc's centre
    expected = np.array([math.sin(theta) * math.sin(phi), math.cos(theta), -math.sin(theta) * math.cos(phi)])
    assert math.degrees(math.acos(min(1.0, float(towards @ expected)))) < 1.0
    total = (img * omega[..., None]).sum(axis=(0, 1))
    np.testing.assert_allclose((rest * omega[..., None]).sum(axis=(0, 1)) + irradiance, total, rtol=1e-12)
    disc = img[..., 0] > 100
    assert np.all(rest[disc] == 0) and np.array_equal(rest[~disc], img[~disc])
    wide, rest_wide = split_suns(_sky_with_sun(h, 0.3, 0.6, 12.0, sun=50.0), resolution)  # ~34 degrees across
    assert wide == [] and rest_wide.shape == img.shape
    assert split_suns(_sky_with_sun(h, 0.3, 0.6, 2.0, sun=5.0), resolution)[0] == []  # not bright enough


def test_a_maps_sun_is_lit_by_nee_from_its_turned_direction_and_projected_without_it() -> None:
    """scene_lighting: an environment map's sun is a NEE light travelling away from its direction as the map's
    rotation and the lighting's rotation turn it, with the sun's irradiance; the basis gets the map without it
    (its coefficients: the directional projection of the sun plus the rest's), and the note says so. With
    direct="transfer" nothing is split."""
    from photon_fields.runtime.pvrt.lighting import scene_lighting
    from photon_fields.runtime.pvrt.suns import split_suns
    from photon_fields.runtime.scene.lights import EnvironmentMap
    from photon_fields.runtime.transport.environment_map import rotation_matrix

    basis = make_basis("dsf", 1)
    img = _sky_with_sun(32, 0.3, 0.6, 1.5).astype(np.float32)
    light = EnvironmentMap("sun.exr", image=img, rotation=(30.0, 10.0, 0.0))
    turn = _rotation([0.2, 1.0, 0.1], 0.7)
    lit = scene_lighting((light,), basis, rotation=turn)
    (towards, irradiance), = split_suns(img.astype(np.float64), basis.resolution)[0]
    world = turn @ rotation_matrix(30.0, 10.0, 0.0) @ towards
    np.testing.assert_allclose(lit.nee_directions, [-world], atol=1e-12)
    np.testing.assert_allclose(lit.nee_rgb, [irradiance], rtol=1e-12)
    assert "sun" in lit.notes[0] and "NEE" in lit.notes[0]
    plain = scene_lighting((light,), basis, rotation=turn, direct="transfer")
    assert len(plain.nee_directions) == 0 and not plain.notes
    # the coefficients' total power: the sun's projection plus the rest's equals the whole map's (to the sphere
    # quadrature's error on the small disc in the plain projection, 0.24 % here; the split sun is exact)
    omega = basis.dsf.solid_angle[:, None]
    np.testing.assert_allclose((lit.coeffs * omega).sum(axis=0), (plain.coeffs * omega).sum(axis=0), rtol=1e-2)


@pytest.mark.parametrize(("rows", "cols"), [(200, 6), (40, 300)])  # more rows than columns (scatter), fewer (SVD)
def test_cpca_recovers_clusters_of_low_rank_matrices(rows: int, cols: int) -> None:
    """Three well separated clusters, each its mean plus a rank-2 part: CPCA with 3 clusters x 2 bases
    reconstructs them to float32 precision, with 1 basis it cannot (what is left is the second axis)."""
    from photon_fields.runtime.pvrt.cpca import compress

    rng = np.random.default_rng(3)
    parts = []
    for c in range(3):
        mean = rng.normal(size=cols) + 20.0 * c
        parts.append(mean + rng.normal(size=(rows, 2)) @ rng.normal(size=(2, cols)))
    x = np.concatenate(parts).astype(np.float32)
    exact = compress(x, 3, 2, seed=0)
    assert exact.relative_error < 1e-5
    np.testing.assert_allclose(exact.reconstruct(), x, atol=1e-3 * np.abs(x).max())
    assert compress(x, 3, 1, seed=0).relative_error > 100 * exact.relative_error
