"""A label scene in a real browser (headless Debian Chromium via selenium, as test_viewer_browser.py; skipped with
the reason where absent): the page shows the label panel instead of the transfer-function editor, a row per label
present with its voxel count; unticking one label's checkbox re-renders without it (its half of the view goes
dark, the other object stays), ticking it brings it back; "hide all" empties the view and "show all" shows the
objects again (the background label stays hidden); a screenshot records the label function shown.

The path tracer at a small ``max_spp`` converges to a fixed image, so any difference is the input's."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser_helpers import click_and_settle, pixels, require_browser, served_page, wait_for
from browser_helpers import settled as settled_at
from viewer_helpers import BACKGROUND, BALL, CUBE, inputs, label_scene

require_browser()

from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402

from photon_fields.runtime.scene.labels import LabelTransfer  # noqa: E402
from photon_fields.runtime.viewer import transfer_edit  # noqa: E402

SIZE, MAX_SPP = 64, 3


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Any, Any]]:
    """(driver, server) of a page on the label scene, once its first frame is shown. The panel tells the page that
    a message may change one label (the server accepts up to 32), so that "hide all" and "show all" on this
    scene's three labels take several messages, as they do on a volume of many labels."""
    scene = label_scene(tmp_path_factory.mktemp("labels"), size=SIZE)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(transfer_edit, "MAX_LABEL_EDITS", 1)  # before the page connects and reads it
        with served_page(inputs(tmp_path_factory.mktemp("shots") / "out", size=SIZE, renderer="pt", scene=scene),
                         max_spp=MAX_SPP, drag_scale=1.0) as (driver, srv):
            wait_for(lambda: driver.execute_script("return window.pfnView && window.pfnView.frames();"),
                     "a first frame")
            yield driver, srv


@pytest.fixture
def page(served: tuple[Any, Any]) -> Any:
    return served[0]


def settled(driver: Any, **want: Any) -> dict:
    """:func:`browser_helpers.settled` at this module's MAX_SPP."""
    return settled_at(driver, MAX_SPP, **want)


def checkbox(driver: Any, label: int) -> Any:
    return driver.find_element(By.CSS_SELECTOR, f'.label_row[data-label="{label}"] input[type=checkbox]')


def click(driver: Any, element: Any) -> dict:
    """Click and wait for the frame at rest of what the click sent."""
    return click_and_settle(driver, element, MAX_SPP)


def test_the_page_shows_the_label_panel(page: Any) -> None:
    driver = page
    assert driver.find_element(By.ID, "labels_box").is_displayed()
    assert not driver.find_element(By.ID, "tf_box").is_displayed()  # no control points for labels
    rows = driver.find_elements(By.CSS_SELECTOR, ".label_row")
    assert [r.get_attribute("data-label") for r in rows] == [str(BACKGROUND), str(BALL), str(CUBE)]
    counts = [int(r.find_element(By.CSS_SELECTOR, ".label_count").text.split()[0].replace(",", "")) for r in rows]
    assert sum(counts) == 32**3 and min(counts) > 1000
    assert [checkbox(driver, v).is_selected() for v in (BACKGROUND, BALL, CUBE)] == [False, True, True]
    assert all(len(r.find_elements(By.CSS_SELECTOR, "input[type=color], input[type=range]")) == 2 for r in rows)


def test_unticking_a_label_hides_it_and_ticking_brings_it_back(page: Any) -> None:
    driver = page
    h0 = settled(driver)
    before = pixels(driver)
    lit = before.sum(axis=2) > 30
    assert lit.mean() > 0.1  # both objects are seen
    h = click(driver, checkbox(driver, CUBE))
    assert h["generation"] > h0["generation"]
    hidden = pixels(driver)
    gone = lit & (hidden.sum(axis=2) < 3)  # lit before, black now: where only the cube was seen
    kept = lit & (hidden.sum(axis=2) > 30)  # the ball
    assert gone.mean() > 0.05 and kept.mean() > 0.05, (gone.mean(), kept.mean())
    columns = np.nonzero(gone)[1].mean(), np.nonzero(kept)[1].mean()
    assert columns[0] > columns[1]  # the cube is the object on the right
    assert not driver.execute_script("return window.pfnView.labels.rows();")[2]["visible"]
    click(driver, checkbox(driver, CUBE))
    assert np.abs(pixels(driver) - before).mean() < 2.0  # the same converged image as before


def test_hide_all_empties_the_view_and_show_all_shows_the_objects(page: Any) -> None:
    driver = page
    settled(driver)
    click(driver, driver.find_element(By.ID, "labels_hide_all"))
    assert pixels(driver).max() == 0.0
    assert not any(checkbox(driver, v).is_selected() for v in (BACKGROUND, BALL, CUBE))
    click(driver, driver.find_element(By.ID, "labels_show_all"))
    assert (pixels(driver).sum(axis=2) > 30).mean() > 0.1
    assert [checkbox(driver, v).is_selected() for v in (BACKGROUND, BALL, CUBE)] == [False, True, True]


def test_the_density_slider_thins_every_label_and_comes_back(page: Any) -> None:
    driver = page
    settled(driver)
    before = pixels(driver)
    shown = float(driver.find_element(By.ID, "label_density_value").text)
    slider = driver.find_element(By.ID, "label_density")
    slider.click()  # focus (the click itself may move it to the middle: x1)
    for key, thinner in ((Keys.ARROW_LEFT, True), (Keys.ARROW_RIGHT, False)):
        sent = driver.execute_script("return window.pfnView.lastSeq();")
        slider.send_keys(*([key] * 80))
        wait_for(lambda s=sent: driver.execute_script("return window.pfnView.lastSeq();") > s, "the slider's message",
                 timeout=30.0)
        settled(driver)
        density = float(driver.find_element(By.ID, "label_density_value").text)
        change = np.abs(pixels(driver) - before).mean()
        if thinner:
            assert density < 0.3 * shown and change > 2.0, (density, change)
        else:
            assert density == pytest.approx(shown, rel=1e-3) and change < 2.0, (density, change)


def test_a_screenshot_of_a_label_view_records_the_label_function(served: tuple[Any, Any]) -> None:
    """The screenshot button on a label view: its JSON's transfer function is the label function shown, which
    LabelTransfer reads back against the volume."""
    driver, srv = served
    click(driver, checkbox(driver, BALL))
    driver.find_element(By.ID, "screenshot").click()
    wait_for(lambda: "saved" in driver.find_element(By.ID, "message").text, "the screenshot message")
    report = json.loads(next(Path(srv.inputs.out_dir).glob("*.json")).read_text())
    path = Path(srv.inputs.out_dir) / "shown_labels_tf.json"
    path.write_text(json.dumps(report["transfer_function"]))
    tf = LabelTransfer.load(path, volume=srv.inputs.scene.volume)
    assert dict(zip(tf.labels.tolist(), tf.opacity.tolist(), strict=True)) == {BACKGROUND: 0.0, BALL: 0.0, CUBE: 1.0}
    click(driver, checkbox(driver, BALL))
