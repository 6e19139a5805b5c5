"""The viewer's camera estimator (``pfn-view --camera-estimator``, then the page's ``set camera_estimator``): the
neural renderer's frames are those of ``render_neural`` with that estimator, the default stays the renderer's own,
a change restarts the accumulation, a bad name is refused in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from viewer_helpers import AnalyticField, make_session, msg, tiny_scene

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.viewer.cli import build_parser
from photon_fields.runtime.viewer.state_message import state_message


def first_frame(out_dir: Path, **kw: object) -> np.ndarray:
    s = make_session(out_dir, gather_after=None, **kw)
    s.next_frame()
    with s.lock:
        return s._acc["L"] / s._acc.samples


def test_marched_frames_are_render_neurals_with_that_estimator(tmp_path: Path) -> None:
    marched = first_frame(tmp_path / "m", camera_estimator="marched")
    default = first_frame(tmp_path / "d")
    scene = tiny_scene().with_overrides(camera=make_session(tmp_path / "v").state.view.camera(24, 24))

    def ref(**kw: object) -> np.ndarray:
        return render_neural(scene, AnalyticField(), spp=1, seed=5, progress=False, **kw).layers["L"]

    np.testing.assert_allclose(marched, ref(camera="marched"), rtol=2e-5, atol=1e-7)
    np.testing.assert_allclose(default, ref(), rtol=2e-5, atol=1e-7)
    assert np.abs(marched - default).max() > 1e-4  # another estimator: another image of the same mean


def test_a_bad_camera_estimator_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="^--camera-estimator: .*'ratio'"):
        make_session(tmp_path, camera_estimator="ratio")
    parse = build_parser().parse_args
    assert parse(["blobs", "--camera-estimator", "marched"]).camera_estimator == "marched"
    assert parse(["blobs"]).camera_estimator is None


def test_the_page_switches_the_estimator_and_the_accumulation_starts_again(tmp_path: Path) -> None:
    s = make_session(tmp_path / "s", gather_after=None)
    for _ in range(2):
        s.next_frame()
    with s.lock:
        assert state_message(s)["camera_estimator"] == "auto" and s._acc.samples == 2
    s.apply(msg("set", control="camera_estimator", value="marched"))
    s.next_frame()
    with s.lock:
        assert state_message(s)["camera_estimator"] == "marched" and s._acc.samples == 1
        shown = s._acc["L"] / s._acc.samples
    np.testing.assert_allclose(shown, first_frame(tmp_path / "m", camera_estimator="marched"), rtol=2e-5, atol=1e-7)


def test_frame_headers_name_the_estimator_a_frame_used(tmp_path: Path) -> None:
    """"auto" (the default) in ``camera_estimator``, what it chose for the scene in ``camera_estimator_used`` (the
    page's status line shows it); no estimator for renderers without one."""
    s = make_session(tmp_path / "a", gather_after=None)
    header = s.next_frame().header
    scene = tiny_scene().with_overrides(camera=s.state.view.camera(24, 24))
    chosen = render_neural(scene, AnalyticField(), spp=1, seed=5, progress=False).stats["camera_estimator"]
    assert (header["camera_estimator"], header["camera_estimator_used"]) == ("auto", chosen)
    marched = make_session(tmp_path / "m", gather_after=None, camera_estimator="marched").next_frame().header
    assert (marched["camera_estimator"], marched["camera_estimator_used"]) == ("marched", "marched")
    assert make_session(tmp_path / "p", renderer="pt").next_frame().header["camera_estimator_used"] is None


def test_auto_does_not_hold_up_a_scenes_first_frame(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With auto, the first frame of an accumulation whose choice is not made renders forced (it does not wait for
    the probe); the next frame probes and renders what auto chose; a later accumulation (a camera move, full-size
    moving frames) starts with the choice made."""
    from photon_fields.runtime.wavefront import camera_choice

    probes = []

    def noise(scene: object, est: object, camera: str, lv: object, ls: str) -> float:
        probes.append(camera)
        return {"forced": 100.0, "marched": 1.0}[camera]  # marched by far

    monkeypatch.setattr(camera_choice, "noise_variance", noise)
    s = make_session(tmp_path, size=96, gather_after=None, drag_scale=1.0)  # 96^2 pixels: enough for a probe
    used = [s.next_frame().header["camera_estimator_used"] for _ in range(3)]
    assert used == ["forced", "marched", "marched"] and len(probes) == 2
    s.apply(msg("orbit", dx=5.0, dy=0.0))
    assert s.next_frame().header["camera_estimator_used"] == "marched" and len(probes) == 2
