"""The viewer's web application: one page, one websocket per page, one render thread per websocket.

Built on starlette (ASGI) and served by uvicorn; docs/viewer.md says why not trame. Routes:

- ``GET /``: the page (``page/index.html``, plain HTML and JavaScript, no build step);
- ``GET /viewer.js``, ``GET /tf_editor.js``, ``GET /label_panel.js``: its scripts;
- ``WS /ws``: the page's connection. The client sends JSON text messages
  (:mod:`photon_fields.runtime.viewer.messages`); the server sends a ``state`` text message on connect, an
  ``error`` text message for every refused message, a ``screenshot`` text message with the files written, and
  frames as binary messages: a 4-byte big-endian header length, the JSON header
  (:meth:`photon_fields.runtime.viewer.session.ViewerSession.next_frame`), then the JPEG or PNG bytes.

Reliability and security:

- a refused message is logged in one line and answered with an ``error`` message; the connection and the
  server keep serving. Text frames above :data:`MAX_FRAME_BYTES` are refused by the websocket layer itself
  (uvicorn closes that connection), so a hostile page cannot make the server buffer large messages;
- a websocket whose ``Origin`` is not this server's own address is refused (a page from another site open in
  the same browser must not drive a viewer on 127.0.0.1);
- at most :data:`MAX_CLIENTS` pages at a time; a page's render thread stops when its websocket closes;
- screenshots go only into the output folder, under names the page cannot turn into a path.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from typing import Any

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.viewer.idle_work import fill_light_margins
from photon_fields.runtime.viewer.messages import MAX_MESSAGE_BYTES, MessageError, parse
from photon_fields.runtime.viewer.session import ViewerSession

log = logging.getLogger("photon_fields.viewer")

MAX_CLIENTS = 4
#: The websocket layer's own limit on an incoming frame (a few valid messages' worth).
MAX_FRAME_BYTES = 4 * MAX_MESSAGE_BYTES
#: Seconds a frame may take to be handed to a slow client before its page is given up on.
SEND_TIMEOUT = 30.0


def _page_file(name: str) -> str:
    return resources.files("photon_fields.runtime.viewer").joinpath("page", name).read_text(encoding="utf-8")


@dataclass
class Stats:
    """Counters the tests and the bench read: connections, refused messages, frames sent."""

    connections: int = 0
    active: int = 0
    refused: int = 0
    frames: int = 0


class RenderWorker:
    """Renders frames of one session on its own thread and hands them to ``send`` (which blocks until the
    websocket took the frame), until :meth:`stop`. Numba kernels and onnxruntime release the GIL, so the event
    loop keeps reading input while a frame renders."""

    def __init__(self, session: ViewerSession, send: Callable[[bytes], None], stats: Stats,
                 send_text: Callable[[str], None] | None = None) -> None:
        self.session, self.send, self.stats, self.send_text = session, send, stats, send_text
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._run, name="pfn-view-render", daemon=True)
        self.error: str | None = None

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self.stop_event.set()
        with self.session.lock:
            self.session.changed.notify_all()

    def _run(self) -> None:
        try:
            while not self.stop_event.is_set():
                status = self.session.poll_updates()  # background retraining: progress, a new field
                if status is not None and self.send_text is not None:
                    self.send_text(json.dumps(status))
                if not self.session.wait_for_work(self.stop_event):
                    fill_light_margins(self.session, self.stop_event)  # nothing to render: the next view's cells
                    continue
                try:
                    frame = self.session.next_frame()
                except (InputError, ValueError, MemoryError) as exc:
                    # A frame that cannot be rendered (e.g. inputs the renderer refuses) is reported and the
                    # loop waits for the next change instead of retrying the same state.
                    log.warning("frame refused: %s", exc)
                    self.session.hold()
                    if self.send_text is not None:
                        self.send_text(json.dumps({"type": "error", "message": f"cannot render this view: {exc}"}))
                    continue
                if self.stop_event.is_set():
                    break
                if frame is None:  # a stale refinement frame: the newer view renders next
                    continue
                head = json.dumps(frame.header).encode()
                try:
                    self.send(struct.pack(">I", len(head)) + head + frame.image)
                except Exception:  # noqa: BLE001  (the page went away while the frame was sent)
                    log.info("a page closed while a frame was being sent; its render loop stops")
                    return
                self.stats.frames += 1
        except Exception as exc:  # noqa: BLE001  (a failed render must end this page's loop, not the server)
            if not self.stop_event.is_set():
                self.error = f"{type(exc).__name__}: {exc}"
                log.error("render loop stopped: %s", self.error)


def create_app(make_session: Callable[[], ViewerSession], *, allowed_origins: Callable[[], set[str]] | None = None,
               warm: Callable[[], None] | None = None) -> Starlette:
    """The ASGI app. ``make_session()`` builds a page's session (they share the loaded scene, field and map);
    ``allowed_origins()`` the ``Origin`` values a websocket may come from (None: any, for tests); ``warm``
    runs on a background thread at start-up (compiles or loads the kernels)."""
    stats = Stats()
    lock = threading.Lock()

    async def page(request: Request) -> Response:
        return HTMLResponse(_page_file("index.html"), headers={"Cache-Control": "no-store"})

    async def script(request: Request) -> Response:
        return Response(_page_file(request.url.path.lstrip("/")), media_type="text/javascript",
                        headers={"Cache-Control": "no-store"})

    async def socket(ws: WebSocket) -> None:
        origin = ws.headers.get("origin")
        if allowed_origins is not None and origin is not None and origin not in allowed_origins():
            log.warning("refused a websocket from origin %r", origin[:100])
            await ws.close(code=1008)
            return
        with lock:
            if stats.active >= MAX_CLIENTS:
                full = True
            else:
                full, stats.active, stats.connections = False, stats.active + 1, stats.connections + 1
        if full:
            log.warning("refused a websocket: %d pages are open already", MAX_CLIENTS)
            await ws.close(code=1013)
            return
        worker: RenderWorker | None = None
        try:
            await ws.accept()
            session = await asyncio.to_thread(make_session)
            loop = asyncio.get_running_loop()

            def send(data: bytes) -> None:
                asyncio.run_coroutine_threadsafe(ws.send_bytes(data), loop).result(SEND_TIMEOUT)

            def send_text(text: str) -> None:
                asyncio.run_coroutine_threadsafe(ws.send_text(text), loop).result(SEND_TIMEOUT)

            await ws.send_text(json.dumps(session.describe()))
            worker = RenderWorker(session, send, stats, send_text)
            worker.start()
            await _serve_messages(ws, session, stats)
        except WebSocketDisconnect:
            pass
        finally:
            if worker is not None:
                worker.stop()
                await asyncio.to_thread(worker.thread.join, 60.0)
                await asyncio.to_thread(worker.session.close)  # a background retrain stops with its page
            with lock:
                stats.active -= 1

    app = Starlette(routes=[Route("/", page), Route("/viewer.js", script), Route("/tf_editor.js", script),
                            Route("/label_panel.js", script), WebSocketRoute("/ws", socket)])
    app.state.stats = stats
    if warm is not None:
        threading.Thread(target=_warm_quietly, args=(warm,), name="pfn-view-warm", daemon=True).start()
    return app


def _warm_quietly(warm: Callable[[], None]) -> None:
    try:
        warm()
    except Exception as exc:  # noqa: BLE001  (warming is an optimization; the first frame compiles otherwise)
        log.warning("warming the kernels failed: %s", exc)


async def _serve_messages(ws: WebSocket, session: ViewerSession, stats: Stats) -> None:
    """Read messages until the page goes: apply the valid ones, refuse the rest in one logged line."""
    while True:
        event = await ws.receive()
        if event["type"] == "websocket.disconnect":
            return
        payload: Any = event.get("text")
        if payload is None:
            payload = event.get("bytes")
        try:
            msg = parse(payload)
            if msg.type == "screenshot":
                files = await asyncio.to_thread(session.screenshot, msg.fields.get("name"))
                await ws.send_text(json.dumps({"type": "screenshot", "files": [str(p) for p in files],
                                               "seq": msg.seq}))
            else:
                session.apply(msg)
        except MessageError as err:
            stats.refused += 1
            log.warning("refused a message: %s", err)
            with contextlib.suppress(Exception):
                await ws.send_text(json.dumps({"type": "error", "message": str(err)}))
