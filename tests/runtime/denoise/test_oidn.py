"""Intel Open Image Denoise (runtime/denoise/oidn.py) and ``pfn-render --denoise oidn``.

With pyoidn installed (the ``oidn`` extra, which ``make test`` installs): the denoiser removes noise from an
image of known content, keeps HDR values and constants, uses the albedo it is given, is deterministic, and the
command line writes the denoised L beside the renderer's layers. Without it (simulated by hiding the module):
the runtime imports and renders, and asking for OIDN is one line naming the way to install it.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.cli.render import _main
from photon_fields.runtime.denoise import oidn
from photon_fields.runtime.denoise.oidn import INSTALL, denoise_oidn, oidn_available
from photon_fields.runtime.denoise.registry import DENOISER_NAMES, DENOISERS
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.images import EXPOSURE_METADATA, read_exr, tonemap_srgb

needs_oidn = pytest.mark.skipif(not oidn_available(),
                                reason=f"pyoidn (Intel Open Image Denoise) is not installed: {INSTALL}")

TINY = ["--scene", "blobs", "--size", "16x16", "--spp", "1", "--seed", "5", "--quiet"]


def rel_l2(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(img - ref) / np.linalg.norm(ref))


def smooth_image(h: int = 64, w: int = 64) -> np.ndarray:
    """A smooth RGB image with values up to 0.9 and gentle gradients (no edges)."""
    y, x = np.mgrid[0:h, 0:w] / 64.0
    return np.stack([0.5 + 0.4 * np.sin(2 * np.pi * x) * np.cos(np.pi * y), 0.3 + 0.2 * x, 0.6 - 0.3 * y],
                    axis=-1).astype(np.float32)


def noisy(truth: np.ndarray, seed: int) -> np.ndarray:
    """Monte Carlo-like noise: each pixel times a Gamma(2) variate of mean 1 (rel. L2 about 0.7)."""
    return (truth * np.random.default_rng(seed).gamma(2.0, 0.5, truth.shape)).astype(np.float32)


def one_line(err: BaseException | str) -> str:
    text = str(err)
    assert "\n" not in text.strip() and text, text
    return text


# ----------------------------------------------------------------------------------------------------------
# the registry


def test_registry_names_oidn_for_stills() -> None:
    assert "oidn" in DENOISER_NAMES and tuple(DENOISERS) == DENOISER_NAMES
    entry = DENOISERS["oidn"]
    assert entry.stills and not entry.sequences
    assert entry.denoise_function() is denoise_oidn


def test_the_runtime_imports_without_loading_pyoidn() -> None:
    """Building the command line and importing the denoiser module must not import pyoidn (a 170 MB optional
    package whose import alone takes a second): only denoising does."""
    code = ("import sys, photon_fields.runtime.cli.render as r, photon_fields.runtime.denoise.oidn; "
            "r.build_parser(); print('pyoidn' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# ----------------------------------------------------------------------------------------------------------
# without pyoidn (simulated)


@pytest.fixture
def no_pyoidn(monkeypatch: pytest.MonkeyPatch) -> None:
    """``import pyoidn`` fails as on a machine without the extra."""
    monkeypatch.setitem(sys.modules, "pyoidn", None)


@pytest.mark.usefixtures("no_pyoidn")
def test_missing_pyoidn_is_one_line_naming_the_extra() -> None:
    assert not oidn_available()
    with pytest.raises(InputError) as info:
        denoise_oidn(smooth_image(8, 8))
    line = one_line(info.value)
    assert "oidn" in line and "pyoidn" in line and INSTALL in line


def test_too_old_pyoidn_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    """pyoidn 2.3 cannot switch the filter to HDR (module docstring): refused by version, in one line."""
    pytest.importorskip("pyoidn")
    monkeypatch.setattr(oidn.metadata, "version", lambda name: "2.3.2")
    with pytest.raises(InputError, match="too old") as info:
        oidn.require_oidn("--denoise oidn")
    assert INSTALL in one_line(info.value) and "--denoise oidn" in str(info.value)


@pytest.mark.usefixtures("no_pyoidn")
def test_cli_renders_without_pyoidn_and_refuses_denoise_in_one_line(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert _main([*TINY, "--out", str(tmp_path / "plain.exr")]) == 0
    assert set(read_exr(tmp_path / "plain.exr")[0]) == {"L", "L_d", "L_i", "L_e"}
    capsys.readouterr()
    out = tmp_path / "denoised"
    assert _main([*TINY, "--denoise", "oidn", "--out", str(out / "r.exr")]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --denoise oidn: ") and INSTALL in lines[0], captured.err
    assert captured.out == "" and not out.exists()  # refused before rendering: nothing written


# ----------------------------------------------------------------------------------------------------------
# bad input (checked before pyoidn is needed, so these run everywhere)


@pytest.mark.parametrize(("image", "needle"), [
    (np.ones((8, 8)), "(H, W, 3)"),
    (np.ones((8, 8, 4)), "(H, W, 3)"),
    (np.ones((0, 8, 3)), "(H, W, 3)"),
    (np.full((8, 8, 3), "a"), "dtype"),
    (np.where(np.arange(192).reshape(8, 8, 3) == 7, np.nan, 1.0), "1 pixel(s) with NaN"),
    (np.where(np.arange(192).reshape(8, 8, 3) == 7, np.inf, 1.0), "infinite"),
    (-np.ones((8, 8, 3)), "negative"),
])
def test_bad_colour_is_one_line(image: np.ndarray, needle: str) -> None:
    with pytest.raises(InputError) as info:
        denoise_oidn(image, what="--denoise oidn")
    line = one_line(info.value)
    assert line.startswith("--denoise oidn: colour image") and needle in line, line


@pytest.mark.parametrize(("albedo", "needle"), [
    (np.full((8, 6, 3), 0.5), "is 6x8 but the colour image 7x8"),
    (np.full((8, 7), 0.5), "(H, W, 3)"),
    (np.full((8, 7, 3), 1.5), "[0, 1]"),
    (np.full((8, 7, 3), np.nan), "NaN"),
])
def test_bad_albedo_is_one_line(albedo: np.ndarray, needle: str) -> None:
    with pytest.raises(InputError) as info:
        denoise_oidn(np.ones((8, 7, 3), np.float32), albedo)
    line = one_line(info.value)
    assert line.startswith("denoiser oidn: albedo image") and needle in line, line


@pytest.mark.parametrize(("kwargs", "needle"), [({"quality": "best"}, "quality"), ({"threads": -1}, "threads"),
                                                ({"threads": 1.5}, "threads")])
def test_bad_settings_are_one_line(kwargs: dict, needle: str) -> None:
    with pytest.raises(InputError, match=needle) as info:
        denoise_oidn(np.ones((8, 8, 3), np.float32), **kwargs)
    one_line(info.value)


# ----------------------------------------------------------------------------------------------------------
# what it computes


@needs_oidn
def test_denoises_a_noisy_smooth_image_towards_it() -> None:
    truth = smooth_image()
    for seed in range(2):
        image = noisy(truth, seed)
        before, after = rel_l2(image, truth), rel_l2(denoise_oidn(image), truth)
        assert before > 0.6 and after < 0.2 * before, (before, after)  # measured: 0.70 -> 0.07


@needs_oidn
@pytest.mark.parametrize("value", [0.5, 7.0])
def test_constant_stays_constant_hdr_values_kept(value: float) -> None:
    """A constant image comes back close to itself, above 1 too: HDR mode is on (in LDR mode OIDN clips
    to [0, 1], so 7 would come back as at most 1)."""
    out = denoise_oidn(np.full((32, 48, 3), value, np.float32))
    assert abs(float(out.mean()) / value - 1) < 0.02
    assert float(np.abs(out / value - 1).max()) < 0.1  # measured: within 5 % at the borders


@needs_oidn
def test_output_shape_dtype_inputs_untouched_and_deterministic() -> None:
    image = noisy(smooth_image(20, 30), 3)
    kept = image.copy()
    out = denoise_oidn(image)
    assert out.shape == (20, 30, 3) and out.dtype == np.float32 and out.flags["C_CONTIGUOUS"]
    assert out is not image and np.array_equal(image, kept)
    assert np.array_equal(denoise_oidn(image), out)  # the same bytes again, from the reused filter
    assert np.array_equal(denoise_oidn(image, threads=1), out)  # and for any thread count
    # float64 and non-contiguous views are accepted as the same image
    wide = np.ascontiguousarray(np.concatenate([image, image], axis=1), dtype=np.float64)
    assert np.array_equal(denoise_oidn(wide[:, :30]), out)
    assert denoise_oidn(np.zeros((1, 1, 3), np.float32)).shape == (1, 1, 3)


@needs_oidn
def test_sizes_can_change_between_calls() -> None:
    """The reused filter is re-bound call by call: a smaller image, then the first one again, give the
    results of fresh calls."""
    a, b = noisy(smooth_image(40, 40), 1), noisy(smooth_image(24, 16), 2)
    first = denoise_oidn(a)
    assert denoise_oidn(b).shape == (24, 16, 3)
    assert np.array_equal(denoise_oidn(a), first)


@needs_oidn
def test_the_albedo_it_is_given_is_used() -> None:
    """An image that is an edged albedo times a constant light: with the albedo, OIDN keeps the edges the
    noise hides and the error drops (measured 0.25 -> 0.15); without it wired in, both would be equal."""
    y, x = np.mgrid[0:64, 0:64] / 64.0
    checker = ((np.floor(x * 8) + np.floor(y * 8)) % 2).astype(np.float32)
    albedo = np.repeat((0.2 + 0.7 * checker)[:, :, None], 3, axis=2)
    truth = 1.5 * albedo
    image = noisy(truth, 0)
    without, with_albedo = rel_l2(denoise_oidn(image), truth), rel_l2(denoise_oidn(image, albedo), truth)
    assert with_albedo < 0.8 * without, (without, with_albedo)
    assert np.array_equal(denoise_oidn(image), denoise_oidn(image, None))  # and dropped again when not given


# ----------------------------------------------------------------------------------------------------------
# pfn-render --denoise oidn


@needs_oidn
def test_cli_writes_denoised_l_and_keeps_the_noisy_layers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plain, denoised = tmp_path / "plain.exr", tmp_path / "denoised.exr"
    assert _main([*TINY, "--out", str(plain)]) == 0
    capsys.readouterr()
    assert _main([*TINY, "--denoise", "oidn", "--out", str(denoised)]) == 0
    assert "denoised: oidn in" in capsys.readouterr().out
    before, _ = read_exr(plain)
    layers, meta = read_exr(denoised)
    assert set(layers) == {"L", "L_noisy", "L_d", "L_i", "L_e"}
    for name in ("L_d", "L_i", "L_e"):  # the renderer's layers, untouched
        assert np.array_equal(layers[name], before[name]), name
    assert np.array_equal(layers["L_noisy"], before["L"])
    assert np.array_equal(layers["L"], denoise_oidn(before["L"]))  # L is OIDN's image of the noisy L
    assert not np.array_equal(layers["L"], layers["L_noisy"])
    assert meta["photon_fields.denoiser"] == "oidn"
    report = json.loads(denoised.with_suffix(".json").read_text())
    assert report["denoise"]["name"] == "oidn" and report["denoise"]["ms"] > 0
    assert report["denoise"]["noisy_layer"] == "L_noisy" and report["denoise"]["version"]
    from PIL import Image

    with Image.open(denoised.with_suffix(".png")) as im:  # the PNG shows the denoised L
        png = np.asarray(im)
    assert np.array_equal(png, tonemap_srgb(layers["L"], float(meta[EXPOSURE_METADATA])))
    assert report["exposure"]["stops"] == float(meta[EXPOSURE_METADATA])


def test_cli_denoises_radiance_clamped_at_zero() -> None:
    """pfn-render --denoise gives the denoiser L with its negative pixels (an unbiased estimator's control variate
    leaves a few at low spp: the "marched" camera estimator) at 0, and keeps the renderer's own L as L_noisy."""
    from photon_fields.runtime.cli.render import denoise_layers
    from photon_fields.runtime.denoise.registry import Denoiser

    seen = []

    class StandIn(Denoiser):
        def denoise_function(self):  # noqa: ANN202
            return lambda image, threads, what: seen.append(image) or image + 1.0

    noisy = np.full((4, 5, 3), 0.5, np.float32)
    noisy[1, 2, 0] = -0.01
    out, report = denoise_layers({"L": noisy, "L_d": noisy}, StandIn("stand-in", "test"), None)
    assert seen[0].min() == 0.0 and seen[0][0, 0, 0] == 0.5
    assert out["L_noisy"] is noisy and out["L"][1, 2, 0] == 1.0 and report["name"] == "stand-in"
