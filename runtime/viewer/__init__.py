"""The interactive viewer (issue 15): a local web page that renders a scene progressively with the neural
renderer (or the path tracer / photon map) and lets a person orbit, zoom, pan and change g, lights, layer and
exposure. ``pfn-view`` is :mod:`photon_fields.runtime.viewer.cli`; in Jupyter::

    from photon_fields.runtime.viewer import start
    viewer = start("vortex", bundle="runs/vortex/field.pfn")
    viewer  # shows the page in the notebook (viewer.url opens it in a browser tab; viewer.stop() ends it)

Modules: ``messages`` (what the page may send, checked strictly), ``camera`` (orbit / pan / zoom), ``session``
(one page's render state machine), ``encode`` (tone mapping and JPEG / PNG), ``server`` (the starlette app),
``launch`` (loading the inputs and serving), ``cli``. Needs the ``view`` extra (starlette, uvicorn).
"""

from __future__ import annotations

from typing import Any


def start(*args: Any, **kwargs: Any) -> Any:
    """:func:`photon_fields.runtime.viewer.launch.start` (imported on use: the web stack loads only here)."""
    from photon_fields.runtime.viewer.launch import start as _start

    return _start(*args, **kwargs)
