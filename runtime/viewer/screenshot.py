"""Viewer screenshots: a view's accumulated layers written as ``NAME.exr`` (all layers, linear), ``NAME.png`` (one
layer, tone-mapped at the page's exposure) and ``NAME.json`` (what was shown and how) into the output folder,
the only folder the page can write to.

Each file is written atomically. Nothing is ever replaced: a name with any of the three files present is refused
before anything is written. A name is a plain file name (:data:`photon_fields.runtime.viewer.messages.NAME_PATTERN`:
no separators, never hidden), and its paths are checked to stay inside the folder. A failed write removes what the
call wrote. Refusals are :class:`photon_fields.runtime.viewer.messages.MessageError`, which the page shows.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.viewer.messages import NAME_PATTERN, MessageError

SUFFIXES = (".exr", ".png", ".json")


def free_stem(out_dir: Path, scene_name: str) -> str:
    """The first ``SCENE_0001``, ``SCENE_0002``, ... with none of its files in ``out_dir``."""
    base = "".join(c if c.isalnum() or c in "-_" else "_" for c in scene_name)[:40] or "view"
    for i in range(1, 100000):
        stem = f"{base}_{i:04d}"
        if not any((out_dir / f"{stem}{ext}").exists() for ext in SUFFIXES):
            return stem
    raise MessageError("screenshot: no free file name left in the output folder")


def write(out_dir: Path, stem: str, layers: Mapping[str, np.ndarray], report: dict[str, Any], *, png_layer: str,
          exposure: float | None) -> list[Path]:
    """Write ``stem``.exr / .png / .json into ``out_dir`` (module docstring); returns the paths written."""
    from photon_fields.runtime.io.atomic import atomic_write_text
    from photon_fields.runtime.io.images import write_image_set

    if not NAME_PATTERN.fullmatch(stem):
        raise MessageError(f"screenshot: {stem!r} is not a plain file name")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MessageError(f"screenshot: cannot create the output folder: {exc.strerror or exc}") from None
    root = out_dir.resolve()
    paths = [root / f"{stem}{ext}" for ext in SUFFIXES]
    if any(p.parent != root for p in paths):  # NAME_PATTERN allows no separator; belt and braces
        raise MessageError(f"screenshot: {stem!r} leaves the output folder")
    existing = [p.name for p in paths if p.exists() or p.is_symlink()]
    if existing:
        raise MessageError(f"screenshot: {', '.join(existing)} exists in the output folder; choose another "
                           f"name (files are never replaced)")
    written: list[Path] = []
    try:
        written += write_image_set(paths[0], dict(layers), {"photon_fields.viewer": json.dumps(report)},
                                   png_layer=png_layer, exposure=exposure)
        atomic_write_text(paths[2], json.dumps(report, indent=2) + "\n")
        written.append(paths[2])
    except (OSError, InputError, ValueError) as exc:
        for p in written:
            with contextlib.suppress(OSError):
                p.unlink()
        raise MessageError(f"screenshot: writing failed: {exc}") from None
    return written
