"""PVRT relighting in the viewer (``pfn-view SCENE --transfer NAME.pvrt``), over a real websocket and in the session:

- a light change with the pvrt renderer gives render_pvrt's frame of the same scene, light, camera and seed (the
  screenshot's EXR, to float32 rounding), relit from the kept camera samples: no march of the camera rays until the
  camera moves;
- a resting pvrt view is one frame: no refinement, no denoising;
- what a transfer cannot render is refused in one line: another g, an edited transfer function, a transfer of
  another scene or g on the command line, a scene with a point light; the connection keeps serving.

The transfer is tiny (:func:`viewer_helpers.tiny_transfer`): these tests are about the viewer, not PVRT's accuracy
(tests/runtime/pvrt/)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import tiny_scene_dict
from viewer_helpers import BALL, CUBE, SIZE, inputs, label_scene_file, make_session, msg, tiny_scene, tiny_transfer

pytest.importorskip("uvicorn")
pytest.importorskip("starlette")
from test_viewer_cli import one_error_line  # noqa: E402
from test_viewer_server import next_frame, next_text, ws_url  # noqa: E402
from websockets.sync.client import ClientConnection, connect  # noqa: E402

from photon_fields.runtime.io.images import read_exr  # noqa: E402
from photon_fields.runtime.pvrt.transfer import load_transfer, save_transfer  # noqa: E402
from photon_fields.runtime.renderers import pvrt as pvrt_renderer  # noqa: E402
from photon_fields.runtime.scene.camera import Camera  # noqa: E402
from photon_fields.runtime.scene.lights import EnvironmentMap, light_from_dict  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, load_scene  # noqa: E402
from photon_fields.runtime.viewer.cli import _main  # noqa: E402
from photon_fields.runtime.viewer.launch import ViewerServer  # noqa: E402
from photon_fields.runtime.viewer.messages import MessageError  # noqa: E402


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> tuple[Scene, Path]:
    """The tiny scene and a transfer file of it."""
    scene = tiny_scene(SIZE)
    return scene, save_transfer(tiny_transfer(scene), tmp_path_factory.mktemp("pvrt") / "blobs32.pvrt")


@pytest.fixture(scope="module")
def server(made: tuple[Scene, Path], tmp_path_factory: pytest.TempPathFactory) -> Iterator[ViewerServer]:
    scene, path = made
    out = tmp_path_factory.mktemp("pvrt_view") / "out"
    srv = ViewerServer(inputs(out, renderer="pvrt", scene=scene, transfer=load_transfer(path, scene)), port=0,
                       warm=False, drag_scale=1.0)
    yield srv
    srv.stop()


@pytest.fixture
def marches(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Every march of camera rays through the medium (render_pvrt's, and Relighting's count and record) appends
    to the list."""
    calls: list[int] = []
    march = pvrt_renderer._march

    def counted(*args: Any) -> Any:
        calls.append(1)
        return march(*args)

    monkeypatch.setattr(pvrt_renderer, "_march", counted)
    return calls


#: Seconds to wait for a frame: with a fresh numba cache (bench/mutants.py) the first one compiles PVRT's kernels.
FRAME_TIMEOUT = 600.0


def frame_of(ws: ClientConnection, seq: int) -> dict:
    """The header of the first frame that includes input ``seq``."""
    while True:
        header, _ = next_frame(ws, FRAME_TIMEOUT)
        if header["seq"] is not None and header["seq"] >= seq:
            return header


def test_light_change_is_render_pvrts_frame_relit_without_a_march(server: ViewerServer, made: tuple[Scene, Path],
                                                                 marches: list[int]) -> None:
    scene, path = made
    with connect(ws_url(server), max_size=None) as ws:
        state = next_text(ws)
        assert state["renderers"] == ["neural", "pt", "preview", "marched", "pvrt"] and state["renderer"] == "pvrt"
        assert state["pvrt"] == {"g": pytest.approx(scene.g)}
        header, _ = next_frame(ws, FRAME_TIMEOUT)
        assert header["renderer"] == "pvrt" and header["spp"] == 1 and not header["denoised"]
        with pytest.raises(TimeoutError):  # a resting view is one frame: nothing refines it
            ws.recv(timeout=0.5)
        kept = len(marches)
        for seq, (azimuth, power) in enumerate(((40.0, 3.0), (115.0, 5.0)), start=1):
            ws.send(json.dumps({"type": "light", "index": 0, "azimuth": azimuth, "elevation": 35.0, "power": power,
                                "seq": seq}))
            header = frame_of(ws, seq)
            assert header["pvrt"]["relit"] and header["pvrt"]["kept_samples"] > 0, header
            assert header["spp"] == 1 and not header["stale"] and not header["warnings"]
        assert len(marches) == kept, "a light change marched the camera rays again"
        ws.send(json.dumps({"type": "screenshot", "name": "relit", "seq": 3}))
        files = [Path(f) for f in next_text(ws)["files"]]
        report = json.loads(files[2].read_text())
        shown, _ = read_exr(files[0])
        ws.send(json.dumps({"type": "orbit", "dx": 20.0, "dy": 0.0, "seq": 4}))
        header = frame_of(ws, 4)
        assert not header["pvrt"]["relit"] and len(marches) > kept  # a camera move marches
    lit = replace(scene, lights=tuple(light_from_dict(d) for d in report["lights"]), _cache={})
    lit = lit.with_overrides(camera=Camera.from_dict(report["camera"]))
    assert lit.lights[0].power == 5.0
    expected = pvrt_renderer.render_pvrt(lit, transfer=load_transfer(path, scene), seed=5, progress=False).layers
    for layer in ("L", "L_d", "L_i"):
        assert expected[layer].max() > 0, layer
        np.testing.assert_allclose(shown[layer], expected[layer], rtol=1e-5, atol=1e-6 * expected[layer].max(),
                                   err_msg=layer)


@pytest.mark.parametrize(("message", "needle"), [
    ({"type": "set", "control": "g", "value": 0.5}, "precomputed for g = 0"),
    ({"type": "transfer", "points": [{"s": 0.0, "opacity": 0.5, "albedo": [1, 1, 1]}], "density_scale": 1.0},
     "transfer function"),
    ({"type": "light", "index": 0, "yaw": 30.0}, "no yaw"),  # a directional light: no map to turn
])
def test_what_the_transfer_cannot_render_is_refused_and_serving_goes_on(server: ViewerServer, message: dict,
                                                                        needle: str) -> None:
    with connect(ws_url(server), max_size=None) as ws:
        next_text(ws)
        next_frame(ws, FRAME_TIMEOUT)
        ws.send(json.dumps(message))
        error = next_text(ws)
        assert error["type"] == "error" and needle in error["message"] and "\n" not in error["message"]
        ws.send(json.dumps({"type": "light", "index": 0, "power": 2.0, "seq": 9}))
        header = frame_of(ws, 9)
        assert header["renderer"] == "pvrt" and header["g"] == 0.0  # the refused message changed nothing


def test_turning_an_environment_map_relights_as_render_pvrt(made: tuple[Scene, Path], tmp_path: Path,
                                                            marches: list[int]) -> None:
    """The page's rotation slider of an environment map (``yaw``) relights the kept samples: render_pvrt's frame of
    the turned map, no march."""
    scene, path = made
    sky = np.full((8, 16, 3), 0.1)
    sky[2:4, 3:6] = 6.0  # a bright patch, so that turning the map moves the light
    sky_scene = replace(scene, lights=(EnvironmentMap("patch", image=sky, rotation=(10.0, 5.0, 0.0)),), _cache={})
    session = make_session(tmp_path, renderer="pvrt", scene=sky_scene, transfer=load_transfer(path, scene))
    before = session.next_frame().header
    assert session.describe()["lights"][0]["yaw"] == 10.0 and not before["pvrt"]["relit"]
    first = session._acc["L"].copy()
    kept = len(marches)
    session.apply(msg("light", index=0, yaw=130.0))
    header = session.next_frame().header
    assert header["pvrt"]["relit"] and len(marches) == kept
    turned = replace(sky_scene, lights=(EnvironmentMap("patch", image=sky, rotation=(130.0, 5.0, 0.0)),), _cache={})
    turned = turned.with_overrides(camera=session.state.view.camera(SIZE, SIZE))
    expected = pvrt_renderer.render_pvrt(turned, transfer=load_transfer(path, scene), seed=5, progress=False).layers
    for layer in ("L", "L_i", "L_e"):
        np.testing.assert_allclose(session._acc[layer], expected[layer], rtol=1e-5,
                                   atol=1e-6 * expected[layer].max(), err_msg=layer)
    assert np.abs(session._acc["L"] - first).mean() > 0.05 * first.mean()  # the turn is visible


def test_session_refuses_pvrt_at_another_g_or_transfer_function(made: tuple[Scene, Path], tmp_path: Path) -> None:
    scene, path = made
    session = make_session(tmp_path, renderer="pt", scene=scene, transfer=load_transfer(path, scene))
    session.apply(msg("set", control="g", value=0.4))
    with pytest.raises(MessageError, match="precomputed for g = 0, not 0.4"):
        session.apply(msg("set", control="renderer", value="pvrt"))
    session.apply(msg("set", control="g", value=0.0))
    points = [{"s": 0.0, "opacity": 0.2, "albedo": [1.0, 1.0, 1.0]}, {"s": 1.0, "opacity": 0.9, "albedo": [1, 1, 1]}]
    session.apply(msg("transfer", points=points, density_scale=2.0))  # the path tracer follows any edit
    with pytest.raises(MessageError, match="edited"):
        session.apply(msg("set", control="renderer", value="pvrt"))
    assert session.state.renderer == "pt"


def test_a_label_edit_undone_renders_with_pvrt(tmp_path: Path) -> None:
    """Hiding a label and showing it again gives the scene's medium back, as the panel's function, which names every
    label present (here the background too, which the scene's function leaves out: another fingerprint): pvrt is
    allowed again and renders it, as the scene's own function."""
    path = label_scene_file(tmp_path / "labels")
    spec = json.loads(path.read_text())
    spec["transfer_function"] = {"labels": {str(BALL): {"albedo": [0.9, 0.3, 0.2], "opacity": 1.0},
                                            str(CUBE): {"albedo": [0.2, 0.5, 0.9], "opacity": 0.8}}}
    path.write_text(json.dumps(spec))
    scene = load_scene(path)
    session = make_session(tmp_path, renderer="pt", scene=scene, transfer=tiny_transfer(scene))
    session.apply(msg("labels", labels={str(CUBE): {"visible": False}}))
    with pytest.raises(MessageError, match="edited"):
        session.apply(msg("set", control="renderer", value="pvrt"))
    session.apply(msg("labels", labels={str(CUBE): {"visible": True}}))
    session.apply(msg("set", control="renderer", value="pvrt"))
    header = session.next_frame().header
    assert header["renderer"] == "pvrt" and header["pvrt"]["kept_samples"] > 0
    assert session._acc["L"].max() > 0


def test_a_camera_move_marches_and_the_view_at_rest_keeps_its_samples(made: tuple[Scene, Path], tmp_path: Path,
                                                                      marches: list[int]) -> None:
    """A moving pvrt frame is one march; once the camera rests, one more frame keeps the view's samples (the same
    image), so that the first light change after a move is relit too."""
    scene, path = made
    session = make_session(tmp_path, renderer="pvrt", scene=scene, transfer=load_transfer(path, scene))
    session.next_frame()
    session.apply(msg("orbit", dx=15.0, dy=0.0))
    count = len(marches)
    moving = session.next_frame()
    assert moving.header["moving"] and moving.header["pvrt"] == {"relit": False, "kept_samples": 0}
    assert len(marches) == count + 1  # render_pvrt: one march
    image = session._acc["L"].copy()
    assert session.wants_frame()
    rest = session.next_frame().header
    assert not rest["moving"] and rest["pvrt"]["kept_samples"] > 0 and rest["spp"] == 1
    np.testing.assert_allclose(session._acc["L"], image, rtol=1e-5, atol=1e-6 * image.max())
    assert not session.wants_frame()
    session.apply(msg("light", index=0, azimuth=75.0))
    count = len(marches)
    assert session.next_frame().header["pvrt"]["relit"] and len(marches) == count


def test_a_resting_pvrt_view_is_one_frame_without_a_denoiser(made: tuple[Scene, Path], tmp_path: Path) -> None:
    scene, path = made
    session = make_session(tmp_path, renderer="pvrt", scene=scene, transfer=load_transfer(path, scene))
    header = session.next_frame().header
    assert header["spp"] == 1 and not header["denoised"] and not session.wants_frame()
    session.apply(msg("set", control="exposure", value=1.0))  # shown again, not rendered again
    assert not session.next_frame().header["rendered"]
    assert len(session._denoisers) == 0 and session._denoisers.depth is None


def test_pvrt_options_make_the_frames_as_render_pvrt_with_them(made: tuple[Scene, Path], tmp_path: Path) -> None:
    """``pfn-view --direct transfer --light-grid N`` reach the frames: the session's resting and relit frames are
    render_pvrt's with the same options (and not the default's)."""
    from photon_fields.runtime.viewer.pvrt_view import PvrtOptions

    scene, path = made
    transfer = load_transfer(path, scene)
    for options in (PvrtOptions("transfer", 64), PvrtOptions("nee", 6)):
        session = make_session(tmp_path / options.direct, renderer="pvrt", scene=scene, transfer=transfer,
                               pvrt_options=options)
        session.next_frame()
        session.apply(msg("light", index=0, azimuth=75.0))
        assert session.next_frame().header["pvrt"]["relit"]
        lit = replace(scene, lights=tuple(lt.light() for lt in session.state.lights), _cache={})
        kw = {"transfer": transfer, "seed": session.seed, "progress": False}
        want = pvrt_renderer.render_pvrt(lit, direct=options.direct, light_grid=options.light_grid, **kw).layers["L"]
        default = pvrt_renderer.render_pvrt(lit, **kw).layers["L"]
        np.testing.assert_allclose(session._acc["L"], want, rtol=1e-4, atol=1e-5 * want.max())
        assert np.abs(default - want).max() > 1e-3 * want.max()


@pytest.fixture
def cli_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Callable[..., str]:
    """``pfn-view ARGV --no-browser``: asserts exit status 2 and returns the one error line."""
    def run(*argv: str) -> str:
        assert _main([*argv, "--no-browser", "--out", str(tmp_path / "out")]) == 2
        captured = capsys.readouterr()
        assert "http://" not in captured.out
        return one_error_line(captured.err)

    return run


def test_command_line_refuses_a_transfer_it_cannot_use(made: tuple[Scene, Path], tmp_path: Path,
                                                       cli_run: Callable[..., str]) -> None:
    scene, path = made
    scene_file, shell_file = tmp_path / "blobs32.json", tmp_path / "shell32.json"
    scene_file.write_text(json.dumps(tiny_scene_dict("blobs")))
    shell_file.write_text(json.dumps(tiny_scene_dict("shell")))
    other_g = save_transfer(tiny_transfer(scene.with_overrides(g=0.5)), tmp_path / "g05.pvrt")
    assert "precomputed for phase g = 0.5" in cli_run(str(scene_file), "--transfer", str(other_g))
    assert "precomputed for another scene" in cli_run(str(shell_file), "--transfer", str(path))
    assert "not found" in cli_run(str(scene_file), "--transfer", str(tmp_path / "missing.pvrt"))
    assert "--renderer" in cli_run(str(scene_file), "--renderer", "pvrt")  # pvrt without --transfer
    point = {**tiny_scene_dict("blobs"), "lights": [{"type": "point", "position": [0.0, 2.0, 0.0], "power": 3.0}]}
    scene_file.write_text(json.dumps(point))
    assert "point light" in cli_run(str(scene_file), "--transfer", str(path))
    scene_file.write_text(json.dumps(tiny_scene_dict("blobs")))
    assert "needs --transfer" in cli_run(str(scene_file), "--direct", "transfer")  # pvrt options without pvrt
