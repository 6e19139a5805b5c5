"""Tests for Zarr arrays and OME-Zarr images (runtime/scene/readers/zarr_store.py) through load_volume: stores
written by zarr itself in both Zarr formats (v2 with OME-NGFF 0.4 metadata, v3 with 0.5), orientation
(stored [z, y, x] -> [x, y, z], OME axes by name), resolution levels read lazily, spacing from the scale
transforms, and one-line errors."""

from __future__ import annotations

import builtins
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from volume_helpers import expected_norm, one_line_error

from photon_fields.runtime.scene.readers.zarr_store import MISSING_ZARR
from photon_fields.runtime.scene.volume_io import load_volume

zarr = pytest.importorskip("zarr", reason="zarr is the optional extra 'formats'")

NX, NY, NZ = 6, 8, 10
FORMATS = [2, 3]


def pattern(nx: int = NX, ny: int = NY, nz: int = NZ, dtype: Any = np.uint16) -> np.ndarray:
    """Indexed [x, y, z]: value = x + 10 y + 100 z."""
    x, y, z = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    return (x + 10 * y + 100 * z).astype(dtype)


def zyx(data: np.ndarray) -> np.ndarray:
    """[x, y, z] -> [z, y, x], the order Zarr / OME-Zarr stores a volume in."""
    return np.ascontiguousarray(data.transpose(2, 1, 0))


def write_array(path: Path | Any, data: np.ndarray, fmt: int = 3, **kwargs: Any) -> Any:
    arr = zarr.create_array(path, shape=data.shape, dtype=data.dtype, chunks=(3,) * data.ndim, zarr_format=fmt,
                            **kwargs)
    arr[...] = data
    return arr


def write_ome(path: Path, data: np.ndarray, fmt: int = 3, levels: int = 3, scale: tuple[float, ...] = (2.0, 0.5, 0.25),
              axes: list[dict[str, str]] | None = None, channels: int = 1) -> Path:
    """An OME-Zarr image (NGFF 0.4 in a v2 store, 0.5 in a v3 store) of ``data`` ([x, y, z]) with axes c, z, y, x
    and ``levels`` levels, each half the previous in x, y and z; ``scale`` is level 0's (z, y, x) voxel size."""
    group = zarr.open_group(path, mode="w", zarr_format=fmt)
    axes = axes or [{"name": "c", "type": "channel"}, {"name": "z", "type": "space", "unit": "micrometer"},
                    {"name": "y", "type": "space", "unit": "micrometer"},
                    {"name": "x", "type": "space", "unit": "micrometer"}]
    datasets = []
    for level in range(levels):
        f = 2**level
        stored = np.stack([zyx(data[::f, ::f, ::f]) + 1000 * c for c in range(channels)])
        write_array(group.store_path / f"s{level}", stored, fmt)
        datasets.append({"path": f"s{level}", "coordinateTransformations": [
            {"type": "scale", "scale": [1.0, *(s * f for s in scale)]},
            {"type": "translation", "translation": [0.0, 5.0, 5.0, 5.0]}]})
    multiscales = [{"name": "img", "axes": axes, "datasets": datasets}]
    if fmt == 2:
        group.attrs.update({"multiscales": [{"version": "0.4", **multiscales[0]}]})
    else:
        group.attrs.update({"ome": {"version": "0.5", "multiscales": multiscales}})
    return path


# ----------------------------------------------------------------------------------------------------------
# Plain arrays


@pytest.mark.parametrize("fmt", FORMATS)
def test_plain_array_orientation(tmp_path: Path, fmt: int) -> None:
    path = tmp_path / "vol.zarr"
    write_array(path, zyx(pattern()), fmt)
    vol = load_volume(path)
    assert vol.dims == (NX, NY, NZ) and vol.name == "vol"
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    top = float(pattern().max())  # spelled out: the last stored axis is x, the first z
    assert vol.data[5, 0, 0] == pytest.approx(5 / top) and vol.data[0, 7, 0] == pytest.approx(70 / top)
    assert vol.data[0, 0, 9] == pytest.approx(900 / top)
    assert vol.spacing == (1.0, 1.0, 1.0)


@pytest.mark.parametrize("fmt", FORMATS)
def test_plain_array_dimension_names(tmp_path: Path, fmt: int) -> None:
    """Named dimensions decide: an array stored [y, x, z] with its names comes back [x, y, z]."""
    path = tmp_path / "named.zarr"
    stored = np.ascontiguousarray(pattern().transpose(1, 0, 2))
    if fmt == 3:
        write_array(path, stored, fmt, dimension_names=("y", "x", "z"))
    else:  # xarray's convention for v2
        write_array(path, stored, fmt, attributes={"_ARRAY_DIMENSIONS": ["y", "x", "z"]})
    np.testing.assert_array_equal(load_volume(path).data, expected_norm(pattern()))


def test_singleton_dimensions_dropped_and_folder_without_suffix(tmp_path: Path) -> None:
    path = tmp_path / "plain"  # no .zarr suffix: found by its zarr.json
    write_array(path, zyx(pattern())[None], 3)  # shape (1, z, y, x)
    vol = load_volume(path)
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))


@pytest.mark.parametrize("fmt", FORMATS)
def test_group_with_one_array(tmp_path: Path, fmt: int) -> None:
    group = zarr.open_group(tmp_path / "g.zarr", mode="w", zarr_format=fmt)
    write_array(group.store_path / "density", zyx(pattern(dtype=np.float32)), fmt)
    np.testing.assert_array_equal(load_volume(tmp_path / "g.zarr").data, expected_norm(pattern()))


# ----------------------------------------------------------------------------------------------------------
# OME-Zarr


@pytest.mark.parametrize("fmt", FORMATS)
def test_ome_levels_orientation_and_spacing(tmp_path: Path, fmt: int) -> None:
    path = write_ome(tmp_path / "img.ome.zarr", pattern(), fmt)
    vol = load_volume(path)
    assert vol.dims == (NX, NY, NZ) and vol.name == "img.ome"
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == pytest.approx((0.25, 0.5, 2.0))  # scale is (c, z, y, x): x is the last entry
    half = load_volume(path, level=1)
    assert half.dims == (3, 4, 5)
    np.testing.assert_array_equal(half.data, expected_norm(pattern()[::2, ::2, ::2]))
    assert half.spacing == pytest.approx((0.5, 1.0, 4.0))
    assert load_volume(path, level=2).dims == (2, 2, 3)
    assert load_volume(path, spacing=(1, 1, 1)).spacing == (1.0, 1.0, 1.0)  # the user's spacing wins


def test_ome_multiscale_scale_and_units(tmp_path: Path) -> None:
    """The multiscale's own scale multiplies the level's; axes in different units are converted to x's unit."""
    axes = [{"name": "c", "type": "channel"}, {"name": "z", "type": "space", "unit": "micrometer"},
            {"name": "y", "type": "space", "unit": "nanometer"}, {"name": "x", "type": "space", "unit": "nanometer"}]
    path = write_ome(tmp_path / "u.zarr", pattern(), 3, levels=1, scale=(2.0, 500.0, 250.0), axes=axes)
    meta = json.loads((path / "zarr.json").read_text())
    meta["attributes"]["ome"]["multiscales"][0]["coordinateTransformations"] = [
        {"type": "scale", "scale": [1.0, 3.0, 1.0, 1.0]}]
    (path / "zarr.json").write_text(json.dumps(meta))
    assert load_volume(path).spacing == pytest.approx((250.0, 500.0, 6000.0))


def test_ome_axes_by_name(tmp_path: Path) -> None:
    """Space axes named x, y, z are mapped by name, whatever their stored order."""
    axes = [{"name": "c", "type": "channel"}, {"name": "x", "type": "space"}, {"name": "z", "type": "space"},
            {"name": "y", "type": "space"}]
    group = zarr.open_group(tmp_path / "o.zarr", mode="w", zarr_format=3)
    write_array(group.store_path / "0", np.ascontiguousarray(pattern().transpose(0, 2, 1))[None], 3)
    group.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 0.1, 0.3, 0.2]}]}]}]}})
    vol = load_volume(tmp_path / "o.zarr")
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == pytest.approx((0.1, 0.2, 0.3))


@pytest.mark.parametrize("version", ["0.2", "0.3"])
def test_ome_before_0_4(tmp_path: Path, version: str) -> None:
    """0.1 / 0.2 had no axes (always t, c, z, y, x); 0.3 lists bare names. Both read [z, y, x] arrays alike."""
    group = zarr.open_group(tmp_path / "old.zarr", mode="w", zarr_format=2)
    write_array(group.store_path / "0", zyx(pattern())[None, None], 2)
    ms: dict[str, Any] = {"version": version, "datasets": [{"path": "0"}]}
    if version == "0.3":
        ms["axes"] = ["t", "c", "z", "y", "x"]
    group.attrs.update({"multiscales": [ms]})
    vol = load_volume(tmp_path / "old.zarr")
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == (1.0, 1.0, 1.0)  # no coordinateTransformations before 0.4


def test_other_levels_are_not_read(tmp_path: Path) -> None:
    """Level 1 loads with level 0's chunks destroyed (it is never decoded); level 0 then fails in one line."""
    path = write_ome(tmp_path / "lazy.zarr", pattern(), 3)
    for chunk in (path / "s0" / "c").rglob("*"):
        if chunk.is_file():
            chunk.write_bytes(b"\x00garbage")
    np.testing.assert_array_equal(load_volume(path, level=1).data, expected_norm(pattern()[::2, ::2, ::2]))
    one_line_error(path, "OME-Zarr level 0 (array 's0'): cannot decode its chunks")


def test_ome_from_a_scene_file(tmp_path: Path) -> None:
    from photon_fields.runtime.scene.scene import load_scene

    write_ome(tmp_path / "img.zarr", pattern(), 2)
    scene = {"volume": {"path": "img.zarr", "level": 1}, "transfer_function": {"preset": "grey_ramp"},
             "lights": [{"type": "directional", "direction": [0, -1, 0]}],
             "camera": {"eye": [2, 0, 0], "target": [0, 0, 0]}}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    loaded = load_scene(tmp_path / "scene.json")
    assert loaded.volume.dims == (3, 4, 5) and loaded.volume.spacing == pytest.approx((0.5, 1.0, 4.0))


# ----------------------------------------------------------------------------------------------------------
# Bad input


def test_groups_without_one_array(tmp_path: Path) -> None:
    zarr.open_group(tmp_path / "empty.zarr", mode="w")
    one_line_error(tmp_path / "empty.zarr", "Zarr group without arrays and without OME-Zarr multiscales metadata")
    root = zarr.open_group(tmp_path / "b2r.zarr", mode="w")
    root.create_group("0")
    root.create_group("1")
    one_line_error(tmp_path / "b2r.zarr", "only subgroups (0, 1; give one of their folders, e.g. b2r.zarr/0)")
    many = zarr.open_group(tmp_path / "many.zarr", mode="w")
    for name in ("u", "v"):
        write_array(many.store_path / name, zyx(pattern()))
    one_line_error(tmp_path / "many.zarr", "Zarr group holds 2 arrays (u, v)")
    np.testing.assert_array_equal(load_volume(tmp_path / "many.zarr" / "v").data, expected_norm(pattern()))


def test_channels_time_and_2d(tmp_path: Path) -> None:
    write_ome(tmp_path / "rgb.zarr", pattern(), 3, levels=1, channels=3)
    one_line_error(tmp_path / "rgb.zarr", "has 3 channels (axis 'c' of shape (3, 10, 8, 6))")
    write_array(tmp_path / "t.zarr", np.zeros((4, NZ, NY, NX), np.uint8), 3, dimension_names=("t", "z", "y", "x"))
    one_line_error(tmp_path / "t.zarr", "has 4 time points (axis 't'")
    flat = zarr.open_group(tmp_path / "flat.zarr", mode="w")
    write_array(flat.store_path / "0", np.zeros((NY, NX), np.uint8))
    flat.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": [
        {"name": "y", "type": "space"}, {"name": "x", "type": "space"}], "datasets": [{"path": "0"}]}]}})
    one_line_error(tmp_path / "flat.zarr", "has 2 space axes")
    write_array(tmp_path / "four.zarr", np.zeros((2, 3, 4, 5), np.uint8))
    one_line_error(tmp_path / "four.zarr", "Zarr array has shape (2, 3, 4, 5); expected three non-singleton")


def test_level_errors(tmp_path: Path) -> None:
    path = write_ome(tmp_path / "img.zarr", pattern(), 3, levels=2)
    one_line_error(path, "level 2 does not exist: this OME-Zarr image has 2 resolution levels (0 .. 1", level=2)
    one_line_error(path, "level must be a resolution level number", level=-1)
    one_line_error(path, "level must be a resolution level number", level="1")
    write_array(tmp_path / "plain.zarr", zyx(pattern()))
    one_line_error(tmp_path / "plain.zarr", "level 1 applies to OME-Zarr multiscale images", level=1)
    np.save(tmp_path / "v.npy", pattern())
    one_line_error(tmp_path / "v.npy", "level only applies to Zarr", level=0)
    meta = json.loads((path / "zarr.json").read_text())
    meta["attributes"]["ome"]["multiscales"][0]["datasets"][1]["path"] = "gone"
    (path / "zarr.json").write_text(json.dumps(meta))
    one_line_error(path, "OME-Zarr level 1 (array 'gone'): no such array", level=1)


def test_corrupt_and_truncated_stores(tmp_path: Path) -> None:
    path = tmp_path / "bad.zarr"
    write_array(path, zyx(pattern()))
    (path / "zarr.json").write_text('{"zarr_format": 3, "node_type": "arr')  # truncated metadata
    one_line_error(path, "not a readable Zarr array or group")
    path2 = tmp_path / "cut.zarr"
    write_array(path2, zyx(pattern()), 2)  # compressed by zarr's default codec
    chunk = path2 / "0.0.0"
    chunk.write_bytes(chunk.read_bytes()[:5])  # a truncated compressed chunk
    one_line_error(path2, "Zarr array: cannot decode its chunks")
    (tmp_path / "file.zarr").write_text("not a folder")
    one_line_error(tmp_path / "file.zarr", "is a file; a Zarr store is a folder")
    (tmp_path / "nometa.zarr").mkdir()
    one_line_error(tmp_path / "nometa.zarr", "not a readable Zarr array or group")


def test_missing_zarr_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "v.zarr"
    write_array(path, zyx(pattern()))
    real_import = builtins.__import__

    def no_zarr(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "zarr" or name.startswith("zarr."):
            raise ImportError("No module named 'zarr'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_zarr)
    assert one_line_error(path, MISSING_ZARR).endswith("pip install 'photon-fields[formats]'")
