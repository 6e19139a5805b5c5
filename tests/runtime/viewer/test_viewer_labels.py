"""Label scenes in a viewer session (runtime/viewer/transfer_edit.py's LabelPanel, session.py): the page gets a row
per label present; a ``labels`` edit reaches the path tracer and L_d at once (a hidden label's region goes dark,
its neighbour's stays lit), marks the field's L_i stale until undone and starts the background retrain with the
edited label function; a screenshot records that function as a label TF file LabelTransfer reads back; the
message of the other kind of scene, and labels the volume does not have, are refused, also over the websocket,
where the connection keeps serving."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import pytest
from viewer_helpers import BACKGROUND, BALL, CUBE, inputs, label_scene, make_session, msg, stand_in_trainer

from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.scene.labels import LabelTransfer, volume_labels
from photon_fields.runtime.scene.scene import load_scene
from photon_fields.runtime.viewer.messages import MessageError
from photon_fields.runtime.viewer.retrain import RetrainSettings
from photon_fields.runtime.viewer.session import ViewerSession
from photon_fields.runtime.viewer.transfer_edit import transfer_message

MANUAL = RetrainSettings(auto=False)  # these tests are about the image; the retrain test sets its own


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("labels")


def session(scene_dir: Path, out: Path, renderer: str = "pt", **kw: object) -> ViewerSession:
    return make_session(out, renderer=renderer, scene=label_scene(scene_dir), **{"retrain": MANUAL, **kw})


def labels(**edits: dict) -> dict:
    """A ``labels`` message's fields: ``labels(l3={"visible": False})`` edits label 3."""
    return {"labels": {name[1:]: edit for name, edit in edits.items()}}


def accumulate(s: ViewerSession, layer: str, frames: int = 4) -> np.ndarray:
    """The mean of ``layer`` over ``frames`` frames of the current state (the accumulation, not the denoised
    frame: what is compared is the renderer's image)."""
    for _ in range(frames):
        s.next_frame()
    with s.lock:
        return (s._acc[layer] / s._acc.samples).sum(axis=-1)


def test_the_page_gets_a_row_per_label_present(scene_dir: Path, tmp_path: Path) -> None:
    s = session(scene_dir, tmp_path)
    d = s.describe()
    assert d["transfer"] is None and d["histogram"] is None  # no control points, no histogram for labels
    rows = d["labels"]["rows"]
    grid = volume_labels(s.base_scene.volume)
    assert [r["label"] for r in rows] == [BACKGROUND, BALL, CUBE]
    assert [r["voxels"] for r in rows] == grid.counts.tolist() and sum(r["voxels"] for r in rows) == 32**3
    assert [r["visible"] for r in rows] == [False, True, True]  # the labels preset: background transparent
    assert all(r["opacity"] == 1.0 for r in rows) and rows[1]["albedo"] != rows[2]["albedo"]
    assert d["labels"]["max_edits"] == 32
    # Unedited, the panel's function (every label named) is the scene's own: nothing is stale.
    s.apply(msg("labels", **labels(l3={"visible": True})))
    assert isinstance(s.state.transfer, LabelTransfer) and not s.field_stale(s.state)


def test_hiding_a_label_darkens_its_region_and_only_its_region(scene_dir: Path, tmp_path: Path) -> None:
    """L_d with both objects shown, then with the cube hidden: where only the cube is seen, L_d is exactly 0 (no
    medium is left along those rays); where the ball is seen it stays lit. The frame is exactly the path tracer's
    image of the edited scene."""
    s = session(scene_dir, tmp_path)
    s.apply(msg("labels", **labels(l3={"visible": False})))
    cube = accumulate(s, "L_d") > 0  # where the cube alone is lit
    s.apply(msg("labels", **labels(l3={"visible": True}, l7={"visible": False})))
    ball = accumulate(s, "L_d") > 0
    only_cube = cube & ~ball
    assert only_cube.mean() > 0.1 and ball.mean() > 0.1, (only_cube.mean(), ball.mean())
    s.apply(msg("labels", **labels(l7={"visible": True})))
    both = accumulate(s, "L_d")
    assert both[only_cube].mean() > 0 and (both[only_cube] > 0).mean() > 0.9
    s.apply(msg("labels", **labels(l7={"visible": False}), seq=7))
    h = s.next_frame().header
    assert h["seq"] == 7 and h["spp"] == 1  # the edit restarted the accumulation
    scene = s.edited_scene(s.state).with_overrides(camera=s.state.view.camera(s.state.width, s.state.height))
    ref = render_path_traced(scene, spp=1, seed=s.seed, progress=False).layers
    np.testing.assert_allclose(s._acc["L_d"], ref["L_d"], rtol=1e-5, atol=1e-7)
    hidden = accumulate(s, "L_d", 3)
    assert np.all(hidden[only_cube] == 0.0)
    assert hidden[ball].mean() > 0.5 * both[ball].mean()


def test_colour_and_opacity_reach_the_medium_and_a_shown_label_keeps_its_opacity(scene_dir: Path,
                                                                                 tmp_path: Path) -> None:
    s = session(scene_dir, tmp_path)
    s.apply(msg("labels", **labels(l7={"albedo": [0.0, 1.0, 0.0], "opacity": 0.25})))
    tf = s.state.transfer
    assert tf.opacity[tf.labels.tolist().index(CUBE)] == 0.25
    np.testing.assert_array_equal(tf.albedo[tf.labels.tolist().index(CUBE)], [0.0, 1.0, 0.0])
    s.next_frame()
    m = s.scene.medium()  # the scene the frame rendered: its categorical tables are the panel's
    k = int(np.searchsorted(volume_labels(s.base_scene.volume).values, CUBE))
    assert m.ext_lut[k] == pytest.approx(0.25 * tf.density_scale)
    np.testing.assert_array_equal(m.albedo_lut[k], [0.0, 1.0, 0.0])
    s.apply(msg("labels", **labels(l7={"visible": False})))
    assert s.state.transfer.opacity[k] == 0.0
    s.apply(msg("labels", **labels(l7={"visible": True})))
    assert s.state.transfer.opacity[k] == 0.25  # back at the opacity it had, not at 1
    rows = {r["label"]: r for r in s.describe()["labels"]["rows"]}
    assert rows[CUBE]["opacity"] == 0.25 and rows[CUBE]["visible"] and rows[CUBE]["albedo"] == [0.0, 1.0, 0.0]


def test_the_density_scale_reaches_the_medium_and_keeps_the_rows(scene_dir: Path, tmp_path: Path) -> None:
    """The label panel's density slider: a ``labels`` message with only ``density_scale`` scales every label's
    extinction, keeps each row's colour, opacity and visibility, and makes the field's L_i stale until undone."""
    s = session(scene_dir, tmp_path, renderer="neural")
    base = s.state.transfer.density_scale
    rows = s.describe()["labels"]["rows"]
    s.next_frame()
    s.apply(msg("labels", density_scale=base * 4))
    h = s.next_frame().header
    assert h["stale"] and any("transfer function" in w for w in h["warnings"])
    tf, m = s.state.transfer, s.scene.medium()
    k = int(np.searchsorted(volume_labels(s.base_scene.volume).values, BALL))
    assert tf.density_scale == base * 4 and m.ext_lut[k] == pytest.approx(tf.opacity[k] * base * 4)
    panel = s.describe()["labels"]
    assert panel["density_scale"] == base * 4 and panel["rows"] == rows
    s.apply(msg("labels", **labels(l7={"opacity": 0.5}), density_scale=base))  # both in one message
    assert s.state.transfer.density_scale == base
    s.apply(msg("labels", **labels(l7={"opacity": 1.0})))
    assert not s.next_frame().header["stale"]  # undone: the medium the field was trained for


def test_a_label_edit_marks_the_fields_indirect_light_stale_until_undone(scene_dir: Path, tmp_path: Path) -> None:
    s = session(scene_dir, tmp_path, renderer="neural")
    h = s.next_frame().header
    assert not h["stale"] and h["warnings"] == []
    colour = next(r for r in s.describe()["labels"]["rows"] if r["label"] == BALL)["albedo"]
    for edit, undo in (({"visible": False}, {"visible": True}), ({"albedo": [0.1, 0.9, 0.1]}, {"albedo": colour}),
                       ({"opacity": 0.5}, {"opacity": 1.0})):
        s.apply(msg("labels", **labels(l3=edit)))
        h = s.next_frame().header
        assert h["stale"] and any("stale L_i" in w and "transfer function" in w for w in h["warnings"]), (edit, h)
        s.apply(msg("labels", **labels(l3=undo)))
        h = s.next_frame().header
        assert not h["stale"] and h["warnings"] == [], (undo, h)
    # The background's colour does not matter while it is hidden: still the trained medium.
    s.apply(msg("labels", **labels(l0={"albedo": [0.0, 0.0, 1.0]})))
    assert not s.next_frame().header["stale"]


def test_the_other_kind_of_edit_and_absent_labels_are_refused(scene_dir: Path, tmp_path: Path) -> None:
    s = session(scene_dir, tmp_path)
    before = s.state.transfer, s.state.labels, s.generation
    scalar = make_session(tmp_path / "scalar", renderer="pt", retrain=MANUAL)
    points = transfer_message(scalar.base_scene.tf)
    with pytest.raises(MessageError, match="label transfer function, which has no control points"):
        s.apply(msg("transfer", points=points["points"], density_scale=points["density_scale"]))
    with pytest.raises(MessageError, match=r"labels: labels 4, 12 not in the volume \(its labels: 0, 3, 7\)"):
        s.apply(msg("labels", **labels(l3={"visible": False}, l4={"visible": True}, l12={"opacity": 1.0})))
    assert (s.state.transfer, s.state.labels, s.generation) == before  # nothing changed, not even label 3
    with pytest.raises(MessageError, match="scalar \\(control points\\), not labels"):
        scalar.apply(msg("labels", **labels(l3={"visible": False})))
    assert scalar.state.labels is None and scalar.state.transfer is scalar.base_scene.tf


def test_hiding_every_label_shows_an_empty_view_and_trains_nothing(scene_dir: Path, tmp_path: Path) -> None:
    """"Hide all, then tick one" is allowed: the view is empty, L_i is stale, but no retrain starts (an empty
    scene has nothing to train), and the page's retrain button is refused; showing a label starts it."""
    out = tmp_path / "out"
    s = session(scene_dir, out, renderer="neural", retrain=stand_in_trainer(tmp_path, "slow", delay_s=0.0))
    try:
        s.apply(msg("labels", **labels(l3={"visible": False}, l7={"visible": False})))
        assert np.all(accumulate(s, "L", 1) == 0.0)
        h = s.next_frame().header
        assert h["stale"] and "every label is hidden" in " ".join(h["warnings"])
        with pytest.raises(MessageError, match="every label is hidden"):
            s.apply(msg("retrain", action="start"))
        time.sleep(0.1)
        assert s.poll_updates() is None and s.updater.job is None
        s.apply(msg("labels", **labels(l7={"visible": True})))
        status = s.poll_updates()
        assert status is not None and status["state"] == "running"
    finally:
        s.close()


def test_a_label_edit_retrains_with_the_edited_label_function(scene_dir: Path, tmp_path: Path) -> None:
    """The job gets the edited scene as a scene file: its transfer function is the panel's label function, which
    LabelTransfer reads back against the volume (the trainer loads exactly what the page shows)."""
    out = tmp_path / "out"
    s = session(scene_dir, out, renderer="neural", retrain=stand_in_trainer(tmp_path, "slow", delay_s=0.0))
    try:
        s.apply(msg("labels", **labels(l7={"visible": False}, l3={"albedo": [0.2, 0.9, 0.3]})))
        status = s.poll_updates()
        assert status is not None and status["state"] == "running", status
        job = s.updater.job
        spec = json.loads(job.scene_file.read_text())
        tf = LabelTransfer.from_dict(spec["transfer_function"], volume=s.base_scene.volume)
        assert tf.to_dict() == s.state.transfer.to_dict()
        opacity = dict(zip(tf.labels.tolist(), tf.opacity.tolist(), strict=True))
        assert opacity == {BACKGROUND: 0.0, BALL: 1.0, CUBE: 0.0}
        assert load_scene(job.scene_file).fingerprint() == s.edited_scene(s.state).fingerprint()
    finally:
        s.close()


def test_a_screenshot_records_a_label_function_that_reads_back(scene_dir: Path, tmp_path: Path) -> None:
    s = session(scene_dir, tmp_path / "shots")
    s.apply(msg("labels", **labels(l7={"visible": False}, l3={"albedo": [0.2, 0.9, 0.3], "opacity": 0.6})))
    s.next_frame()
    report = json.loads(next(p for p in s.screenshot("labels") if p.suffix == ".json").read_text())
    path = tmp_path / "labels_tf.json"
    path.write_text(json.dumps(report["transfer_function"]))
    tf = LabelTransfer.load(path, volume=s.base_scene.volume)
    assert tf.to_dict() == s.state.transfer.to_dict()
    shown = {int(k): v for k, v in report["transfer_function"]["labels"].items()}
    assert shown[CUBE]["opacity"] == 0.0 and shown[BALL] == {"albedo": [0.2, 0.9, 0.3], "opacity": 0.6}
    assert report["stale_indirect"] is False  # the path tracer's screenshot has no field to be stale


def test_label_edits_over_the_websocket(scene_dir: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The real server on a label scene: the state carries the panel; a scalar edit and an absent label are each
    refused with an error message and a logged line, and the same connection then renders a label edit."""
    pytest.importorskip("uvicorn")
    from test_viewer_server import next_frame, next_text, ws_url
    from websockets.sync.client import connect

    from photon_fields.runtime.viewer.launch import ViewerServer

    srv = ViewerServer(inputs(tmp_path / "out", scene=label_scene(scene_dir)), port=0, warm=False, max_spp=1 << 16)
    try:
        with caplog.at_level(logging.WARNING, logger="photon_fields.viewer"), \
                connect(ws_url(srv), max_size=None) as ws:
            state = next_text(ws)
            assert [r["label"] for r in state["labels"]["rows"]] == [BACKGROUND, BALL, CUBE]
            assert state["transfer"] is None
            h0, _ = next_frame(ws)
            ws.send(json.dumps({"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, 1]}],
                                "density_scale": 10}))
            ws.send(json.dumps({"type": "labels", "labels": {"5": {"visible": True}}}))
            errors = [next_text(ws) for _ in range(2)]
            assert [e["type"] for e in errors] == ["error", "error"]
            assert "'labels' message" in errors[0]["message"] and "label 5 not in the volume" in errors[1]["message"]
            ws.send(json.dumps({"type": "labels", "labels": {str(CUBE): {"visible": False}}, "seq": 42}))
            for _ in range(40):
                h, _ = next_frame(ws)
                if h["seq"] == 42:
                    break
            assert h["seq"] == 42 and h["generation"] > h0["generation"]
        refused = [r.getMessage() for r in caplog.records if r.getMessage().startswith("refused a message")]
        assert len(refused) == 2 and all("\n" not in line for line in refused), refused
        assert srv.stats.refused == 2
    finally:
        srv.stop()


def test_a_real_retrain_of_a_label_edit_swaps_a_field_in(scene_dir: Path, tmp_path: Path) -> None:
    """The tiny trainer for real on a label edit: pfn-train reads the edited label scene, and the field it trains
    loads against that scene's fingerprint (the label function survived the scene file), is swapped in, and is
    not stale."""
    pytest.importorskip("torch")
    from test_viewer_retrain import poll_until

    settings = RetrainSettings(photons="3k", preset="tiny", steps=3, delay_s=0.0,
                               extra=("--batch", "256", "--k", "32"))
    s = ViewerSession(label_scene(scene_dir), out_dir=tmp_path / "out", seed=5, width=24, height=24,
                      retrain=settings)
    s.apply(msg("labels", **labels(l7={"visible": False})))
    s.apply(msg("retrain", action="start"))
    status = poll_until(s, {"done", "failed"})[-1]
    assert status["state"] == "done", status
    h = s.next_frame().header
    assert h["renderer"] == "neural" and not h["stale"] and h["warnings"] == []
    assert s.pmap.scene_fingerprint == s.edited_scene(s.state).fingerprint()
