"""The viewer's final gather at rest (runtime/viewer/session.py, ``gather_after``): resting frames from sample
``gather_after`` on take one real bounce before the field, moving frames never; the accumulation is exactly the
plain samples plus the gathered ones; a single light's power edit scales only the field's part of a gathered
L_i (NEE at the bounce already sees the edited light); headers and screenshots count the gathered samples."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from viewer_helpers import AnalyticField, make_session, msg, tiny_scene

from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.viewer.session import ViewerSession


def accumulated(session: ViewerSession, layer: str) -> np.ndarray:
    with session.lock:
        return session._acc[layer] / session._acc.samples


class _Times:
    def __init__(self, inner: AnalyticField, scale: float) -> None:
        self.inner, self.scale = inner, scale

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        return self.scale * self.inner(x, d, g)


def test_resting_samples_after_gather_after_take_the_final_gather(tmp_path: Path) -> None:
    s = make_session(tmp_path, gather_after=2)
    hs = [s.next_frame().header for _ in range(5)]
    assert [h["gathered"] for h in hs] == [0, 0, 1, 2, 3]
    scene = tiny_scene().with_overrides(camera=s.state.view.camera(24, 24))
    plain = render_neural(scene, AnalyticField(), spp=2, seed=5, progress=False).layers
    gathered = render_neural(scene, AnalyticField(), spp=3, seed=5, progress=False, first_sample=2,
                             final_gather_after=0).layers
    for layer in ("L", "L_d", "L_i"):
        np.testing.assert_allclose(accumulated(s, layer), (2 * plain[layer] + 3 * gathered[layer]) / 5, rtol=2e-5,
                                   atol=1e-7)
    assert np.abs(gathered["L_i"] - render_neural(scene, AnalyticField(), spp=3, seed=5, progress=False,
                                                  first_sample=2).layers["L_i"]).max() > 1e-4
    shot = s.screenshot("g")
    assert json.loads(shot[2].read_text())["final_gather_samples"] == 3


def test_moving_frames_never_gather_and_never_means_never(tmp_path: Path) -> None:
    s = make_session(tmp_path, gather_after=0)
    assert s.next_frame().header["gathered"] == 1  # the first frame of a session is a cut, not a move
    s.apply(msg("orbit", dx=5.0, dy=0.0))
    h = s.next_frame().header
    assert h["moving"] and h["gathered"] == 0
    assert s.next_frame().header["gathered"] == 1
    off = make_session(tmp_path / "off", gather_after=None)
    assert [off.next_frame().header["gathered"] for _ in range(3)] == [0, 0, 0]
    pt = make_session(tmp_path / "pt", renderer="pt", gather_after=0)
    assert pt.next_frame().header["gathered"] == 0


def test_a_light_power_edit_scales_only_the_fields_part_of_a_gathered_frame(tmp_path: Path) -> None:
    s = make_session(tmp_path, gather_after=0)
    power = s.state.lights[0].power
    s.apply(msg("light", index=0, power=power * 2.5))
    h = s.next_frame().header
    assert h["gathered"] == 1 and h["warnings"] == []
    edited = tiny_scene().with_overrides(camera=s.state.view.camera(24, 24))
    brighter = replace(edited, lights=(replace(edited.lights[0], power=power * 2.5),), _cache={})
    ref = render_neural(brighter, _Times(AnalyticField(), 2.5), spp=1, seed=5, progress=False,
                        final_gather_after=0).layers
    np.testing.assert_allclose(accumulated(s, "L_i"), ref["L_i"], rtol=1e-5, atol=1e-8)
    # Rescaling the gathered L_i of the edited scene afterwards (what plain frames do) would count the light's new
    # power twice in NEE at the bounce.
    whole = 2.5 * render_neural(brighter, AnalyticField(), spp=1, seed=5, progress=False,
                                final_gather_after=0).layers["L_i"]
    assert np.abs(whole - ref["L_i"]).max() > 1e-3 * np.abs(ref["L_i"]).max()
