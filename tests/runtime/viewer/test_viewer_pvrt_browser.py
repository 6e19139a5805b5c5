"""PVRT in a real browser (headless Debian Chromium via selenium, as test_viewer_browser.py; skipped with the reason
where absent): selecting "pvrt" in the renderer menu shows its frame and fixes the g slider (the transfer renders its
own g only); moving the light's azimuth slider relights the view (from the kept samples) and the image changes."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from browser_helpers import header, pixels, require_browser, served_page, wait_for
from viewer_helpers import inputs, tiny_scene, tiny_transfer

require_browser()

from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402
from selenium.webdriver.support.ui import Select  # noqa: E402

SIZE = 64


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    scene = tiny_scene(SIZE)
    with served_page(inputs(tmp_path_factory.mktemp("pvrt_browser") / "out", size=SIZE, renderer="pt", scene=scene,
                            transfer=tiny_transfer(scene)), max_spp=2, drag_scale=1.0) as (driver, _):
        wait_for(lambda: driver.execute_script("return window.pfnView && window.pfnView.frames();"), "a first frame")
        yield driver


def pvrt_frame(driver: Any) -> dict:
    """Wait for a pvrt frame that includes every input the page sent (one frame is the whole resting view)."""
    def ok() -> dict | None:
        h = header(driver)
        last = driver.execute_script("return window.pfnView.lastSeq();")
        return h if h and h["renderer"] == "pvrt" and h["seq"] == last else None

    return wait_for(ok, "a pvrt frame of the last input")


def test_selecting_pvrt_and_moving_the_light_relights_the_image(page: Any) -> None:
    driver = page
    Select(driver.find_element(By.ID, "renderer")).select_by_value("pvrt")
    pvrt_frame(driver)
    assert not driver.find_element(By.ID, "g").is_enabled()
    assert "PVRT" in driver.find_element(By.ID, "g_note").text
    before = pixels(driver)
    assert before.mean() > 1.0
    slider = driver.find_element(By.ID, "az0")
    slider.click()  # focus (the click itself may move it to the middle)
    slider.send_keys(*([Keys.ARROW_RIGHT] * 60))
    h = pvrt_frame(driver)
    assert h["pvrt"]["relit"], h  # the camera rested: its samples were kept
    after = pixels(driver)
    volume = (before.sum(axis=2) > 0) | (after.sum(axis=2) > 0)
    assert np.abs(after - before)[volume].mean() > 2.0, np.abs(after - before)[volume].mean()
