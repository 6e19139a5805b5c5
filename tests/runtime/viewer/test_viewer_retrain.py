"""Background retraining in a viewer session (runtime/viewer/retrain.py, updater.py): a job starts once edits
rest, a newer edit cancels the older job, progress reaches the page, a failed job shows its one line and leaves
the field in use, a page that closes stops its job, and a real (tiny) training swaps a new field in: the neural
renderer appears, and its L_i is no longer stale.

Stand-in trainers (a short script taking pfn-train's arguments) test the orchestration without torch; the last
test runs the real trainer and is skipped where torch is not installed."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from viewer_helpers import make_session, msg, stand_in_trainer

from photon_fields.runtime.viewer import retrain as retrain_module
from photon_fields.runtime.viewer.retrain import RetrainSettings
from photon_fields.runtime.viewer.session import ViewerSession
from photon_fields.runtime.viewer.transfer_edit import transfer_message


def edit(session: ViewerSession, scale: float) -> None:
    t = transfer_message(session.base_scene.tf)
    points = [{**p, "opacity": min(1.0, p["opacity"] * scale)} for p in t["points"]]
    session.apply(msg("transfer", points=points, density_scale=t["density_scale"]))


def poll_until(session: ViewerSession, states: set[str], timeout: float = 600.0) -> list[dict[str, Any]]:
    seen: list[dict[str, Any]] = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        status = session.poll_updates()
        if status is not None:
            seen.append(status)
            if status["state"] in states:
                return seen
        time.sleep(0.05)
    raise AssertionError(f"no {states} status within {timeout} s; saw {seen}")


def jobs(out: Path) -> list[Path]:
    return sorted((out / "retrain").iterdir()) if (out / "retrain").exists() else []


def test_a_job_starts_once_edits_rest_and_a_newer_edit_replaces_it(tmp_path: Path) -> None:
    out = tmp_path / "out"
    s = make_session(out, retrain=stand_in_trainer(tmp_path, "slow", delay_s=0.4))
    try:
        for scale in (0.9, 0.8, 0.7):  # a dragged control point: several edits in a row
            edit(s, scale)
            assert s.poll_updates() is None  # not yet: the edits have not rested
        seen = poll_until(s, {"running"})
        assert len(jobs(out)) == 1 and seen[-1]["folder"] == str(jobs(out)[0])
        first = s.updater.job
        seen = [st for st in poll_until(s, {"running"}) if st.get("stage")]
        assert seen[-1]["stage"] in ("trace", "fit") and 0 <= seen[-1]["fraction"] < 1
        assert "retraining in the background" in " ".join(s.next_frame().header["warnings"])
        edit(s, 0.6)
        poll_until(s, {"running"}, timeout=30)
        while s.updater.job is first:
            s.poll_updates()
        assert first.process.poll() is not None  # the older job was stopped
        assert len(jobs(out)) == 2
        # the scene handed to the trainer is the edited one
        assert s.updater.job.scene.tf.opacity.tolist() == s.state.transfer.opacity.tolist()
    finally:
        s.close()
    assert s.updater.job is None


def test_a_field_with_its_run_folder_is_fine_tuned_and_one_without_is_trained_afresh(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    for name in ("checkpoint.pt", "log.json"):
        (run / name).write_text("stand-in")
    settings = stand_in_trainer(tmp_path, "slow")
    for info, command in (({"bundle": str(run / "field.pfn")}, "update"), ({"bundle": None}, "all")):
        s = make_session(tmp_path / f"out_{command}", retrain=settings, info=info)
        try:
            edit(s, 0.5)
            status = poll_until(s, {"running"})[0]
            assert status["warm_start"] is (command == "update")
            argv_file = s.updater.job.folder / "argv.json"
            while not argv_file.exists():
                time.sleep(0.05)
            argv = json.loads(argv_file.read_text())
            assert argv[0] == command and str(s.updater.job.scene_file) in argv
            if command == "update":
                assert argv[1] == str(run.resolve())
                assert argv[argv.index("--scene") + 1] == str(s.updater.job.scene_file)
        finally:
            s.close()


def test_under_pvrt_a_light_edit_waits_for_the_page_to_leave_pvrt(tmp_path: Path) -> None:
    """PVRT relights from its own transfer: a light drag must not start a retrain that takes a core from it; the
    stale field is retrained once the page switches to a renderer that shows it."""
    from viewer_helpers import tiny_scene, tiny_transfer

    scene = tiny_scene()
    out = tmp_path / "out"
    s = make_session(out, renderer="pvrt", scene=scene, transfer=tiny_transfer(scene),
                     retrain=stand_in_trainer(tmp_path, "slow"))
    try:
        for azimuth in (20.0, 40.0, 60.0):  # a light drag
            s.apply(msg("light", index=0, azimuth=azimuth))
        assert s.field_stale(s.state)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            assert s.poll_updates() is None
            time.sleep(0.05)
        assert s.updater.job is None and jobs(out) == []
        s.apply(msg("set", control="renderer", value="neural"))
        poll_until(s, {"running"})
        assert len(jobs(out)) == 1
        assert s.updater.job.scene.lights[0].direction.tolist() == s.edited_scene(s.state).lights[0].direction.tolist()
    finally:
        s.close()


def test_a_job_is_done_once_its_bundle_is_written_not_when_its_trainer_has_exited(tmp_path: Path) -> None:
    """The trainer's interpreter takes ~1 s to exit after writing the bundle: the swap must not wait for it. The
    exiting process is reaped later (by a poll, or by close())."""
    from viewer_helpers import tiny_scene

    from photon_fields.runtime.viewer.updater import FieldUpdater

    updater = FieldUpdater(tmp_path / "out", stand_in_trainer(tmp_path, "linger"))
    updater.want(tiny_scene(), now=True)
    updater.poll()  # starts the job
    job = updater.job
    end = time.monotonic() + 60
    status, done = None, None
    while done is None and time.monotonic() < end:
        status, done = updater.poll()
        time.sleep(0.05)
    assert done is job and status["state"] == "done"
    assert not job.exited()  # the stand-in sleeps 4 s after it is done
    updater.close()
    assert job.exited()


def test_cancel_stops_the_job_and_closing_the_page_stops_it_too(tmp_path: Path) -> None:
    s = make_session(tmp_path / "out", retrain=stand_in_trainer(tmp_path, "slow"))
    edit(s, 0.5)
    poll_until(s, {"running"})
    job = s.updater.job
    s.apply(msg("retrain", action="cancel"))
    assert poll_until(s, {"cancelled"})[-1]["message"] == "retraining cancelled"
    assert job.process.poll() is not None
    s.apply(msg("retrain", action="start"))
    poll_until(s, {"running"})
    job = s.updater.job
    s.close()
    assert job.process.poll() is not None


@pytest.mark.parametrize(("mode", "needle"), [("fail", "too few photons"), ("crash", "Segmentation fault")])
def test_a_failed_job_shows_its_line_and_the_field_stays(tmp_path: Path, mode: str, needle: str) -> None:
    s = make_session(tmp_path / "out", retrain=stand_in_trainer(tmp_path, mode))
    field = s.estimator
    edit(s, 0.5)
    status = poll_until(s, {"failed", "done"})[-1]
    assert status["state"] == "failed" and needle in status["message"] and "\n" not in status["message"]
    assert s.estimator is field
    h = s.next_frame().header
    assert h["stale"] and "press retrain" in " ".join(h["warnings"])


def test_no_job_without_the_train_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = retrain_module.importlib.util.find_spec
    monkeypatch.setattr(retrain_module.importlib.util, "find_spec",
                        lambda name, *a: None if name == "torch" else real(name, *a))
    s = make_session(tmp_path / "out", retrain=RetrainSettings(delay_s=0.0))
    assert s.describe()["retrain"]["available"] is False
    edit(s, 0.5)
    status = poll_until(s, {"unavailable", "running"})[-1]
    assert status["state"] == "unavailable" and "train extra" in status["message"]
    assert jobs(tmp_path / "out") == [] and "train extra" in " ".join(s.next_frame().header["warnings"])


def test_a_real_retrain_swaps_a_field_in(tmp_path: Path) -> None:
    """No field at start (the path tracer); an edit, then the page's retrain button: the tiny trainer runs for
    real, the session loads its bundle and map, switches to the neural renderer, and nothing is stale."""
    pytest.importorskip("torch")
    settings = RetrainSettings(photons="3k", preset="tiny", steps=3, delay_s=0.0,
                               extra=("--batch", "256", "--k", "32"))
    s = ViewerSession(make_session(tmp_path).base_scene, out_dir=tmp_path / "out", seed=5, width=24, height=24,
                      retrain=settings)
    assert s.available == ["pt", "preview"] and s.state.renderer == "pt"
    edit(s, 0.7)
    assert s.poll_updates() is None  # no field to make stale: nothing starts by itself
    s.apply(msg("retrain", action="start"))
    status = poll_until(s, {"done", "failed"})[-1]
    assert status["state"] == "done", status
    assert status["renderers"] == ["neural", "pt", "preview", "marched", "photonmap"] and status["renderer"] == "neural"
    assert status["cycle_s"] > 0 and "new field in" in status["message"]
    h = s.next_frame().header
    assert h["renderer"] == "neural" and not h["stale"] and h["warnings"] == []
    assert s.estimator is not None and s.pmap is not None
    assert s.pmap.scene_fingerprint == s.edited_scene(s.state).fingerprint()
    s.apply(msg("set", control="renderer", value="photonmap"))
    assert not s.next_frame().header["stale"]
