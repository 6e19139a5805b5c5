"""The frame size rule (runtime/viewer/frame_size.py): a page's view within ``--size``'s pixel count is rendered
as is; a larger one is scaled down to that pixel count keeping its aspect ratio (within one frame pixel), never
below the smallest side; every result is a size a ``view`` message may carry; the message's own bounds still
refuse what they refused."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from photon_fields.runtime.viewer.frame_size import fit_view
from photon_fields.runtime.viewer.messages import MAX_PIXELS, MAX_SIDE, MIN_SIDE, MessageError, parse


@pytest.mark.parametrize(("view", "cap"), [((600, 400), (512, 512)), ((512, 512), (512, 512)),
                                           ((1024, 256), (512, 512)), ((16, 16), (64, 64)),
                                           ((2000, 16), (512, 512)), ((16, 2000), (256, 256))])
def test_a_view_within_the_cap_is_taken_as_is(view: tuple[int, int], cap: tuple[int, int]) -> None:
    assert fit_view(view, cap) == view


@pytest.mark.parametrize(("view", "cap", "expected"), [
    ((1024, 1024), (512, 512), (512, 512)),  # same aspect: the cap itself
    ((1600, 500), (512, 512), (915, 286)),  # wide: as many pixels as 512x512, not 512x160 (286 * 3.2 = 915.2)
    ((500, 1600), (512, 512), (286, 915)),
    ((1920, 1080), (512, 512), (682, 384)),  # 384 * 16 / 9 = 682.7, but 683 x 384 is over the budget
    ((630, 700), (64, 64), (60, 67)),
])
def test_a_larger_view_is_scaled_down_to_the_caps_pixels_keeping_its_aspect(
        view: tuple[int, int], cap: tuple[int, int], expected: tuple[int, int]) -> None:
    w, h = fit_view(view, cap)
    assert (w, h) == expected
    assert w * h <= cap[0] * cap[1]


def test_a_degenerate_aspect_stays_valid() -> None:
    """2000x16 cannot keep its aspect under a 64x64 budget with both sides >= MIN_SIDE: the short side stays at
    MIN_SIDE and the long one takes the rest of the budget."""
    assert fit_view((2000, 16), (64, 64)) == (256, 16)
    assert fit_view((16, 2000), (64, 64)) == (16, 256)
    assert fit_view((2048, 16), (16, 16)) == (16, 16)
    with pytest.raises(ValueError, match="at least"):
        fit_view((8, 100), (64, 64))


def test_the_view_messages_bounds_still_refuse_what_they_refused() -> None:
    for width, height, why in [(MIN_SIDE - 1, 100, "integer in"), (100, MAX_SIDE + 1, "integer in"),
                               (0, 10, "integer in"), (MAX_SIDE, MAX_SIDE, "pixels"), (1921, 1080, "pixels"),
                               (640.0, 480, "integer"), (True, 480, "integer")]:
        with pytest.raises(MessageError, match=why):
            parse(json.dumps({"type": "view", "width": width, "height": height}))
    assert parse('{"type": "view", "width": 1920, "height": 1080}').fields == {"width": 1920, "height": 1080}


sides = st.integers(MIN_SIDE, MAX_SIDE)


@given(sides, sides, sides, sides)
def test_every_fitted_size_is_a_valid_view_within_the_cap(w: int, h: int, cw: int, ch: int) -> None:
    """For any view a message may carry and any cap ``--size`` accepts: the frame is within the cap's pixels, a
    valid view itself, no larger than the view on either side, keeps the view's aspect within one frame pixel
    unless a side is held at MIN_SIDE, and does not waste the budget (at least 1 - 3 / short side of it)."""
    if w * h > MAX_PIXELS or cw * ch > MAX_PIXELS:
        return
    fw, fh = fit_view((w, h), (cw, ch))
    assert parse(json.dumps({"type": "view", "width": fw, "height": fh})).fields == {"width": fw, "height": fh}
    assert fw <= w and fh <= h
    budget = cw * ch
    if w * h <= budget:
        assert (fw, fh) == (w, h)
        return
    assert fw * fh <= budget
    aspect_kept = abs(fw * h - fh * w) <= min(w, h)  # the long side within one frame pixel of short * aspect
    if min(fw, fh) > MIN_SIDE:
        assert aspect_kept and fw * fh >= budget * (1 - 3 / min(fw, fh)), (fw, fh)
    else:  # the short side held at MIN_SIDE: the long one takes the rest of the budget
        assert aspect_kept or max(fw, fh) == min(max(w, h), budget // MIN_SIDE), (fw, fh)
