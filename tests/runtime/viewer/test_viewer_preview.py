"""The preview renderer in a viewer session (``preview``: the ray marcher): frames are jittered marches of seed
``seed + n`` that a resting view averages up to ``PREVIEW_FRAMES`` and never denoises; it needs no field and
follows every transfer-function and light edit at once, with a light volume of the edited scene (never the one a
camera move keeps)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_viewer_transfer import MANUAL, edited
from viewer_helpers import make_session, msg

from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.viewer.field_in_use import PREVIEW_FRAMES
from photon_fields.runtime.viewer.session import ViewerSession


def accumulated(session: ViewerSession, layer: str) -> np.ndarray:
    with session.lock:
        return session._acc[layer] / session._acc.samples


def marched_mean(scene: Scene, seeds: range) -> np.ndarray:
    return np.mean([render_ray_marched(scene, spp=1, seed=s, progress=False).layers["L_d"] for s in seeds], 0)


def test_preview_frames_average_jittered_marches_and_stop(tmp_path: Path) -> None:
    s = make_session(tmp_path, renderer="preview", max_spp=64)
    assert "preview" in s.available and "preview" in s.describe()["renderers"]
    hs = [s.next_frame().header for _ in range(3)]
    assert [h["spp"] for h in hs] == [1, 2, 3]
    assert not any(h["denoised"] or h["stale"] for h in hs) and all(h["warnings"] == [] for h in hs)
    scene = s.edited_scene(s.state).with_overrides(camera=s.state.view.camera(s.state.width, s.state.height))
    ref = marched_mean(scene, range(s.seed, s.seed + 3))
    assert ref.max() > 0.0
    np.testing.assert_allclose(accumulated(s, "L_d"), ref, rtol=1e-5, atol=1e-7)
    assert np.abs(accumulated(s, "L_d") - marched_mean(scene, range(s.seed, s.seed + 1))).max() > 0.0  # 3 frames
    assert not accumulated(s, "L_i").any()  # single scattering: no L_i, and nothing stale about it
    while s.wants_frame():
        s.next_frame()
    assert s._acc.samples == PREVIEW_FRAMES < s.state.max_spp


def test_preview_follows_transfer_and_light_edits_with_the_edited_scenes_light_volume(tmp_path: Path) -> None:
    """After a camera move (which keeps the light volume), a light edit and then a transfer-function edit: each
    first frame is the edited scene's own march from scratch, so no light volume of an earlier scene was read."""
    s = make_session(tmp_path, renderer="preview", retrain=MANUAL)
    s.next_frame()
    s.apply(msg("orbit", dx=30.0, dy=0.0))
    s.next_frame()
    s.next_frame()  # the resting view's first frame
    for edit in (msg("light", index=0, azimuth=s.state.lights[0].azimuth + 120.0),
                 msg("transfer", **edited(s, density_scale=3 * s.base_scene.tf.density_scale))):
        before = accumulated(s, "L_d").copy()
        s.apply(edit)
        h = s.next_frame().header
        assert h["spp"] == 1 and not h["stale"] and h["warnings"] == []
        fresh = replace(s.base_scene, tf=s.state.transfer or s.base_scene.tf, _cache={},
                        lights=tuple(lt.light() for lt in s.state.lights)).with_overrides(
            camera=s.state.view.camera(s.state.width, s.state.height))  # built here: no cache of the session's
        np.testing.assert_allclose(accumulated(s, "L_d"), marched_mean(fresh, range(s.seed, s.seed + 1)), rtol=1e-5,
                                   atol=1e-7, err_msg=edit.type)
        assert np.abs(accumulated(s, "L_d") - before).mean() > 0.05 * np.abs(before).mean(), edit.type


def test_a_light_edit_keeps_what_depends_on_the_medium_alone(tmp_path: Path) -> None:
    """A light edit shares the medium, the march's step grids and the walks' depth bounds with the scene before it
    (``Scene.adopt_medium``; a 512^3 step grid is a second of work), never its light volumes; a transfer-function
    edit shares none of them."""
    s = make_session(tmp_path, renderer="preview", retrain=MANUAL)
    s.next_frame()
    before = s.scene
    grids, bounds, volumes = (before.shared_cache(k) for k in ("step_units", "depth_bounds", "light_volumes"))
    assert grids and volumes
    s.apply(msg("light", index=0, azimuth=s.state.lights[0].azimuth + 45.0))
    s.next_frame()
    lit = s.scene
    assert lit is not before and lit.medium() is before.medium()
    assert lit.shared_cache("step_units") is grids and lit.shared_cache("depth_bounds") is bounds
    assert lit.shared_cache("light_volumes") is not volumes
    s.apply(msg("transfer", **edited(s, density_scale=2 * s.base_scene.tf.density_scale)))
    s.next_frame()
    assert s.scene.medium() is not lit.medium() and s.scene.shared_cache("step_units") is not grids


def test_each_change_shows_the_interactive_level_first_and_rests_on_the_full_volume(tmp_path: Path) -> None:
    """With an interactive level (here 1 on the 32^3 scene; ``auto`` picks one above 128 voxels a side), the first
    frame of every change (the first view, a camera move, an edit) is the march of that level of the volume; the
    view at rest starts its accumulation anew with full-level frames (the coarse frame never enters it); other
    renderers never take a level."""
    s = make_session(tmp_path, renderer="preview", retrain=MANUAL, interactive_level=1)

    def scene() -> Scene:
        return s.edited_scene(s.state).with_overrides(camera=s.state.view.camera(s.state.width, s.state.height))

    for change in (None, msg("orbit", dx=25.0, dy=5.0), msg("transfer", **edited(s, opacity_scale=0.7))):
        if change is not None:
            s.apply(change)
        h = s.next_frame().header
        assert (h["level"], h["spp"]) == (1, 1), change
        coarse = render_ray_marched(scene(), spp=1, seed=s.seed, progress=False, level=1).layers["L_d"]
        np.testing.assert_allclose(accumulated(s, "L_d"), coarse, rtol=1e-5, atol=1e-7)
        hs = [s.next_frame().header for _ in range(2)]
        assert [(h["level"], h["spp"]) for h in hs] == [(0, 1), (0, 2)], change
        np.testing.assert_allclose(accumulated(s, "L_d"), marched_mean(scene(), range(s.seed, s.seed + 2)),
                                   rtol=1e-5, atol=1e-7)
        assert np.abs(coarse - marched_mean(scene(), range(s.seed, s.seed + 1))).max() > 0.0  # another image
    s.apply(msg("set", control="renderer", value="pt"))
    assert s.next_frame().header["level"] == 0


def test_a_changes_first_frame_is_shown_even_when_the_next_change_comes_while_it_renders(tmp_path: Path) -> None:
    """During a continuous slider drag every frame is a new change's first: it must be shown although the next edit
    arrives while it renders (only refinements of a view are dropped then), also after a coarse frame."""
    s = make_session(tmp_path, renderer="preview", retrain=MANUAL, interactive_level=1)
    s.next_frame()  # a coarse frame: the view has not rested yet
    render = s._render

    def render_then_edit(*args: object, **kw: object) -> dict:
        layers = render(*args, **kw)
        s.apply(msg("transfer", **edited(s, opacity_scale=0.5)))  # the drag goes on
        return layers

    s._render = render_then_edit  # type: ignore[method-assign]
    s.apply(msg("transfer", **edited(s, opacity_scale=0.8)))
    frame = s.next_frame()
    assert frame is not None and frame.header["level"] == 1


def test_a_resting_preview_frame_gives_way_to_a_move_during_its_fill(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The full-level frame after a coarse one (at 256^3 an edit's is seconds of filling) is a refinement: a move
    arriving while its light volume fills cancels it between fill chunks (dropped, not shown), the move's frame
    comes next, and the resting view's accumulation is then the plain marches' as if nothing had been cancelled."""
    from photon_fields.runtime.renderers import ray_marcher
    from photon_fields.runtime.transport import light_volume

    monkeypatch.setattr(light_volume, "FILL_CHUNK", 1)
    s = make_session(tmp_path, renderer="preview", retrain=MANUAL, interactive_level=1)
    assert s.next_frame().header["level"] == 1
    fill = ray_marcher.fill_wanted
    moves = []

    def fill_while_the_camera_moves(*args: object, **kw: object) -> bool:
        if not moves:
            moves.append(1)
            s.apply(msg("orbit", dx=20.0, dy=0.0))
        return fill(*args, **kw)

    monkeypatch.setattr(ray_marcher, "fill_wanted", fill_while_the_camera_moves)
    assert s.next_frame() is None and s.dropped == 1 and moves
    lv = ray_marcher.scene_light_volume(s.scene, *ray_marcher.light_volume_settings(s.scene))
    assert lv.wanted.any()  # stopped inside its fill, not finished and then dropped
    h = s.next_frame().header
    assert (h["level"], h["moving"], h["spp"]) == (1, True, 1)
    hs = [s.next_frame().header for _ in range(2)]
    assert [(h["level"], h["spp"]) for h in hs] == [(0, 1), (0, 2)]
    scene = s.edited_scene(s.state).with_overrides(camera=s.state.view.camera(s.state.width, s.state.height))
    np.testing.assert_allclose(accumulated(s, "L_d"), marched_mean(scene, range(s.seed, s.seed + 2)), rtol=1e-5,
                               atol=1e-7)


def test_the_preview_with_the_fields_l_i_is_marched_denoised_and_stale_after_an_edit(tmp_path: Path) -> None:
    """``marched``: the preview's L_d and the field's L_i at one marched point per ray, a noisy renderer (its frames
    accumulate to --max-spp and are denoised); its L_i comes from the field, so a transfer-function edit makes it
    stale as the neural renderer's."""
    s = make_session(tmp_path, renderer="marched", max_spp=64, retrain=MANUAL)
    assert "marched" in s.available and "marched" in s.describe()["renderers"]
    h = s.next_frame().header
    assert h["spp"] == 1 and not h["stale"]
    scene = s.edited_scene(s.state).with_overrides(camera=s.state.view.camera(s.state.width, s.state.height))
    one = render_ray_marched(scene, spp=1, seed=s.seed, progress=False, estimator=s.field.estimator).layers
    np.testing.assert_allclose(accumulated(s, "L_d"), one["L_d"], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(accumulated(s, "L_i"), one["L_i"], rtol=1e-5, atol=1e-7)
    assert one["L_i"].max() > 0.0
    for _ in range(3):
        s.next_frame()
    assert s.next_frame().header["denoised"]
    s.apply(msg("transfer", **edited(s, density_scale=3 * s.base_scene.tf.density_scale)))
    assert s.next_frame().header["stale"]


def test_an_idle_render_thread_fills_the_light_volumes_margin_and_stops_for_a_frame(tmp_path: Path) -> None:
    """With no frame wanted (a resting view done), fill_light_margins fills the margin of the preview's light volume
    (the cells beside those its frames filled); once a change makes a frame wanted, it stops before filling."""
    import threading

    from photon_fields.runtime.viewer.idle_work import fill_light_margins

    s = make_session(tmp_path, renderer="preview")
    while s.wants_frame():
        s.next_frame()
    (lv,) = s.scene.shared_cache("light_volumes").values()
    filled = int((lv.values >= 0.0).sum())
    assert lv.margin.any() and filled > 0
    assert fill_light_margins(s, threading.Event())
    assert not lv.margin.any() and int((lv.values >= 0.0).sum()) > filled
    s.apply(msg("orbit", dx=40.0, dy=0.0))
    while s.wants_frame():
        s.next_frame()
    assert lv.margin.any()  # the new view filled cells of its own
    s.apply(msg("orbit", dx=40.0, dy=0.0))  # a frame is wanted again: the margin waits, marked
    filled = int((lv.values >= 0.0).sum())
    assert not fill_light_margins(s, threading.Event()) and int((lv.values >= 0.0).sum()) == filled
    stop = threading.Event()
    stop.set()
    assert not fill_light_margins(s, stop) and lv.wanted.any()
    while s.wants_frame():
        s.next_frame()
    assert fill_light_margins(s, threading.Event())  # at rest: what was left marked, and the new margin
    assert not lv.wanted.any() and not lv.margin.any() and (lv.values >= -1.0).all()


def test_idle_work_gives_way_to_every_pages_frames(tmp_path: Path) -> None:
    """While another page's frame holds the render turn, the idle margin waits; a frame waiting for its turn is seen
    (render_turns.frames_waiting), and gets it once the holder is done."""
    import threading
    import time

    from photon_fields.runtime.viewer.idle_work import fill_light_margins
    from photon_fields.runtime.viewer.render_turns import RENDER_LOCK, frames_waiting, render_turn

    s = make_session(tmp_path, renderer="preview")
    while s.wants_frame():
        s.next_frame()
    (lv,) = s.scene.shared_cache("light_volumes").values()
    with render_turn():  # another page's frame renders
        assert not fill_light_margins(s, threading.Event()) and lv.margin.any()
    got = threading.Event()

    def frame() -> None:
        with render_turn():
            got.set()

    with render_turn():
        waiter = threading.Thread(target=frame)
        waiter.start()
        end = time.monotonic() + 10
        while not frames_waiting() and time.monotonic() < end:
            time.sleep(0.01)
        assert frames_waiting() and not got.is_set()
    waiter.join(10)
    assert got.is_set() and not frames_waiting() and not RENDER_LOCK.locked()
    assert fill_light_margins(s, threading.Event()) and not lv.margin.any()


def test_idle_work_fills_the_margin_of_the_interactive_levels_light_volume_too(tmp_path: Path) -> None:
    """The first frame after a change marches the volume's coarser level (here forced to 1): its light volume, kept
    with the level's scene, gets its margin in idle time as the full volume's does."""
    import threading

    from photon_fields.runtime.viewer.idle_work import fill_light_margins

    s = make_session(tmp_path, renderer="preview", interactive_level=1)
    s.next_frame()
    s.apply(msg("orbit", dx=20.0, dy=0.0))
    while s.wants_frame():
        s.next_frame()
    (level,) = s.scene.shared_cache("levels").values()
    (lv,) = level.shared_cache("light_volumes").values()
    assert lv.margin.any()
    assert fill_light_margins(s, threading.Event())
    assert not lv.margin.any() and not lv.wanted.any()
