"""The size a viewer renders frames at: the page's view, scaled down to fit ``pfn-view --size`` (the largest frame).

The page measures the box it shows frames in (CSS size x devicePixelRatio) and sends it as a ``view`` message;
:func:`fit_view` turns that into the frame size. A view within the cap is rendered as is (one frame pixel per
device pixel); a larger one is scaled down keeping its aspect ratio, and the page scales the frame up.

The cap bounds the **pixel count** (``W * H`` of ``--size``), not each side. A frame's cost (the render, the
denoiser, the encoding) grows with its pixels, and ``--size`` is the cost a user picked for the frame rate on
their machine; a pixel budget spends exactly that on any window shape. Bounding each side instead would punish
wide and tall windows for nothing: with ``--size 512x512`` a 1600x500 view would get 512x160 frames (a third of
the pixels, blurry when scaled up) where the budget gives 915x286 at the cost of one 512x512 frame.

Aspect first, then pixels: the shorter side is scaled down and rounded down, the longer one is that times the
view's aspect, rounded, so the frame's aspect matches the view's within one frame pixel (it may use a few
pixels less than the budget). A degenerate view (2000x16 against a small budget) cannot keep its aspect with
both sides at least :data:`MIN_SIDE`: the short side stays at :data:`MIN_SIDE` and the long one takes what the
budget leaves.
"""

from __future__ import annotations

import math

from photon_fields.runtime.viewer.messages import MIN_SIDE


def fit_view(view: tuple[int, int], cap: tuple[int, int]) -> tuple[int, int]:
    """The frame size for a page's ``view`` (width, height) under the largest frame ``cap`` (width, height):
    ``view`` itself when it has at most ``cap``'s pixels, else scaled down to them keeping its aspect ratio
    (module docstring). Both sides of the result are at least :data:`MIN_SIDE` and at most ``view``'s."""
    w, h = int(view[0]), int(view[1])
    budget = int(cap[0]) * int(cap[1])
    if min(w, h) < MIN_SIDE or budget < MIN_SIDE * MIN_SIDE:
        raise ValueError(f"fit_view: sides must be at least {MIN_SIDE}, got view {w}x{h} and cap {cap[0]}x{cap[1]}")
    if w * h <= budget:
        return w, h
    wide = w >= h
    short_v, long_v = (h, w) if wide else (w, h)
    scale = math.sqrt(budget / (w * h))
    short = max(MIN_SIDE, math.floor(short_v * scale + 1e-9))
    long = min(long_v, round(short * long_v / short_v), budget // short)
    return (long, short) if wide else (short, long)
