"""What the viewer's browser tests share: headless Chromium from Debian's ``chromium`` and ``chromium-driver``
packages (never a downloaded browser) driven by selenium, skipped with the reason where either is missing, and
waiting for frames and reading the canvas's pixels.

Selenium is imported only after :func:`require_browser` has checked for it, so a test module calls that first,
at import, and skips as a whole where no browser can run."""

from __future__ import annotations

import base64
import io
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
from PIL import Image

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
DRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


def require_browser() -> None:
    """Skip the calling test module, saying why, where Chromium, its driver, selenium or the view extra is
    missing."""
    if not (os.path.exists(CHROMIUM) and os.path.exists(DRIVER)):
        pytest.skip("Chromium or chromedriver is not installed (Debian: apt-get install chromium chromium-driver; "
                    "`make install` does it where apt-get is available as root)", allow_module_level=True)
    pytest.importorskip("selenium", reason="selenium is not installed (pip install -e '.[browser-test]')")
    pytest.importorskip("uvicorn", reason="the view extra is not installed (pip install -e '.[view]')")


def open_chrome(url: str, scratch: str) -> Any:
    """A headless Chromium (900x700 window) showing ``url``, its temporary files (profile, the singleton socket it
    would otherwise leave in /tmp as ``org.chromium.Chromium.*``) in the folder ``scratch``; the caller quits it
    and removes the folder."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=900,700", "--no-first-run", "--disable-extensions"):
        opts.add_argument(arg)
    os.environ.setdefault("SE_OFFLINE", "true")  # selenium must not fetch a browser or a driver
    opts.add_argument(f"--user-data-dir={os.path.join(scratch, 'profile')}")
    driver = webdriver.Chrome(options=opts, service=Service(executable_path=DRIVER, env={**os.environ,
                                                                                          "TMPDIR": scratch}))
    driver.set_script_timeout(30)
    try:
        driver.get(url)
    except Exception:
        driver.quit()
        raise
    return driver


@contextmanager
def served_page(inputs: Any, **server: Any) -> Iterator[tuple[Any, Any]]:
    """(driver, server): a viewer serving ``inputs`` (a :class:`ViewerInputs`; ``server``: ViewerServer's options)
    on a free port, and a headless Chromium showing its page; both stopped afterwards."""
    from photon_fields.runtime.viewer.launch import ViewerServer

    srv = ViewerServer(inputs, port=0, warm=False, **server)
    scratch = tempfile.mkdtemp(prefix="pfn-chromium-")
    try:
        driver = open_chrome(srv.url, scratch)
        try:
            yield driver, srv
        finally:
            driver.quit()
    finally:
        srv.stop()
        shutil.rmtree(scratch, ignore_errors=True)


def wait_for(cond: Callable[[], Any], what: str, timeout: float = 600.0) -> Any:
    """Wait for ``cond()`` to be truthy. The timeout is generous: on a fresh clone the first frame compiles the
    renderer's kernels (~100 s on 2 cores), and a slow CI machine must not fail a test that is not about speed."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = cond()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def header(driver: Any) -> dict | None:
    """The header of the frame the page shows (None before the first)."""
    return driver.execute_script("return window.pfnView && window.pfnView.header();")


def settled(driver: Any, max_spp: int, **want: Any) -> dict:
    """Wait for a frame at ``max_spp`` (the image at rest) that includes every input the page sent (a drag's last
    movement is sent on the next animation frame, after the test's pointer events) and has the ``want``
    values."""
    def ok() -> dict | None:
        h = header(driver)
        last = driver.execute_script("return window.pfnView.lastSeq();")
        if not h or h["spp"] < max_spp or (last and h["seq"] != last):
            return None
        return h if all(h.get(k) == v for k, v in want.items()) else None

    return wait_for(ok, f"a settled frame with {want}")


def click_and_settle(driver: Any, element: Any, max_spp: int) -> dict:
    """Click ``element`` and wait for the settled frame of what the click sent: the page sends a control's change on
    its next animation frame, so a frame that settled before that would otherwise pass for the new one."""
    before = driver.execute_script("return window.pfnView.lastSeq();")
    element.click()
    wait_for(lambda: driver.execute_script("return window.pfnView.lastSeq();") > before, "the click's message",
             timeout=30.0)  # the next animation frame: no kernel compiles in between
    return settled(driver, max_spp)


def pixels(driver: Any) -> np.ndarray:
    """The view canvas's pixels, (height, width, 3) floats in [0, 255]."""
    url = driver.execute_script("return document.getElementById('view').toDataURL('image/png');")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"), dtype=float)
