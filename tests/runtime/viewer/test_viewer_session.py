"""The viewer's render state machine (runtime/viewer/session.py) on a 32^3 scene at 24x24: progressive
accumulation (exactly one multi-spp render for the neural renderer), restarts on camera moves, newest state
wins, g and light edits reach the image, layer and exposure changes do not restart, screenshots are atomic,
complete and confined to the output folder."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from viewer_helpers import AnalyticField, make_session, msg, tiny_scene

from photon_fields.runtime.io.images import read_exr
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.viewer.messages import MessageError
from photon_fields.runtime.viewer.session import ViewerSession


def frames(session: ViewerSession, n: int) -> list[dict]:
    return [session.next_frame().header for _ in range(n)]


def accumulated(session: ViewerSession, layer: str) -> np.ndarray:
    with session.lock:
        return session._acc[layer] / session._acc.samples


def test_neural_accumulation_equals_one_render_with_all_samples(tmp_path: Path) -> None:
    s = make_session(tmp_path)
    hs = frames(s, 6)
    assert [h["spp"] for h in hs] == [1, 2, 3, 4, 5, 6]
    scene = tiny_scene().with_overrides(camera=s.state.view.camera(24, 24))
    ref = render_neural(scene, AnalyticField(), spp=6, seed=5, progress=False).layers
    for layer in ("L", "L_d", "L_i"):
        assert np.abs(ref[layer]).max() > 0
        np.testing.assert_allclose(accumulated(s, layer), ref[layer], rtol=2e-5, atol=1e-7)


def test_path_tracer_accumulation_is_the_mean_of_seeded_frames(tmp_path: Path) -> None:
    s = make_session(tmp_path, renderer="pt")
    frames(s, 4)
    scene = tiny_scene().with_overrides(camera=s.state.view.camera(24, 24))
    mean = np.mean([render_path_traced(scene, spp=1, seed=5 + i, progress=False).layers["L"] for i in range(4)], 0)
    np.testing.assert_allclose(accumulated(s, "L"), mean, rtol=1e-5, atol=1e-7)
    # Four different frames, not one frame four times.
    one = render_path_traced(scene, spp=1, seed=5, progress=False).layers["L"]
    assert np.abs(accumulated(s, "L") - one).max() > 1e-3


def test_camera_move_restarts_at_one_sample_and_newest_camera_wins(tmp_path: Path) -> None:
    s = make_session(tmp_path)
    assert [h["spp"] for h in frames(s, 3)] == [1, 2, 3]
    for i in range(5):  # five drags arrive while a frame renders: only the last state is rendered
        s.apply(msg("orbit", dx=4.0, dy=1.0, seq=10 + i))
    h = s.next_frame().header
    assert (h["spp"], h["seq"], h["moving"]) == (1, 14, True)
    expected = make_session(tmp_path)
    expected.apply(msg("orbit", dx=20.0, dy=5.0))
    expected.next_frame()
    np.testing.assert_allclose(accumulated(s, "L"), accumulated(expected, "L"), rtol=1e-6, atol=1e-8)
    assert s.state.view.camera(24, 24).eye.tolist() == pytest.approx(expected.state.view.camera(24, 24).eye.tolist())
    assert s.next_frame().header["spp"] == 2  # resting again: refining


@pytest.mark.parametrize("renderer", ["neural", "pt"])
def test_g_changes_the_indirect_layer_and_restarts(tmp_path: Path, renderer: str) -> None:
    s = make_session(tmp_path, renderer=renderer)
    frames(s, 2)
    before = accumulated(s, "L_i").copy()
    s.apply(msg("set", control="g", value=0.8))
    assert s.next_frame().header["spp"] == 1
    frames(s, 1)
    after = accumulated(s, "L_i")
    assert s.state.g == 0.8
    assert np.abs(after - before).mean() > 0.05 * np.abs(before).mean()


def test_layer_exposure_and_format_do_not_restart(tmp_path: Path) -> None:
    s = make_session(tmp_path, max_spp=3)
    frames(s, 3)
    gen = s.generation
    s.apply(msg("set", control="layer", value="L_i"))
    s.apply(msg("set", control="exposure", value=2.0))
    s.apply(msg("set", control="format", value="png"))
    h = s.next_frame()
    assert s.generation == gen and h.header["spp"] == 3 and not h.header["rendered"]
    assert (h.header["layer"], h.header["format"]) == ("L_i", "png")
    assert h.image[:8] == b"\x89PNG\r\n\x1a\n"
    with s.lock:
        assert not s.wants_frame()  # converged at max_spp: the render thread idles


def test_exposure_offset_adds_stops_and_auto_measures_again(tmp_path: Path) -> None:
    s = make_session(tmp_path)
    base = s.next_frame().header["exposure"]
    s.apply(msg("set", control="exposure", value=1.5))
    assert s.next_frame().header["exposure"] == pytest.approx(base + 1.5)
    s.apply(msg("set", control="g", value=0.5))  # g does not re-measure: its effect stays visible
    assert s.next_frame().header["exposure"] == pytest.approx(base + 1.5)


def test_light_edits_change_direct_light_and_are_checked(tmp_path: Path) -> None:
    s = make_session(tmp_path)
    frames(s, 2)
    before = accumulated(s, "L_d").copy()
    s.apply(msg("light", index=0, azimuth=s.state.lights[0].azimuth + 90.0))
    h = s.next_frame().header
    frames(s, 1)
    assert np.abs(accumulated(s, "L_d") - before).mean() > 0.05 * np.abs(before).mean()
    assert h["warnings"] and "trained" in h["warnings"][0]
    s.apply(msg("light", index=0, power=0.0 + s.state.lights[0].power * 2))
    with pytest.raises(MessageError, match="index 3"):
        s.apply(msg("light", index=3, power=1.0))
    with pytest.raises(MessageError, match="power above 0"):
        s.apply(msg("light", index=0, power=0.0))


def test_single_light_power_rescales_the_indirect_layer_exactly(tmp_path: Path) -> None:
    """One light: a power edit scales the field's L_i by the power ratio (radiance is linear in it) and NEE's L_d
    follows the edited light, with no warning; moving the light instead warns and leaves L_i unscaled. (The forced
    estimator: "auto" would probe with each estimator, the field's and None, and may choose differently.)"""
    s = make_session(tmp_path, camera_estimator="forced")
    assert len(s.state.lights) == 1
    power = s.state.lights[0].power
    s.apply(msg("light", index=0, power=power * 2.5))
    h = s.next_frame().header
    assert h["warnings"] == []
    edited = tiny_scene().with_overrides(camera=s.state.view.camera(24, 24))
    base = render_neural(edited, AnalyticField(), spp=1, seed=5, progress=False, camera="forced").layers
    np.testing.assert_allclose(accumulated(s, "L_i"), 2.5 * base["L_i"], rtol=1e-5, atol=1e-8)
    brighter = replace(edited, lights=(replace(edited.lights[0], power=power * 2.5),), _cache={})
    ld = render_neural(brighter, None, spp=1, seed=5, progress=False, camera="forced").layers["L_d"]
    np.testing.assert_allclose(accumulated(s, "L_d"), ld, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(accumulated(s, "L"), accumulated(s, "L_e") + accumulated(s, "L_d")
                               + accumulated(s, "L_i"), rtol=1e-5, atol=1e-7)
    s.apply(msg("light", index=0, azimuth=s.state.lights[0].azimuth + 30.0))
    assert s.field.indirect_scale(s.state.lights) is None
    assert "does not follow" in s.next_frame().header["warnings"][0]


def test_light_controls_round_trip_the_scene_lights(tmp_path: Path) -> None:
    s = make_session(tmp_path)
    for control, light in zip(s.state.lights, tiny_scene().lights, strict=True):
        np.testing.assert_allclose(control.light().direction, light.direction, atol=1e-12)
        assert control.light().power == light.power


def test_renderer_without_its_input_is_refused(tmp_path: Path) -> None:
    s = ViewerSession(tiny_scene(), out_dir=tmp_path, width=24, height=24)
    assert s.available == ["pt", "preview"] and s.state.renderer == "pt"
    with pytest.raises(MessageError, match="not available"):
        s.apply(msg("set", control="renderer", value="neural"))
    with pytest.raises(MessageError, match="not available"):
        s.apply(msg("set", control="renderer", value="photonmap"))


def test_moving_frames_are_denoised_then_accumulation_is_shown(tmp_path: Path) -> None:
    s = make_session(tmp_path, denoise_frames=2)
    hs = frames(s, 3)
    assert [h["denoised"] for h in hs] == [True, True, False]
    s.apply(msg("orbit", dx=2.0, dy=0.0))
    assert s.next_frame().header["denoised"]
    s.apply(msg("set", control="denoise", value=False))
    assert not s.next_frame().header["denoised"]


def test_view_resize_renders_at_the_new_size(tmp_path: Path) -> None:
    s = make_session(tmp_path)
    s.next_frame()
    s.apply(msg("view", width=32, height=16))
    h = s.next_frame().header
    assert (h["width"], h["height"], h["spp"]) == (32, 16, 1)
    assert accumulated(s, "L").shape == (16, 32, 3)


def test_view_larger_than_the_cap_renders_scaled_down_and_restarts(tmp_path: Path) -> None:
    """The session's size (24x24, pfn-view --size) is the largest frame: before any view message frames are at it;
    a 96x48 view (8x its pixels) renders 32x16 frames (its aspect, at most 576 pixels) with a 32x16 camera, and
    restarts the accumulation; a view that fits to the same size neither restarts nor counts as a cut."""
    s = make_session(tmp_path, max_spp=64)
    hs = frames(s, 3)
    assert [(h["width"], h["height"], h["spp"], h["view_size"]) for h in hs] == [(24, 24, n, None) for n in (1, 2, 3)]
    s.apply(msg("view", width=96, height=48, seq=7))
    h = s.next_frame().header
    assert (h["width"], h["height"], h["spp"], h["view_size"], h["seq"]) == (32, 16, 1, [96, 48], 7)
    assert h["generation"] > hs[-1]["generation"]
    scene = tiny_scene().with_overrides(camera=s.state.view.camera(32, 16))
    ref = render_neural(scene, AnalyticField(), spp=1, seed=5, progress=False).layers["L"]
    np.testing.assert_allclose(accumulated(s, "L"), ref, rtol=2e-5, atol=1e-7)  # not a stretched 24x24 render
    s.apply(msg("view", width=98, height=49))  # fits to 32x16 again: the accumulation goes on
    h2 = s.next_frame().header
    assert (h2["width"], h2["height"], h2["spp"], h2["view_size"]) == (32, 16, 2, [98, 49])
    s.apply(msg("view", width=100, height=50))  # 32x16 again, and a drag before the next frame: still a move,
    s.apply(msg("orbit", dx=3.0, dy=0.0))  # not a cut (a page sends view messages while a person drags)
    h3 = s.next_frame().header
    assert (h3["width"], h3["height"], h3["spp"], h3["moving"], h3["view_size"]) == (32, 16, 1, True, [100, 50])
    s.apply(msg("view", width=20, height=24))  # within the cap: taken as is
    h4 = s.next_frame().header
    assert (h4["width"], h4["height"], h4["spp"]) == (20, 24, 1)


def test_screenshot_records_the_size_it_was_taken_at(tmp_path: Path) -> None:
    out = tmp_path / "shots"
    s = make_session(out)
    s.apply(msg("view", width=200, height=100))  # 32x16 under the 24x24 cap
    frames(s, 2)
    s.screenshot("wide")
    report = json.loads((out / "wide.json").read_text())
    assert (report["camera"]["width"], report["camera"]["height"]) == (32, 16)
    layers, _ = read_exr(out / "wide.exr")
    assert layers["L"].shape[:2] == (16, 32)
    assert Image.open(out / "wide.png").size == (32, 16)


def test_same_seed_same_frames(tmp_path: Path) -> None:
    a, b = make_session(tmp_path), make_session(tmp_path)
    assert [a.next_frame().image for _ in range(2)] == [b.next_frame().image for _ in range(2)]


def test_screenshot_writes_exr_png_json_of_the_accumulation(tmp_path: Path) -> None:
    out = tmp_path / "shots"
    s = make_session(out)
    with pytest.raises(MessageError, match="no frame"):
        s.screenshot("early")
    frames(s, 3)
    files = s.screenshot("one")
    assert sorted(p.name for p in out.iterdir()) == ["one.exr", "one.json", "one.png"]  # no temporary files
    assert [p.name for p in files] == ["one.exr", "one.png", "one.json"]
    layers, _ = read_exr(out / "one.exr")
    np.testing.assert_allclose(layers["L_i"], accumulated(s, "L_i"), rtol=1e-6)
    report = json.loads((out / "one.json").read_text())
    assert report["spp"] == 3 and report["renderer"] == "neural" and report["seed"] == 5
    assert report["camera"]["width"] == 24
    auto = s.screenshot()
    assert auto[0].name.endswith("_0001.exr") and len(list(out.iterdir())) == 6


def test_screenshot_never_replaces_and_never_leaves_the_folder(tmp_path: Path) -> None:
    out = tmp_path / "shots"
    out.mkdir()
    (out / "taken.png").write_bytes(b"keep me")
    s = make_session(out)
    s.next_frame()
    with pytest.raises(MessageError, match="exists"):
        s.screenshot("taken")
    assert (out / "taken.png").read_bytes() == b"keep me" and not (out / "taken.exr").exists()
    for bad in ("../up", "/tmp/abs", "sub/dir", ".hidden", "a" * 80):
        with pytest.raises(MessageError):
            s.screenshot(bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shots"]
    assert sorted(p.name for p in out.iterdir()) == ["taken.png"]


def test_failed_screenshot_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "shots"
    s = make_session(out)
    s.next_frame()

    def broken(*args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("photon_fields.runtime.io.atomic.atomic_write_text", broken)
    with pytest.raises(MessageError, match="writing failed"):
        s.screenshot("full")
    assert list(out.iterdir()) == []


def test_stale_refinement_frames_are_dropped_but_first_frames_never(tmp_path: Path) -> None:
    """A refinement frame whose view changed while it rendered is dropped (the new view comes sooner); the
    first frame of a state is shown even when stale, or a continuous drag would show nothing."""
    s = make_session(tmp_path)
    real = s._render

    cancels = []

    def render_while_input_arrives(scene, state, n, gather, moving, cancel=None, level=0):  # noqa: ANN001, ANN202
        s.apply(msg("orbit", dx=1.0, dy=0.0))  # input arriving during every render
        cancels.append(cancel is not None and cancel())
        return real(scene, state, n, gather, moving, cancel, level)

    assert s.next_frame() is not None  # first frame of the scene camera
    s.apply(msg("orbit", dx=1.0, dy=0.0))
    s._render = render_while_input_arrives
    h1 = s.next_frame()  # first frame of the moved state, stale already: shown
    assert h1 is not None and h1.header["spp"] == 1
    s._render = real
    assert s.next_frame().header["spp"] == 1  # the newest camera, first frame
    assert s.next_frame().header["spp"] == 2  # refining at rest
    s._render = render_while_input_arrives
    assert s.next_frame() is None and s.dropped == 1  # a refinement overtaken by input: dropped
    # a first frame is never cancelled; the refinement was, before its first batch (RenderCancelledError)
    assert cancels == [False, True]
    s._render = real
    h = s.next_frame().header
    assert (h["spp"], h["moving"]) == (1, True)


def test_drag_scale_renders_moving_frames_smaller_and_rest_at_full_size(tmp_path: Path) -> None:
    s = make_session(tmp_path, size=32, drag_scale=0.5, max_spp=1)
    assert s.next_frame().header["width"] == 32  # the first view rests: full size
    s.apply(msg("orbit", dx=3.0, dy=0.0))
    h = s.next_frame().header
    assert (h["width"], h["height"], h["moving"], h["spp"]) == (16, 16, True, 1)
    assert accumulated(s, "L").shape == (16, 16, 3)
    with s.lock:
        assert s.wants_frame()  # at rest again: a full-size frame is due although max_spp = 1 is reached
    h = s.next_frame().header
    assert (h["width"], h["spp"], h["moving"]) == (32, 1, False)
    with s.lock:
        assert not s.wants_frame()
    # The resting accumulation is the one of a session that never rendered at reduced size.
    other = make_session(tmp_path, size=32, max_spp=1)
    other.apply(msg("orbit", dx=3.0, dy=0.0))
    other.next_frame()
    np.testing.assert_allclose(accumulated(s, "L"), accumulated(other, "L"), rtol=1e-6, atol=1e-8)
    s.apply(msg("set", control="drag_scale", value=1.0))
    s.apply(msg("orbit", dx=3.0, dy=0.0))
    assert s.next_frame().header["width"] == 32


def test_auto_drag_level_keeps_the_frame_rate() -> None:
    """drag_scale "auto": a moving frame over budget steps one size down, one that leaves room for the next
    size up (frame time scaling with the pixel count) steps up, anything between stays; the ends hold."""
    from photon_fields.runtime.viewer.session import DRAG_LEVELS, next_drag_level

    budget = 1.0 / 8.0
    assert next_drag_level(0, 0.2, 8.0) == 1  # 200 ms at full size: smaller
    assert next_drag_level(0, 0.01, 8.0) == 0  # the largest size stays
    last = len(DRAG_LEVELS) - 1
    assert next_drag_level(last, 5.0, 8.0) == last  # the smallest size stays however slow
    for level in range(1, len(DRAG_LEVELS)):
        grow = (DRAG_LEVELS[level - 1] / DRAG_LEVELS[level]) ** 2
        assert next_drag_level(level, 0.8 * budget / grow, 8.0) == level - 1
        assert next_drag_level(level, 0.9 * budget / grow, 8.0) == level  # the larger one would be too slow
        assert next_drag_level(level, 1.1 * budget, 8.0) == level  # a little over: hold (no oscillation)
    # A frame time that settles: stepping down from 250 ms at full size reaches a level within budget and stays.
    level, cost_full = 0, 0.25
    for _ in range(10):
        level = next_drag_level(level, cost_full * DRAG_LEVELS[level] ** 2, 8.0)
    assert cost_full * DRAG_LEVELS[level] ** 2 <= 1.15 * budget
    assert level == next_drag_level(level, cost_full * DRAG_LEVELS[level] ** 2, 8.0)


def test_auto_drag_scale_follows_the_level(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With drag_scale "auto" the moving frames take the size of the current level, which moves after every
    moving frame (the level function is replaced by a fixed step, so the test does not depend on speed); frames
    at rest stay full size."""
    import photon_fields.runtime.viewer.session as session_module

    monkeypatch.setattr(session_module, "next_drag_level", lambda level, frame_s: min(level + 2, 4))
    s = make_session(tmp_path, size=64, drag_scale="auto", max_spp=1)
    assert s.next_frame().header["width"] == 64
    sizes = []
    for _ in range(3):
        s.apply(msg("orbit", dx=3.0, dy=0.0))
        sizes.append(s.next_frame().header["width"])
    assert sizes == [64, 32, 16]  # levels 0, 2, 4: 1, 0.5, 0.25 of 64
    # Denoisers of every size share one depth estimator (building one per size costs tens of ms mid-drag).
    assert len(s._denoisers) == 2 and len({id(d.depth_estimator) for d in s._denoisers.values()}) == 1
    h = s.next_frame().header
    assert (h["width"], h["moving"]) == (64, False)
    s.apply(msg("set", control="drag_scale", value="auto"))  # the page's selector
    assert s.state.drag_scale == "auto"


def test_lights_scaled_together_rescale_and_one_of_several_is_stale() -> None:
    """L_i follows the page's lights when their fluxes change by one factor (exact), not when one of two lights
    changes alone (that would need per-light outputs)."""
    from photon_fields.runtime.scene.lights import PointLight
    from photon_fields.runtime.viewer.field_in_use import FieldInUse
    from photon_fields.runtime.viewer.light_control import LightControl

    scene = tiny_scene()
    two = replace(scene, lights=(scene.lights[0], PointLight([0.9, 0.2, 0.9], [0.6, 0.75, 1.0], 0.6)), _cache={})
    field = FieldInUse(two, estimator=AnalyticField())
    controls = [LightControl.from_light(light) for light in two.lights]
    np.testing.assert_array_equal(field.indirect_scale(controls), [1.0, 1.0, 1.0])
    both = [replace(c, power=c.power * 2.0) for c in controls]
    np.testing.assert_allclose(field.indirect_scale(both), [2.0, 2.0, 2.0], rtol=1e-12)
    assert field.indirect_scale([both[0], controls[1]]) is None
    assert field.stale(two.tf, [both[0], controls[1]]) and not field.stale(two.tf, both)
    bluer = [replace(c, color=c.color * np.array([0.5, 1.0, 2.0])) for c in controls]
    np.testing.assert_allclose(field.indirect_scale(bluer), [0.5, 1.0, 2.0], rtol=1e-12)
