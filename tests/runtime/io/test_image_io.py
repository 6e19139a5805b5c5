"""Tests for photon_fields.runtime.io.images: exact EXR round trips, atomic writes, and the sRGB tonemapping."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.images import (
    EXPOSURE_METADATA,
    aces_fitted,
    auto_exposure_stops,
    read_exr,
    srgb_oetf,
    tonemap_srgb,
    write_exr,
    write_image_set,
    write_png,
)


def _layers(h: int = 12, w: int = 17, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        # HDR radiance, including values no 8-bit or half-float format would keep exactly.
        "L": (rng.lognormal(0.0, 2.0, (h, w, 3)) * rng.choice([1.0, -1.0], (h, w, 3))).astype(np.float32),
        "albedo": rng.random((h, w, 3), dtype=np.float32),
        "depth": rng.random((h, w), dtype=np.float32) * 1e6,
    }


def _ref_srgb(x: float) -> float:
    """IEC 61966-2-1 written out independently of the module."""
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1.0 / 2.4) - 0.055


def _ref_aces(x: float) -> float:
    return min(1.0, max(0.0, x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14)))


def _leftovers(directory: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name not in keep)


# ----------------------------------------------------------------------------------------------
# EXR
# ----------------------------------------------------------------------------------------------


def test_exr_round_trip_exact(tmp_path: Path) -> None:
    layers = _layers()
    meta = {"method": "pt", "spp": "64", "scene": "vortex\nline two, ünïcode"}
    path = tmp_path / "img.exr"
    assert write_exr(path, layers, meta) == path
    got, got_meta = read_exr(path)
    assert set(got) == set(layers)
    for name, data in layers.items():
        assert got[name].dtype == np.float32
        assert got[name].shape == data.shape
        assert np.array_equal(got[name], data)
    assert got_meta == meta
    assert _leftovers(tmp_path, {"img.exr"}) == []


def test_exr_float64_input_is_stored_as_float32(tmp_path: Path) -> None:
    data = np.random.default_rng(1).random((4, 5, 3))
    write_exr(tmp_path / "a.exr", {"L": data})
    got, meta = read_exr(tmp_path / "a.exr")
    assert np.array_equal(got["L"], data.astype(np.float32))
    assert meta == {}


def test_exr_channel_names_and_header(tmp_path: Path) -> None:
    path = tmp_path / "img.exr"
    write_exr(path, _layers(), {"renderer": "photon-fields"})
    with OpenEXR.File(str(path), separate_channels=True) as exr:  # its dicts are cleared on exit: copy
        channels = {name: np.array(ch.pixels) for name, ch in exr.channels().items()}
        header = dict(exr.header())
    assert set(channels) == {"L.R", "L.G", "L.B", "albedo.R", "albedo.G", "albedo.B", "depth.Y"}
    for pixels in channels.values():
        assert pixels.dtype == np.float32
        assert pixels.shape == (12, 17)
    assert np.array_equal(channels["L.G"], _layers()["L"][:, :, 1])
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    assert header["type"] == OpenEXR.scanlineimage
    assert header["renderer"] == "photon-fields"


def test_exr_keeps_non_finite_pixels(tmp_path: Path) -> None:
    data = np.ones((3, 4, 3), dtype=np.float32)
    data[0, 0] = np.nan
    data[1, 1, 2] = np.inf
    data[2, 3, 0] = -np.inf
    write_exr(tmp_path / "nan.exr", {"L": data})
    got, _ = read_exr(tmp_path / "nan.exr")
    assert np.array_equal(got["L"], data, equal_nan=True)


def test_read_foreign_channel_names(tmp_path: Path) -> None:
    # Files from other tools: bare R/G/B/A channels and an incomplete triple stay single channels.
    plane = np.arange(12, dtype=np.float32).reshape(3, 4)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    chans = {"R": plane, "G": plane + 1, "B": plane + 2, "A": plane + 3, "N.R": plane, "N.G": plane}
    OpenEXR.File(header, chans).write(str(tmp_path / "foreign.exr"))
    got, _ = read_exr(tmp_path / "foreign.exr")
    assert set(got) == set(chans)
    assert np.array_equal(got["A"], plane + 3)


@pytest.mark.parametrize(
    "layers, metadata, error",
    [
        ({}, None, ValueError),
        ({"L": np.zeros((4, 5, 4))}, None, ValueError),
        ({"L": np.zeros((4, 5, 3)), "D": np.zeros((4, 6))}, None, ValueError),
        ({"L": np.zeros((0, 5, 3))}, None, ValueError),
        ({"L": np.zeros((4, 5, 3))}, {"compression": "none"}, ValueError),
        ({"L": np.zeros((4, 5, 3))}, {"spp": 64}, TypeError),
    ],
)
def test_write_exr_rejects_bad_arguments(
    tmp_path: Path, layers: dict, metadata: dict | None, error: type
) -> None:
    with pytest.raises(error):
        write_exr(tmp_path / "bad.exr", layers, metadata)
    assert _leftovers(tmp_path, set()) == []


def _assert_one_line_input_error(exc: pytest.ExceptionInfo[InputError], path: Path) -> None:
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(str(path))
    assert len(msg) < 200


def test_read_corrupt_exr_raises_input_error(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.exr"
    garbage.write_bytes(b"this is not an EXR file at all" * 10)
    with pytest.raises(InputError) as exc:
        read_exr(garbage)
    _assert_one_line_input_error(exc, garbage)
    assert "not an OpenEXR file" in str(exc.value)


@pytest.mark.parametrize("keep", [0.5, 0.95])
def test_read_truncated_exr_raises_input_error(tmp_path: Path, keep: float) -> None:
    good = tmp_path / "good.exr"
    write_exr(good, _layers(64, 80))
    data = good.read_bytes()
    bad = tmp_path / "truncated.exr"
    bad.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(InputError) as exc:
        read_exr(bad)
    _assert_one_line_input_error(exc, bad)


def test_read_missing_or_directory_raises_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found") as exc:
        read_exr(tmp_path / "missing.exr")
    _assert_one_line_input_error(exc, tmp_path / "missing.exr")
    with pytest.raises(InputError, match="directory"):
        read_exr(tmp_path)


def test_failed_exr_write_keeps_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "img.exr"
    old = _layers(seed=1)
    write_exr(path, old, {"run": "first"})
    before = path.read_bytes()

    def failing_write(self: OpenEXR.File, filename: str) -> None:
        with open(filename, "wb") as f:  # a partial file, as a real failure mid-write would leave
            f.write(b"\x76\x2f\x31\x01 partial")
        raise RuntimeError("disk full")

    monkeypatch.setattr(OpenEXR.File, "write", failing_write)
    with pytest.raises(InputError, match="disk full") as exc:
        write_exr(path, _layers(seed=2), {"run": "second"})
    assert "\n" not in str(exc.value)
    monkeypatch.undo()
    assert path.read_bytes() == before
    got, meta = read_exr(path)
    assert np.array_equal(got["L"], old["L"]) and meta == {"run": "first"}
    assert _leftovers(tmp_path, {"img.exr"}) == []


def test_write_creates_parent_directories(tmp_path: Path) -> None:
    paths = write_image_set(tmp_path / "a" / "b" / "img.exr", _layers())
    assert all(p.is_file() for p in paths)


# ----------------------------------------------------------------------------------------------
# tonemapping
# ----------------------------------------------------------------------------------------------


def test_srgb_oetf_analytic_values() -> None:
    assert srgb_oetf(0.0) == 0.0
    assert srgb_oetf(1.0) == pytest.approx(1.0, abs=1e-15)
    assert srgb_oetf(0.5) == pytest.approx(0.7353569830524495, abs=1e-14)
    # Both branches meet (to the precision of the standard's constants) at the breakpoint.
    assert srgb_oetf(0.0031308) == pytest.approx(12.92 * 0.0031308, abs=1e-14)
    assert srgb_oetf(0.0031308) == pytest.approx(1.055 * 0.0031308 ** (1 / 2.4) - 0.055, abs=1e-7)
    assert srgb_oetf(0.001) == pytest.approx(0.01292, abs=1e-15)  # linear segment
    xs = np.linspace(0.0, 1.0, 1001)
    assert np.allclose(srgb_oetf(xs), [_ref_srgb(float(x)) for x in xs], atol=1e-14, rtol=0)
    assert np.all(np.diff(srgb_oetf(xs)) > 0)


def test_aces_curve_values() -> None:
    assert aces_fitted(0.0) == 0.0
    assert aces_fitted(1.0) == pytest.approx(2.54 / 3.16, abs=1e-15)
    assert aces_fitted(8.0) == 1.0
    assert aces_fitted(-3.0) == 0.0
    xs = np.linspace(0.0, 7.0, 500)
    assert np.all(np.diff(aces_fitted(xs)) > 0)


def test_tonemap_end_to_end_pixel_values() -> None:
    # x0 is the radiance the curve maps to exactly 0.5: a wrong OETF (e.g. gamma 2.2, or none) fails.
    x0 = (0.265 + math.sqrt(0.265**2 + 4 * 1.295 * 0.07)) / (2 * 1.295)
    assert _ref_aces(x0) == pytest.approx(0.5, abs=1e-12)
    img = np.array([[[x0, x0, x0], [0.0, 0.0, 0.0], [100.0, 100.0, 100.0], [x0 / 2, x0 / 4, 0.0]]])
    out = tonemap_srgb(img, exposure=0.0)
    assert out.dtype == np.uint8 and out.shape == (1, 4, 3)
    assert out[0, 0].tolist() == [188, 188, 188]  # round(255 * 0.7353569830524495)
    assert out[0, 1].tolist() == [0, 0, 0]
    assert out[0, 2].tolist() == [255, 255, 255]
    # Exposure in stops: +1 stop on x0 / 2 equals x0 at 0 stops.
    doubled = tonemap_srgb(img[:, 3:] * 2, exposure=0.0)
    assert np.array_equal(doubled, tonemap_srgb(img[:, 3:], exposure=1.0))
    expected = [round(255 * _ref_srgb(_ref_aces(v))) for v in (x0 / 2, x0 / 4, 0.0)]
    assert out[0, 3].tolist() == expected


def test_auto_exposure_maps_percentile_to_one() -> None:
    img = np.full((8, 8, 3), 0.037)
    expected = round(255 * _ref_srgb(_ref_aces(1.0)))
    assert np.all(tonemap_srgb(img) == expected)


def test_auto_exposure_is_scale_invariant(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    img = rng.lognormal(-1.0, 1.5, (40, 50, 3))
    a = tonemap_srgb(img)
    assert np.array_equal(a, tonemap_srgb(img * 10.0))
    assert 0 < a.mean() < 255
    # The PNG files written from float32 layers agree as well (float32 * 10 rounds, so allow 1 level).
    layers = {"L": img.astype(np.float32)}
    pa = write_image_set(tmp_path / "a.exr", layers)[1]
    pb = write_image_set(tmp_path / "b.exr", {"L": layers["L"] * np.float32(10.0)})[1]
    ia, ib = np.asarray(Image.open(pa)), np.asarray(Image.open(pb))
    assert np.abs(ia.astype(int) - ib.astype(int)).max() <= 1
    assert np.mean(ia == ib) > 0.999


def test_auto_exposure_black_and_sparse_images() -> None:
    black = np.zeros((5, 6, 3))
    assert np.all(tonemap_srgb(black) == 0)
    sparse = np.zeros((100, 100, 3))
    sparse[3, 4] = 5.0  # fewer than 0.5 % lit pixels: exposed for the brightest, not blown to inf
    out = tonemap_srgb(sparse)
    assert out[3, 4].tolist() == [round(255 * _ref_srgb(_ref_aces(1.0)))] * 3
    assert out.sum() == out[3, 4].sum()


def test_tonemap_non_finite_pixels_become_black_without_warnings() -> None:
    rng = np.random.default_rng(4)
    img = rng.random((40, 50, 3))
    img[0, 0] = np.nan
    img[1, 1, 1] = np.inf
    img[2, 2, 0] = -np.inf
    bad = ~np.all(np.isfinite(img), axis=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "invalid value" / "overflow" RuntimeWarnings either
        out = tonemap_srgb(img)
        assert np.all(tonemap_srgb(np.full((2, 2, 3), np.nan)) == 0)
        assert np.all(tonemap_srgb(np.full((2, 2, 3), np.inf), exposure=0.0) == 0)
        huge = tonemap_srgb(np.array([[[1e308, 1e308, 1e308], [1.0, 0.0, 0.0]]]), exposure=5000.0)
    assert np.all(out[bad] == 0)
    assert huge[0, 0].tolist() == [255, 255, 255] and huge[0, 1].tolist() == [255, 0, 0]
    # The bad pixels are left out of the auto exposure: the others look as with an explicit exposure.
    lum = img[~bad] @ np.array([0.2126, 0.7152, 0.0722])
    stops = -math.log2(np.percentile(lum, 99.5))
    explicit = tonemap_srgb(np.where(bad[:, :, None], 0.0, img), exposure=stops)
    assert np.abs(out.astype(int) - explicit.astype(int)).max() <= 1


def test_tonemap_single_channel_is_grey() -> None:
    out = tonemap_srgb(np.linspace(0, 1, 20).reshape(4, 5))
    assert out.shape == (4, 5, 3)
    assert np.array_equal(out[..., 0], out[..., 1]) and np.array_equal(out[..., 0], out[..., 2])


# ----------------------------------------------------------------------------------------------
# PNG and image sets
# ----------------------------------------------------------------------------------------------


def test_write_image_set_paths_and_png(tmp_path: Path) -> None:
    layers = _layers(h=21, w=34)
    layers["L"] = np.abs(layers["L"])
    layers["L"][0, 0] = np.nan
    paths = write_image_set(tmp_path / "render.exr", layers, {"seed": "1"})
    assert paths == [tmp_path / "render.exr", tmp_path / "render.png"]
    with Image.open(paths[1]) as im:
        assert im.format == "PNG" and im.mode == "RGB" and im.size == (34, 21)
        assert np.array_equal(np.asarray(im), tonemap_srgb(layers["L"]))
    got, meta = read_exr(paths[0])
    # The header records the exposure the PNG was made with (the automatic one here).
    assert meta == {"seed": "1", EXPOSURE_METADATA: repr(auto_exposure_stops(layers["L"]))}
    assert np.array_equal(got["L"], layers["L"], equal_nan=True)
    assert _leftovers(tmp_path, {"render.exr", "render.png"}) == []


def test_write_image_set_other_layer_and_exposure(tmp_path: Path) -> None:
    layers = _layers()
    paths = write_image_set(tmp_path / "x.exr", layers, png_layer="depth", exposure=-20.0)
    with Image.open(paths[1]) as im:
        assert im.mode == "RGB"
        assert np.array_equal(np.asarray(im), tonemap_srgb(layers["depth"], exposure=-20.0))


def test_write_image_set_bad_layer_writes_nothing(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="png_layer"):
        write_image_set(tmp_path / "x.exr", _layers(), png_layer="nope")
    with pytest.raises(ValueError):
        write_image_set(tmp_path / "x.png", _layers())
    assert _leftovers(tmp_path, set()) == []


def test_write_png_modes(tmp_path: Path) -> None:
    rgb = np.random.default_rng(5).integers(0, 256, (7, 9, 3), dtype=np.uint8)
    write_png(tmp_path / "rgb.png", rgb)
    write_png(tmp_path / "grey.png", rgb[..., 0])
    with Image.open(tmp_path / "rgb.png") as im:
        assert im.mode == "RGB" and np.array_equal(np.asarray(im), rgb)
    with Image.open(tmp_path / "grey.png") as im:
        assert im.mode == "L" and np.array_equal(np.asarray(im), rgb[..., 0])
    with pytest.raises(ValueError):
        write_png(tmp_path / "f.png", rgb.astype(np.float32))
    with pytest.raises(ValueError):
        write_png(tmp_path / "f.png", rgb[..., :2])


def test_failed_png_write_keeps_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "p.png"
    write_png(path, np.zeros((4, 4, 3), np.uint8))
    before = path.read_bytes()

    def failing_save(self: Image.Image, fp: object, *args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", failing_save)
    with pytest.raises(InputError, match="No space left"):
        write_png(path, np.full((4, 4, 3), 255, np.uint8))
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert _leftovers(tmp_path, {"p.png"}) == []
