"""render_orbit with the WRLS denoiser (runtime/renderers/orbit.py): each frame's L goes through it with its
camera and the scene's depth; the noisy frame is kept beside the denoised one."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from conftest import constant_tf, small_camera, smooth_field

from photon_fields.runtime.denoise.wrls import WRLSDenoiser
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.images import read_exr
from photon_fields.runtime.renderers.orbit import orbit_frame_paths, orbit_noisy_png_path, render_orbit
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.scene.lights import DirectionalLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.volume import make_volume


@pytest.fixture(scope="module")
def scene() -> Scene:
    vol = make_volume(smooth_field(16), window=(0.0, 1.0), name="smooth")
    return Scene(vol, constant_tf(5.0, 0.9), (DirectionalLight([-0.5, -1.0, -0.3], [1, 1, 1], 2.0),),
                 small_camera(16), 0.0, "orbit")


def test_orbit_writes_denoised_and_noisy_frames(scene, tmp_path) -> None:  # noqa: ANN001
    out = tmp_path / "o" / "f.exr"
    dn = WRLSDenoiser(16, 16)
    seeds = itertools.count()  # fresh samples every frame (render_orbit's docstring)
    summary = render_orbit(scene, lambda s: render_path_traced(s, spp=1, seed=next(seeds), progress=False), out,
                           frames=6,
                           degrees=3.0, progress=False, denoiser=dn)
    paths = orbit_frame_paths(out, 6)
    layers = [read_exr(p)[0] for p in paths]
    assert all(p.with_suffix(".png").exists() and orbit_noisy_png_path(p).exists() for p in paths)
    for i, frame in enumerate(layers):
        assert set(frame) >= {"L", "L_noisy", "L_d", "L_i", "L_e"}
        assert frame["L"].shape == frame["L_noisy"].shape == (16, 16, 3)
        assert not np.array_equal(frame["L"], frame["L_noisy"]), i
    # The denoised sequence changes less from frame to frame than the 1-spp one.
    step = [np.abs(b["L"] - a["L"]).mean() for a, b in zip(layers, layers[1:], strict=False)]
    step_noisy = [np.abs(b["L_noisy"] - a["L_noisy"]).mean() for a, b in zip(layers, layers[1:], strict=False)]
    assert np.mean(step) < 0.5 * np.mean(step_noisy), (step, step_noisy)
    data = json.loads((tmp_path / "o" / "f_timings.json").read_text())
    assert data["denoiser"]["name"] == "wrls" and len(data["denoiser"]["denoise_ms"]) == 6
    assert data["denoiser"]["params"]["alpha"] == 0.75
    assert summary["denoiser"]["mean_depth_ms"] > 0
    assert dn.frames == 6 and dn.history_weight.max() > 0  # it followed the camera with its history


def test_orbit_refuses_a_denoiser_of_another_size(scene, tmp_path) -> None:  # noqa: ANN001
    with pytest.raises(InputError) as err:
        render_orbit(scene, lambda s: render_path_traced(s, spp=1, progress=False), tmp_path / "x.exr", frames=2,
                     progress=False, denoiser=WRLSDenoiser(8, 16))
    assert "\n" not in str(err.value) and "8x16" in str(err.value)
