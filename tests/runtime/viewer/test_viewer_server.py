"""The viewer's server over a real websocket (uvicorn on a free port of 127.0.0.1): the state message, frames
whose header reports the input they include, every malformed message answered with an error while the same
connection keeps serving, websockets from other origins and oversized frames refused, renders stopped when a
page closes, and screenshots through the socket."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from viewer_helpers import inputs, split_frame

pytest.importorskip("uvicorn")
pytest.importorskip("starlette")
from test_viewer_messages import BAD  # noqa: E402
from websockets.exceptions import ConnectionClosed, InvalidStatus  # noqa: E402
from websockets.sync.client import ClientConnection, connect  # noqa: E402

from photon_fields.runtime.viewer.launch import ViewerServer  # noqa: E402
from photon_fields.runtime.viewer.server import MAX_FRAME_BYTES  # noqa: E402


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ViewerServer]:
    srv = ViewerServer(inputs(tmp_path_factory.mktemp("view") / "out"), port=0, warm=False, max_spp=1 << 16)
    yield srv
    srv.stop()


def ws_url(srv: ViewerServer) -> str:
    return srv.url.replace("http://", "ws://") + "ws"


def next_frame(ws: ClientConnection, timeout: float = 60.0) -> tuple[dict, bytes]:
    """The next binary frame (text messages in between are skipped)."""
    end = time.monotonic() + timeout
    while True:
        m = ws.recv(timeout=max(0.1, end - time.monotonic()))
        if isinstance(m, bytes):
            return split_frame(m)


def next_text(ws: ClientConnection, timeout: float = 30.0) -> dict:
    end = time.monotonic() + timeout
    while True:
        m = ws.recv(timeout=max(0.1, end - time.monotonic()))
        if isinstance(m, str):
            return json.loads(m)


def test_page_and_script_are_served(server: ViewerServer) -> None:
    import urllib.request

    page = urllib.request.urlopen(server.url, timeout=10).read().decode()
    assert "<canvas" in page and "viewer.js" in page
    script = urllib.request.urlopen(server.url + "viewer.js", timeout=10).read().decode()
    assert "new WebSocket" in script
    assert server.host == "127.0.0.1"
    # The Jupyter cell's display: the page in an iframe.
    assert f'src="{server.url}"' in server._repr_html_() and "<iframe" in server._repr_html_()


def test_state_then_frames_that_report_their_input(server: ViewerServer) -> None:
    with connect(ws_url(server), max_size=None) as ws:
        state = json.loads(ws.recv(timeout=30))
        assert state["type"] == "state" and state["renderer"] == "pt"
        assert state["renderers"] == ["neural", "pt", "preview", "marched"]
        header, image = next_frame(ws)
        assert image[:2] == b"\xff\xd8" and header["width"] == 24  # a JPEG of the view's size
        ws.send(json.dumps({"type": "orbit", "dx": 10, "dy": 0, "seq": 41}))
        for _ in range(20):
            header, _ = next_frame(ws)
            if header["seq"] == 41:
                break
        assert header["seq"] == 41 and header["spp"] in (1, 2)


def test_malformed_messages_are_refused_and_the_connection_keeps_serving(server: ViewerServer) -> None:
    refused = server.stats.refused
    with connect(ws_url(server), max_size=None) as ws:
        next_text(ws)
        bad = [text for text, _ in BAD if len(text.encode()) <= MAX_FRAME_BYTES]
        for text in bad:
            ws.send(text)
        ws.send(b"\x00\xffbinary")
        ws.send(json.dumps({"type": "light", "index": 9, "power": 1}))  # well formed, but no such light
        errors = [next_text(ws) for _ in range(len(bad) + 2)]
        assert all(e["type"] == "error" and e["message"] for e in errors)
        ws.send(json.dumps({"type": "set", "control": "g", "value": 0.5, "seq": 99}))
        for _ in range(20):
            header, _ = next_frame(ws)
            if header["seq"] == 99:
                break
        assert header["seq"] == 99 and header["g"] == 0.5
    assert server.stats.refused - refused == len(bad) + 2


def test_oversized_frame_closes_only_that_connection(server: ViewerServer) -> None:
    with connect(ws_url(server), max_size=None) as ws:
        next_text(ws)
        ws.send("x" * (MAX_FRAME_BYTES + 10))
        with pytest.raises(ConnectionClosed):
            for _ in range(100):
                ws.recv(timeout=30)
    with connect(ws_url(server), max_size=None) as ws:  # the server still serves
        assert next_text(ws)["type"] == "state"
        next_frame(ws)


def test_foreign_origin_is_refused(server: ViewerServer) -> None:
    with pytest.raises(InvalidStatus) as info:
        connect(ws_url(server), origin="http://evil.example", max_size=None)
    assert info.value.response.status_code == 403
    with connect(ws_url(server), origin=server.url.rstrip("/"), max_size=None) as ws:
        assert next_text(ws)["type"] == "state"


def test_closing_the_page_stops_its_renders(server: ViewerServer) -> None:
    with connect(ws_url(server), max_size=None) as ws:
        next_text(ws)
        next_frame(ws)
        assert server.stats.active >= 1
    end = time.monotonic() + 30
    while server.stats.active and time.monotonic() < end:
        time.sleep(0.05)
    assert server.stats.active == 0
    frames = server.stats.frames
    time.sleep(0.5)
    assert server.stats.frames == frames  # nothing renders for a closed page


def test_screenshot_through_the_socket(server: ViewerServer) -> None:
    with connect(ws_url(server), max_size=None) as ws:
        next_text(ws)
        next_frame(ws)
        ws.send(json.dumps({"type": "screenshot", "name": "via_ws"}))
        reply = next_text(ws)
        assert reply["type"] == "screenshot"
        assert sorted(Path(f).name for f in reply["files"]) == ["via_ws.exr", "via_ws.json", "via_ws.png"]
        assert all(Path(f).parent == server.inputs.out_dir.resolve() for f in reply["files"])
        ws.send(json.dumps({"type": "screenshot", "name": "via_ws"}))
        assert next_text(ws)["type"] == "error"


def render_threads() -> int:
    return sum(t.name == "pfn-view-render" and t.is_alive() for t in threading.enumerate())


def test_closing_an_idle_page_ends_its_render_thread(tmp_path: Path) -> None:
    """A converged view renders nothing and sends nothing, so only the close itself can end its thread."""
    srv = ViewerServer(inputs(tmp_path / "out"), port=0, warm=False, max_spp=1)
    try:
        end = time.monotonic() + 30
        while render_threads() and time.monotonic() < end:  # pages closed by earlier tests finish their frame
            time.sleep(0.05)
        before = render_threads()
        assert before == 0
        with connect(ws_url(srv), max_size=None) as ws:
            next_text(ws)
            next_frame(ws)
            time.sleep(0.3)  # converged at 1 spp: idle
            assert render_threads() == before + 1
        end = time.monotonic() + 10
        while render_threads() > before and time.monotonic() < end:
            time.sleep(0.05)
        assert render_threads() == before
    finally:
        srv.stop()


def test_a_frame_that_fails_is_reported_and_the_loop_waits_for_the_next_change(tmp_path: Path) -> None:
    from viewer_helpers import make_session, msg

    from photon_fields.runtime.errors import InputError
    from photon_fields.runtime.viewer.server import RenderWorker, Stats

    session = make_session(tmp_path, renderer="pt")
    real = session._render
    calls = []

    def failing(scene, state, n, gather, moving, cancel=None, level=0):  # noqa: ANN001, ANN202
        calls.append(scene.g)
        if scene.g > 0.5:
            raise InputError("g", "this renderer cannot answer it")
        return real(scene, state, n, gather, moving, cancel, level)

    session._render = failing
    session.apply(msg("set", control="g", value=0.9))
    binary, texts = [], []
    worker = RenderWorker(session, binary.append, Stats(), texts.append)
    worker.start()
    try:
        end = time.monotonic() + 30
        while not texts and time.monotonic() < end:
            time.sleep(0.02)
        assert texts and json.loads(texts[0])["type"] == "error" and "cannot render" in texts[0]
        time.sleep(0.3)
        assert len(calls) == 1 and not binary  # held: the failing state is not retried in a loop
        session.apply(msg("set", control="g", value=0.2))
        while not binary and time.monotonic() < end:
            time.sleep(0.02)
        assert binary and worker.thread.is_alive()
    finally:
        worker.stop()
        worker.thread.join(30)


def test_the_render_loop_fills_the_light_volumes_margin_once_the_view_rests(tmp_path: Path) -> None:
    """A preview view's frames done, the render thread has nothing to render: it fills the light volume's margin
    (runtime/viewer/idle_work.py) and sends no frame for it."""
    from viewer_helpers import make_session

    from photon_fields.runtime.viewer.field_in_use import PREVIEW_FRAMES
    from photon_fields.runtime.viewer.server import RenderWorker, Stats

    session = make_session(tmp_path, renderer="preview")
    binary: list[bytes] = []
    worker = RenderWorker(session, binary.append, Stats())
    worker.start()
    try:
        end = time.monotonic() + 30
        volumes = session.scene.shared_cache("light_volumes")
        while time.monotonic() < end and not (len(binary) == PREVIEW_FRAMES and volumes
                                              and not any(lv.margin.any() for lv in volumes.values())):
            time.sleep(0.05)
        (lv,) = volumes.values()
        assert len(binary) == PREVIEW_FRAMES and not lv.margin.any() and not lv.wanted.any()
        assert worker.thread.is_alive() and worker.error is None
    finally:
        worker.stop()
        worker.thread.join(30)
