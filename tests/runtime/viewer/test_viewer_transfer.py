"""Transfer-function edits in a viewer session (runtime/viewer/session.py): an edit reaches the path tracer and
L_d at once, restarts the accumulation, marks the field's L_i stale (and not when the edit is undone), refuses a
function that leaves nothing visible, and the page gets the function and the volume's histogram to edit it on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from viewer_helpers import make_session, msg

from photon_fields.runtime.denoise.depth import DepthEstimator
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.viewer.messages import MessageError
from photon_fields.runtime.viewer.retrain import RetrainSettings
from photon_fields.runtime.viewer.session import ViewerSession
from photon_fields.runtime.viewer.transfer_edit import transfer_message

MANUAL = RetrainSettings(auto=False)  # these tests are about the image; retraining has its own tests


def edited(session: ViewerSession, opacity_scale: float = 1.0, density_scale: float | None = None) -> dict:
    """A ``transfer`` message: the scene's function with its opacities scaled."""
    t = transfer_message(session.base_scene.tf)
    points = [{"s": p["s"], "opacity": min(1.0, p["opacity"] * opacity_scale), "albedo": p["albedo"]}
              for p in t["points"]]
    return {"points": points, "density_scale": density_scale or t["density_scale"]}


def mean_of(session: ViewerSession, layer: str = "L") -> float:
    with session.lock:
        return float((session._acc[layer] / session._acc.samples).mean())


def test_an_edit_reaches_the_path_traced_image_and_restarts_the_accumulation(tmp_path: Path) -> None:
    s = make_session(tmp_path, renderer="pt", retrain=MANUAL)
    for _ in range(3):
        s.next_frame()
    before = mean_of(s)
    s.apply(msg("transfer", **edited(s, density_scale=4 * s.base_scene.tf.density_scale), seq=3))
    h = s.next_frame().header
    assert h["spp"] == 1 and h["seq"] == 3 and not h["stale"]  # the path tracer is never stale
    scene = s.edited_scene(s.state).with_overrides(camera=s.state.view.camera(s.state.width, s.state.height))
    assert scene.tf.density_scale == 4 * s.base_scene.tf.density_scale
    ref = render_path_traced(scene, spp=1, seed=s.seed, progress=False).layers["L"]
    np.testing.assert_allclose(s._acc["L"], ref, rtol=1e-5, atol=1e-7)  # exactly the edited scene's frame
    assert abs(mean_of(s) - before) > 0.05 * before


def test_an_edit_marks_the_fields_indirect_light_stale_until_undone(tmp_path: Path) -> None:
    s = make_session(tmp_path, retrain=MANUAL)
    h = s.next_frame().header
    assert not h["stale"] and h["warnings"] == []
    d0 = mean_of(s, "L_d")
    s.apply(msg("transfer", **edited(s, opacity_scale=0.3)))
    h = s.next_frame().header
    assert h["stale"] and any("stale L_i" in w and "transfer function" in w and "press retrain" in w
                              for w in h["warnings"]), h["warnings"]
    assert mean_of(s, "L_d") != pytest.approx(d0, rel=0.02)  # L_d follows the edit at once
    s.apply(msg("transfer", **edited(s)))  # back to the function the field was trained for
    h = s.next_frame().header
    assert not h["stale"] and h["warnings"] == []


def test_the_depth_the_denoiser_uses_follows_the_edited_medium(tmp_path: Path) -> None:
    s = make_session(tmp_path, retrain=MANUAL)
    s.next_frame()
    depth = s._denoisers.depth
    assert depth is not None
    s.apply(msg("orbit", dx=3.0, dy=0.0))
    s.next_frame()
    assert s._denoisers.depth is depth  # a camera move keeps it
    s.apply(msg("transfer", **edited(s, opacity_scale=0.5)))
    s.next_frame()
    assert s._denoisers.depth is not None and s._denoisers.depth is not depth
    fresh = DepthEstimator(s.scene.medium())  # the edited medium's coarse extinction, not the old one's
    np.testing.assert_array_equal(s._denoisers.depth.grid, fresh.grid)
    assert not np.array_equal(depth.grid, fresh.grid)


def test_a_function_that_leaves_nothing_visible_is_refused(tmp_path: Path) -> None:
    s = make_session(tmp_path, retrain=MANUAL)
    tf = s.state.transfer
    with pytest.raises(MessageError, match="nothing would be visible"):
        s.apply(msg("transfer", **edited(s, opacity_scale=0.0)))
    assert s.state.transfer is tf


def test_the_page_gets_the_function_and_the_volume_histogram(tmp_path: Path) -> None:
    s = make_session(tmp_path, retrain=MANUAL)
    d = s.describe()
    t = d["transfer"]
    assert t["density_scale"] == s.base_scene.tf.density_scale
    assert [p["s"] for p in t["points"]] == s.base_scene.tf.points.tolist()
    h = np.asarray(d["histogram"])
    assert h.shape == (64,) and h.max() == 1.0 and h.min() >= 0
    counts, _ = np.histogram(s.base_scene.volume.data, bins=64, range=(0, 1))
    assert int(np.argmax(h)) == int(np.argmax(counts))  # log scale keeps the order
    assert d["retrain"]["auto"] is False
    # The message the page would send back is a valid, equal transfer function.
    s.apply(msg("transfer", points=t["points"], density_scale=t["density_scale"]))
    assert not s.field_stale(s.state)


def test_a_screenshot_records_the_edited_function_and_the_stale_indirect_light(tmp_path: Path) -> None:
    import json

    s = make_session(tmp_path, retrain=MANUAL)
    s.apply(msg("transfer", **edited(s, opacity_scale=0.5)))
    s.next_frame()
    report = json.loads(next(p for p in s.screenshot("edited") if p.suffix == ".json").read_text())
    assert report["transfer_function"]["points"][-1]["opacity"] == pytest.approx(
        min(1.0, s.base_scene.tf.opacity[-1] * 0.5))
    assert report["stale_indirect"] is True
