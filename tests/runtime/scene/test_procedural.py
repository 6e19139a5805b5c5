"""Tests for runtime.scene.procedural: the embedded scenes are deterministic, normalized and as described."""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.procedural import GENERATORS, HEAD_LEVELS, SHELL_LEVELS, blobs, head, shell, vortex
from photon_fields.runtime.scene.volume import make_volume

N = 48  # small but enough for the structure (thin vortex cores are ~0.5 voxel here)

# Non-empty (value > 0) fractions promised by the module docstring.
FILL_RANGES = {"vortex": (0.10, 0.25), "blobs": (0.20, 0.40)}


@pytest.fixture(scope="module")
def volumes() -> dict[str, np.ndarray]:
    return {name: gen(N) for name, gen in GENERATORS.items()}


def test_registry_names() -> None:
    assert set(GENERATORS) == {"vortex", "blobs", "shell", "head"}
    assert GENERATORS["vortex"] is vortex and GENERATORS["blobs"] is blobs and GENERATORS["shell"] is shell
    assert GENERATORS["head"] is head


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_deterministic_bitwise(name: str, volumes: dict[str, np.ndarray]) -> None:
    again = GENERATORS[name](N)
    assert again.tobytes() == volumes[name].tobytes()


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_shape_dtype_range(name: str, volumes: dict[str, np.ndarray]) -> None:
    v = volumes[name]
    assert v.shape == (N, N, N)
    assert v.dtype == np.float32
    assert np.all(np.isfinite(v))
    assert float(v.min()) == 0.0
    assert float(v.max()) == 1.0


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_default_resolution(name: str) -> None:
    assert GENERATORS[name]().shape == (96, 96, 96)


@pytest.mark.parametrize("name", sorted(FILL_RANGES))
@pytest.mark.parametrize("n", [N, 80])
def test_non_empty_fraction(name: str, n: int, volumes: dict[str, np.ndarray]) -> None:
    v = volumes[name] if n == N else GENERATORS[name](n)
    lo, hi = FILL_RANGES[name]
    assert lo <= float(np.mean(v > 0)) <= hi


def test_has_empty_space_and_structure(volumes: dict[str, np.ndarray]) -> None:
    # "Wispy with lots of empty space": most non-zero voxels are faint, a few are dense cores.
    v = volumes["vortex"]
    nz = v[v > 0]
    assert np.median(nz) < 0.3
    assert np.mean(nz > 0.7) > 0.001
    # The cloud is soft: many distinct values (no hard plateaus), and it has a dense body.
    b = volumes["blobs"]
    assert np.unique(b).size > 1000
    assert np.mean(b[b > 0] > 0.5) > 0.2


def test_blobs_flat_base_and_up_is_y(volumes: dict[str, np.ndarray]) -> None:
    # +y is up: the cloud's mass sits low with a flat base; nothing below the base.
    b = volumes["blobs"]
    per_y = b.sum(axis=(0, 2))
    occupied = np.flatnonzero(per_y > 0)
    base = occupied[0]
    assert base > 0  # empty space below the base
    # Just above the flat base the cloud is already wide (a rounded bottom would start with a few voxels).
    assert np.mean(b[:, base + 2, :] > 0) > 0.5 * np.max(np.mean(b > 0, axis=(0, 2)))


def test_shell_piecewise_constant_sharp(volumes: dict[str, np.ndarray]) -> None:
    v = volumes["shell"]
    levels = np.asarray(SHELL_LEVELS, dtype=np.float32)
    assert set(np.unique(v).tolist()) == {0.0, *levels.tolist()}
    # Sharp edges: every non-zero voxel sits exactly on a level, so there is no anti-aliased ramp.
    assert np.isin(v[v > 0], levels).all()
    # Edges are 1 voxel: along each axis the value jumps straight from 0 to the wall level.
    for axis in range(3):
        d = np.abs(np.diff(v, axis=axis))
        jumps = np.unique(d[d > 0])
        assert np.isin(np.float32(SHELL_LEVELS[0]), jumps)
        assert jumps.size <= 6  # differences between the few levels only


def test_shell_geometry(volumes: dict[str, np.ndarray]) -> None:
    v = volumes["shell"]
    wall = np.float32(SHELL_LEVELS[0])
    c = N // 2
    # Walking out from the centre along each axis: dense core, empty gap, wall ~0.06 thick, outside.
    for line in (v[c:, c, c], v[c, c:, c], v[c, c, c:], v[:c, c, c][::-1]):
        assert line[0] == 1.0
        assert np.any(line == 0.0)
        runs = np.flatnonzero(line == wall)
        if runs.size:  # this axis may leave through a hole
            assert 0.04 * N <= runs.size <= 0.09 * N
            assert np.all(line[runs[-1] + 1 :] == 0.0)
    # Holes: some rays from the centre leave through the wall without touching it, most do not.
    rng = np.random.default_rng(0)
    t = np.linspace(0.2, 0.49, 60)
    escaped = 0
    for d in rng.normal(size=(400, 3)):
        idx = np.clip(((t[:, None] * d / np.linalg.norm(d) + 0.5) * N).astype(int), 0, N - 1)
        escaped += not np.any(v[idx[:, 0], idx[:, 1], idx[:, 2]] == wall)
    assert 0.02 < escaped / 400 < 0.5


@pytest.mark.parametrize("n", [N, 96])
def test_head_phantom_structure(n: int, volumes: dict[str, np.ndarray]) -> None:
    v = volumes["head"] if n == N else head(n)
    csf, skin, brain, vessel, bone = (np.float32(level) for level in HEAD_LEVELS)
    assert set(np.unique(v).tolist()) == {0.0, *(float(level) for level in (csf, skin, brain, vessel, bone))}
    # Fine structures at the scale a density estimate blurs: vessels are 1-3 voxels across (no vessel voxel is
    # more than 2 voxels from a non-vessel one), and the sulci cut CSF clefts into the brain.
    is_vessel = v == vessel
    assert 0.0005 < is_vessel.mean() < 0.01
    core = is_vessel.copy()
    for axis in range(3):
        for shift in (-2, 2):
            core &= np.roll(is_vessel, shift, axis=axis)
    assert not core.any()
    c = n // 2
    inner = v[c - n // 5:c + n // 5, c - n // 5:c + n // 5, c - n // 5:c + n // 5]
    assert 0.02 < np.mean(inner == csf) < 0.4 and np.mean(inner == brain) > 0.5
    # The cut-away: no skin or bone in the octant facing the default camera (+x, +z, upper part).
    octant = v[c + n // 20:, c:, c + n // 20:]
    assert not np.isin(octant, [skin, bone]).any() and (octant == brain).any()
    # Elsewhere the skull encloses the brain: along -x from the centre, bone comes before the outside.
    line = v[:c, c, c][::-1]
    assert (line == bone).any() and np.flatnonzero(line == bone)[0] > np.flatnonzero(line == brain)[-1]


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_usable_as_volume(name: str, volumes: dict[str, np.ndarray]) -> None:
    vol = make_volume(volumes[name], window=(0.0, 1.0), name=name)
    np.testing.assert_array_equal(vol.data, volumes[name])


def test_resolution_is_validated() -> None:
    with pytest.raises(InputError):
        vortex(4)
