"""The viewer in a real browser: headless Chromium from Debian's ``chromium`` and ``chromium-driver`` packages
(never a downloaded browser), driven by selenium. Loads the page, waits for a frame, drags to orbit and checks
the image changes, moves the g slider on the L_i layer and checks the image changes, takes a screenshot with
the button and checks the files, resizes the window and checks the frames follow the view's size and aspect.
Skipped, saying why, where Chromium or its driver is not installed.

The server runs with ``--size 64x64``: the page's view (hundreds of pixels) is scaled down to 4096 pixels, so the
frames stay as small and fast as they were before the page asked for its own size.

Frames converge at a small ``max_spp`` so that the image at rest is fixed: any difference is then the input's.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser_helpers import header, pixels, require_browser, served_page, wait_for
from browser_helpers import settled as settled_at
from PIL import Image
from viewer_helpers import inputs, stand_in_trainer

require_browser()

from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402
from selenium.webdriver.support.ui import Select  # noqa: E402

from photon_fields.runtime.viewer.launch import ViewerServer  # noqa: E402

SIZE, MAX_SPP = 64, 3


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Any, ViewerServer]]:
    out = tmp_path_factory.mktemp("browser") / "shots"
    trainer = stand_in_trainer(tmp_path_factory.mktemp("trainer"), "slow", delay_s=0.2)
    with served_page(inputs(out, size=SIZE, renderer="neural"), max_spp=MAX_SPP,
                     drag_scale=1.0,  # full-size moving frames whatever the machine's speed
                     retrain=trainer) as opened:  # reports progress, then waits: the page shows a running retrain
        yield opened


def settled(driver: Any, **want: Any) -> dict:
    """:func:`browser_helpers.settled` at this module's MAX_SPP."""
    return settled_at(driver, MAX_SPP, **want)


def view_box(driver: Any) -> tuple[int, int]:
    """The canvas's box in device pixels (the page's devicePixelRatio, capped at 2 as the page does)."""
    w, h, dpr = driver.execute_script("const r = document.getElementById('view').getBoundingClientRect();"
                                      "return [r.width, r.height, window.devicePixelRatio];")
    return round(w * min(dpr, 2.0)), round(h * min(dpr, 2.0))


def frame_for_the_box(driver: Any) -> tuple[dict, tuple[int, int]]:
    """Wait for a settled frame rendered for the canvas's current box; check it is within the cap (64x64's pixels),
    has the box's aspect ratio within one frame pixel and does not waste the cap, and that the canvas's pixels
    are the box's. Returns the frame's header and the box."""
    box = view_box(driver)
    h = settled(driver, view_size=list(box))
    w_f, h_f = h["width"], h["height"]
    assert w_f * h_f <= SIZE * SIZE and min(w_f, h_f) >= 16, (h, box)
    assert abs(w_f - h_f * box[0] / box[1]) <= 1.0 or abs(h_f - w_f * box[1] / box[0]) <= 1.0, (h, box)
    assert w_f * h_f >= 0.85 * SIZE * SIZE, (h, box)  # every box here is larger than the cap
    assert driver.execute_script("const c = document.getElementById('view'); return [c.width, c.height];") \
        == list(box)
    return h, box


def test_page_shows_a_frame_and_dragging_orbits(page: tuple[Any, ViewerServer]) -> None:
    driver, _ = page
    wait_for(lambda: driver.execute_script("return window.pfnView && window.pfnView.frames();"), "a first frame")
    _, box = frame_for_the_box(driver)
    before = pixels(driver)
    assert before.shape == (box[1], box[0], 3) and before.mean() > 1.0  # a real image, not a black canvas
    time.sleep(0.3)
    assert np.array_equal(pixels(driver), before)  # at rest the image stays put
    canvas = driver.find_element(By.ID, "view")
    chain = ActionChains(driver).click_and_hold(canvas)
    for _ in range(6):
        chain = chain.move_by_offset(10, 0).pause(0.03)
    chain.release().perform()
    time.sleep(0.1)  # the page sends the last movement on its next animation frame
    assert driver.execute_script("return window.pfnView.lastSeq();") > 0
    settled(driver)
    after = pixels(driver)
    assert np.abs(after - before).mean() > 2.0, np.abs(after - before).mean()


def test_the_camera_estimator_select_reaches_the_frames(page: tuple[Any, ViewerServer]) -> None:
    driver, _ = page
    settled(driver)
    before = pixels(driver)
    Select(driver.find_element(By.ID, "camera_estimator")).select_by_value("marched")
    settled(driver, camera_estimator="marched")
    after = pixels(driver)
    Select(driver.find_element(By.ID, "camera_estimator")).select_by_value("forced")
    settled(driver, camera_estimator="forced")
    assert np.abs(after - before).mean() > 0.0  # another estimator: other samples of the same image


def test_g_slider_changes_the_indirect_layer(page: tuple[Any, ViewerServer]) -> None:
    driver, _ = page
    Select(driver.find_element(By.ID, "layer")).select_by_value("L_i")
    settled(driver, layer="L_i")
    before = pixels(driver)
    slider = driver.find_element(By.ID, "g")
    slider.click()  # focus (the click itself may move it to the middle, g = 0)
    slider.send_keys(*([Keys.ARROW_RIGHT] * 40))
    g = float(driver.find_element(By.ID, "g").get_attribute("value"))
    assert g > 0.3
    h = settled(driver, layer="L_i", g=g)
    after = pixels(driver)
    assert h["g"] == pytest.approx(g)
    # Over the pixels that show the volume: how much of the canvas is black background depends on the window's
    # aspect ratio (the frames take the view's), not on g.
    volume = (before.sum(axis=2) > 0) | (after.sum(axis=2) > 0)
    assert volume.mean() > 0.2
    assert np.abs(after - before)[volume].mean() > 2.0, np.abs(after - before)[volume].mean()


def test_frames_are_drawn_in_arrival_order_when_decoding_finishes_out_of_order(
        page: tuple[Any, ViewerServer]) -> None:
    """The browser decodes frames asynchronously: if an older frame's decode finished after a newer one's and was
    drawn, the page would keep showing a stale image once the view rests (no frame follows). Decoding is delayed
    here so that the frames of one view finish in reverse order; the page must end on the newest."""
    driver, _ = page
    settled(driver)
    driver.execute_script("""
        window.__createImageBitmap = window.createImageBitmap;
        let k = 0;
        window.createImageBitmap = (blob) => {
          const delay = Math.max(0, 1600 - 400 * k++);
          return new Promise((r) => setTimeout(r, delay)).then(() => window.__createImageBitmap(blob));
        };""")
    try:
        driver.execute_script("window.pfnView.send({type: 'orbit', dx: 5, dy: 0});")
        settled(driver)
        time.sleep(2.0)  # every delayed decode has finished
        h = header(driver)
        assert h["spp"] == MAX_SPP and h["seq"] == driver.execute_script("return window.pfnView.lastSeq();"), h
    finally:
        driver.execute_script("window.createImageBitmap = window.__createImageBitmap;")


def test_screenshot_button_writes_png_exr_json(page: tuple[Any, ViewerServer]) -> None:
    driver, srv = page
    h = settled(driver)
    driver.find_element(By.ID, "screenshot").click()
    text = wait_for(lambda: "saved" in driver.find_element(By.ID, "message").text
                    and driver.find_element(By.ID, "message").text, "the screenshot message")
    out = Path(srv.inputs.out_dir)
    names = sorted(p.name for p in out.iterdir())
    assert len(names) == 3 and {Path(n).suffix for n in names} == {".exr", ".png", ".json"}, names
    assert all(n in text for n in names)
    report = json.loads((out / [n for n in names if n.endswith(".json")][0]).read_text())
    assert report["spp"] >= 1 and report["renderer"] == "neural"
    png = Image.open(out / [n for n in names if n.endswith(".png")][0])
    assert png.size == (h["width"], h["height"])  # the frame's size (the view's, scaled down to the cap)
    assert (report["camera"]["width"], report["camera"]["height"]) == png.size


def test_frames_follow_the_window_size(page: tuple[Any, ViewerServer]) -> None:
    """The view fills what the panel leaves of the window, in a large, a wide, a tall and a narrow window (the
    panel below the view there); each size's frames are rendered for the new box, with its aspect ratio, within
    the cap. A resize that changes nothing sends nothing, a burst of resizes sends one or two view messages, and
    the device pixel ratio counts (capped at 2)."""
    driver, _ = page
    start = driver.get_window_size()
    seen = []
    try:
        for width, height in [(1300, 800), (1400, 420), (700, 950), (520, 760)]:
            driver.set_window_size(width, height)
            h, box = frame_for_the_box(driver)
            inner = driver.execute_script("return [window.innerWidth, window.innerHeight];")
            areas = driver.execute_script("""return ['view', 'panel'].map((id) => {
                const r = document.getElementById(id).getBoundingClientRect(); return r.width * r.height; });""")
            assert sum(areas) == pytest.approx(inner[0] * inner[1], rel=0.01), (areas, inner)  # no gap, no overlap
            seen.append((box, (h["width"], h["height"])))
        assert len({b for b, _ in seen}) == 4 and len({f for _, f in seen}) == 4, seen
        assert seen[1][1][0] > 2 * seen[1][1][1] and seen[2][1][1] > seen[2][1][0], seen  # wide, then tall

        driver.execute_script("""window.__views = [];
            const send = WebSocket.prototype.send;
            WebSocket.prototype.__send = send;
            WebSocket.prototype.send = function (text) {
              if (JSON.parse(text).type === 'view') window.__views.push(text);
              return send.call(this, text);
            };""")
        driver.execute_script("window.dispatchEvent(new Event('resize'));")
        time.sleep(0.6)
        assert driver.execute_script("return window.__views.length;") == 0  # the size did not change
        driver.execute_async_script("""const done = arguments[0]; const panel = document.getElementById('panel');
            let k = 0; const step = () => { panel.style.flexBasis = (40 + 4 * k) + '%';
              if (++k < 10) setTimeout(step, 20); else setTimeout(done, 600); }; step();""")
        assert 1 <= driver.execute_script("return window.__views.length;") <= 2  # debounced: not one per step
        frame_for_the_box(driver)

        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                               {"width": 0, "height": 0, "deviceScaleFactor": 3, "mobile": False})
        css = driver.execute_script("const r = document.getElementById('view').getBoundingClientRect();"
                                    "return [r.width, r.height, window.devicePixelRatio];")
        assert css[2] == 3
        h, box = frame_for_the_box(driver)
        assert box == (round(css[0] * 2), round(css[1] * 2)) and h["view_size"] == list(box)
    finally:
        driver.execute_cdp_cmd("Emulation.clearDeviceMetricsOverride", {})
        driver.execute_script("document.getElementById('panel').style.flexBasis = '';"
                              "if (WebSocket.prototype.__send) WebSocket.prototype.send = WebSocket.prototype.__send;")
        driver.set_window_size(start["width"], start["height"])
    frame_for_the_box(driver)


def test_editing_the_transfer_function_marks_l_i_stale_and_shows_the_retraining(
        page: tuple[Any, ViewerServer]) -> None:
    """Last in the module: it leaves a retrain folder in the output folder. Drag the editor's brightest control
    point down: the frame follows the edit (a new generation), the page marks L_i stale, and the background
    retrain's progress appears (the stand-in trainer reports the fit at 50 %); cancel stops it."""
    driver, srv = page
    Select(driver.find_element(By.ID, "layer")).select_by_value("L")
    h0 = settled(driver, layer="L")
    assert not h0["stale"] and not driver.find_element(By.ID, "stale").is_displayed()
    points = driver.execute_script("return window.pfnView.tf.message().points;")
    i = max(range(len(points)), key=lambda k: points[k]["opacity"])
    x, y = driver.execute_script(f"return window.pfnView.tf.pointOnPage({i});")
    canvas = driver.find_element(By.ID, "tf")
    rect = driver.execute_script("const r = arguments[0].getBoundingClientRect(); return [r.left, r.top];", canvas)
    chain = ActionChains(driver).move_to_element_with_offset(canvas, 0, 0)  # the canvas's centre
    size = canvas.size
    chain.move_by_offset(round(x - rect[0] - size["width"] / 2), round(y - rect[1] - size["height"] / 2))
    chain.click_and_hold().move_by_offset(0, 30).pause(0.05).move_by_offset(0, 10).release().perform()
    after = driver.execute_script("return window.pfnView.tf.message().points;")
    assert after[i]["opacity"] < points[i]["opacity"] - 0.1, (points[i], after[i])
    h = settled(driver)
    assert h["generation"] > h0["generation"] and h["stale"]
    assert driver.find_element(By.ID, "stale").is_displayed()
    status = wait_for(lambda: (r := driver.execute_script("return window.pfnView.retrain();"))
                      and r["stage"] == "fit" and r, "the retrain's progress")
    assert status["state"] == "running" and status["fraction"] == pytest.approx((1 + 0.5) / 3, abs=1e-3)
    assert float(driver.find_element(By.ID, "retrain_bar").get_attribute("value")) > 0.4
    assert "fit" in driver.find_element(By.ID, "retrain_state").text
    driver.find_element(By.ID, "retrain_cancel").click()
    wait_for(lambda: driver.execute_script("return window.pfnView.retrain().state;") == "cancelled", "the cancel")
    assert "cancelled" in driver.find_element(By.ID, "retrain_state").text
