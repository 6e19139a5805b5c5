"""Strict validation of every message a viewer page sends (the server trusts nothing that arrives).

A message is one JSON object in a websocket text frame. Its ``type`` picks a schema: the set of keys it may
and must have, and for each key a check of its JSON type and range. Anything else is refused with one line
(:class:`MessageError`) that the server logs and sends back, and the connection keeps serving:

- text that is not JSON, JSON that is not an object, a frame larger than :data:`MAX_MESSAGE_BYTES`;
- an unknown ``type`` or control, an unknown or missing key;
- a key given twice (JSON readers disagree on which one counts);
- a wrong JSON type (``true`` is not a number, ``1.5`` is not an integer, a number is not a string);
- NaN or infinities (Python's JSON reader accepts ``NaN`` and ``Infinity``; they are refused here), and
  numbers outside the control's range, including huge integers.

What a valid message does is :meth:`photon_fields.runtime.viewer.session.ViewerSession.apply`'s business;
this module only says whether it is well formed, and returns it as a :class:`Message` with plain Python
values.

Messages (``seq``, optional everywhere: a non-negative integer the client numbers its inputs with; frames
report the last ``seq`` they include, which is how the page and the bench measure input-to-image latency):

- ``{"type": "orbit", "dx": deg, "dy": deg}``: turn the camera about its target (yaw, pitch);
- ``{"type": "pan", "dx": f, "dy": f}``: move the target across the view, in fractions of the view's height;
- ``{"type": "zoom", "factor": f}``: multiply the distance to the target by ``f``;
- ``{"type": "reset_camera"}``: back to the scene's camera;
- ``{"type": "set", "control": NAME, "value": V}``: one of :data:`CONTROLS`;
- ``{"type": "light", "index": i, "azimuth": deg, "elevation": deg, "power": p, "yaw": deg}``: light ``i``'s
  direction (where the light comes from) and power, or an environment map's rotation about the vertical axis
  (``yaw``); each optional;
- ``{"type": "view", "width": w, "height": h}``: the size the page shows frames at;
- ``{"type": "screenshot"}`` (``"name"`` optional: a plain file stem): PNG + EXR + JSON into the output folder;
- ``{"type": "transfer", "points": [{"s": f, "opacity": f, "albedo": [r, g, b]}, ...], "density_scale": f}``:
  the transfer function (1 to :data:`MAX_TF_POINTS` points, ``s`` strictly increasing in [0, 1], opacity and
  albedo in [0, 1]; the model is :class:`photon_fields.runtime.scene.transfer.TransferFunction`);
- ``{"type": "labels", "labels": {"3": {"albedo": [r, g, b], "opacity": o, "visible": true}, ...},
  "density_scale": f}``: a label scene's label panel (1 to :data:`MAX_LABEL_EDITS` labels, each a decimal integer
  string with at least one of ``albedo`` (three numbers in [0, 1]), ``opacity`` (in [0, 1]) and ``visible`` (a
  boolean); ``density_scale``, the extinction of opacity 1, in the ``transfer`` message's range; either key may be
  left out, not both); labels it does not list keep their settings, so "show all" on a volume of many labels is
  several messages. Whether the labels are in the volume is the session's check
  (:class:`photon_fields.runtime.viewer.transfer_edit.LabelPanel`); the model is
  :class:`photon_fields.runtime.scene.labels.LabelTransfer`;
- ``{"type": "retrain", "action": "start" | "cancel"}``: start a background retrain of the field for the
  scene as edited now, or cancel the running one.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from photon_fields.runtime.renderers.registry import CAMERA_ESTIMATOR_NAMES

#: The largest text frame accepted (bytes of UTF-8). Real messages are under 200 bytes.
MAX_MESSAGE_BYTES = 4096
#: Frame sizes a page may ask for (each side), and the most pixels in one frame: bounds the memory a page
#: can make the server allocate (film, denoiser state, encoded frame).
MIN_SIDE, MAX_SIDE, MAX_PIXELS = 16, 2048, 1920 * 1080
#: The most control points a page's transfer function may have (a message stays under MAX_MESSAGE_BYTES).
MAX_TF_POINTS = 32
#: The most labels one ``labels`` message may change (a message of that many stays under MAX_MESSAGE_BYTES with
#: the page's four decimals).
MAX_LABEL_EDITS = 32
#: A label as a ``labels`` message names it: a decimal integer in its one canonical spelling ("3", "-2"; not
#: "03", "+3" or " 3", so two keys never name one label), at most 10 digits.
LABEL_PATTERN = re.compile(r"-?(0|[1-9][0-9]{0,9})")
#: Renderers by the names the page uses, and what each is called in the renderer table.
RENDERER_NAMES = {"neural": "field", "pt": "pt", "preview": "raymarch", "marched": "raymarch-field",
                  "photonmap": "photonmap", "pvrt": "pvrt"}
LAYERS = ("L", "L_d", "L_i")
FORMATS = ("jpeg", "png")
#: A screenshot's file stem: letters, digits, ``-``, ``_``, ``.`` (not first), at most 64 characters; no path.
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}")


class MessageError(ValueError):
    """A refused message; ``str(err)`` is one line saying what was wrong."""

    def __init__(self, problem: str) -> None:
        self.problem = " ".join(str(problem).split())[:300]
        super().__init__(self.problem)


@dataclass(frozen=True)
class Message:
    """A validated message: its ``type``, the checked fields and the client's ``seq`` (or None)."""

    type: str
    fields: dict[str, Any]
    seq: int | None = None


Check = Callable[[str, Any], Any]


def number(lo: float, hi: float) -> Check:
    """A finite JSON number (int or float, not a boolean) in ``[lo, hi]``, as a float."""

    def check(key: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MessageError(f"'{key}' must be a number, got {type(value).__name__}")
        if isinstance(value, int) and abs(value) > 1 << 53:
            raise MessageError(f"'{key}' must be in [{lo:g}, {hi:g}], got a {value.bit_length()}-bit integer")
        v = float(value)
        if not math.isfinite(v):
            raise MessageError(f"'{key}' must be finite, got {v}")
        if not lo <= v <= hi:
            raise MessageError(f"'{key}' must be in [{lo:g}, {hi:g}], got {v:g}")
        return v

    return check


def integer(lo: int, hi: int) -> Check:
    """A JSON integer (not a boolean, not 2.0) in ``[lo, hi]``."""

    def check(key: str, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise MessageError(f"'{key}' must be an integer, got {type(value).__name__}")
        if not lo <= value <= hi:
            shown = value if abs(value) < 1 << 64 else f"a {value.bit_length()}-bit integer"
            raise MessageError(f"'{key}' must be an integer in [{lo}, {hi}], got {shown}")
        return value

    return check


def choice(options: tuple[str, ...]) -> Check:
    """A string that is one of ``options``."""

    def check(key: str, value: Any) -> str:
        if not isinstance(value, str) or value not in options:
            shown = repr(value[:40]) if isinstance(value, str) else type(value).__name__
            raise MessageError(f"'{key}' must be one of {', '.join(options)}, got {shown}")
        return value

    return check


def name(key: str, value: Any) -> str:
    """A screenshot's file stem (:data:`NAME_PATTERN`): never a path, never hidden."""
    if not isinstance(value, str) or not NAME_PATTERN.fullmatch(value):
        shown = repr(value[:40]) if isinstance(value, str) else type(value).__name__
        raise MessageError(f"'{key}' must be a plain file name of letters, digits, '-', '_', '.', at most 64 "
                           f"characters, got {shown}")
    return value


def exposure(key: str, value: Any) -> float | None:
    """Exposure in stops relative to the automatic exposure, or the string ``"auto"`` (re-measure it)."""
    if value == "auto":
        return None
    return number(-20.0, 20.0)(key, value)


#: ``set`` controls: name -> check of its value.
CONTROLS: dict[str, Check] = {
    "renderer": choice(tuple(RENDERER_NAMES)),
    "layer": choice(LAYERS),
    "g": number(-1.0, 1.0),
    "exposure": exposure,
    "format": choice(FORMATS),
    "denoise": lambda key, value: _boolean(key, value),
    "max_spp": integer(1, 1 << 16),
    "drag_scale": lambda key, value: drag_scale(key, value),
    "camera_estimator": choice(CAMERA_ESTIMATOR_NAMES),
}


def drag_scale(key: str, value: Any) -> float | str:
    """The moving frames' size: a fraction of the view in [0.25, 1], or ``"auto"`` (chosen for the frame rate)."""
    if value == "auto":
        return "auto"
    return number(0.25, 1.0)(key, value)


def _boolean(key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise MessageError(f"'{key}' must be true or false, got {type(value).__name__}")
    return value


def albedo(key: str, value: Any) -> list[float]:
    """An RGB albedo: a list of three numbers in [0, 1]."""
    if not isinstance(value, list) or len(value) != 3:
        raise MessageError(f"'{key}' must be a list of three numbers [r, g, b]")
    return [number(0.0, 1.0)(key, a) for a in value]


_TF_POINT: dict[str, Check] = {"s": number(0.0, 1.0), "opacity": number(0.0, 1.0), "albedo": albedo}


def tf_points(key: str, value: Any) -> list[dict[str, Any]]:
    """A transfer function's control points: a list of 1 to :data:`MAX_TF_POINTS` objects with exactly ``s``,
    ``opacity`` (numbers in [0, 1]) and ``albedo`` (three numbers in [0, 1]), ``s`` strictly increasing."""
    if not isinstance(value, list) or not 1 <= len(value) <= MAX_TF_POINTS:
        got = f"{len(value)} points" if isinstance(value, list) else type(value).__name__
        raise MessageError(f"'{key}' must be a list of 1 to {MAX_TF_POINTS} control points, got {got}")
    points = []
    for i, p in enumerate(value):
        where = f"{key}[{i}]"
        if not isinstance(p, dict) or set(p) != {"s", "opacity", "albedo"}:
            shown = sorted(str(k)[:20] for k in p)[:5] if isinstance(p, dict) else type(p).__name__
            raise MessageError(f"'{where}' must be an object with exactly s, opacity, albedo, got {shown}")
        point = {k: check(f"{where}.{k}", p[k]) for k, check in _TF_POINT.items()}
        if points and point["s"] <= points[-1]["s"]:
            raise MessageError(f"'{key}': s must increase strictly from point to point ({where})")
        points.append(point)
    return points


_LABEL_EDIT: dict[str, Check] = {"albedo": albedo, "opacity": number(0.0, 1.0), "visible": _boolean}


def label_edits(key: str, value: Any) -> list[dict[str, Any]]:
    """A ``labels`` message's edits: an object of 1 to :data:`MAX_LABEL_EDITS` labels (:data:`LABEL_PATTERN`), each
    an object with some of ``albedo``, ``opacity``, ``visible`` and nothing else. Returned as a list of
    ``{"label": int, ...the keys given}`` in the message's order (plain values: no integer keys)."""
    if not isinstance(value, dict) or not 1 <= len(value) <= MAX_LABEL_EDITS:
        got = f"{len(value)} labels" if isinstance(value, dict) else type(value).__name__
        raise MessageError(f"'{key}' must be an object of 1 to {MAX_LABEL_EDITS} labels, got {got}")
    edits = []
    for label, entry in value.items():
        where = f"{key}[{label[:20]!r}]"
        if not LABEL_PATTERN.fullmatch(label):
            raise MessageError(f"{where}: a label must be a decimal integer such as \"3\" (no sign but -, no "
                               "leading zeros, at most 10 digits)")
        if not isinstance(entry, dict) or not entry or not set(entry) <= set(_LABEL_EDIT):
            shown = sorted(str(k)[:20] for k in entry)[:5] if isinstance(entry, dict) else type(entry).__name__
            raise MessageError(f"{where} must be an object with some of albedo, opacity, visible, got {shown}")
        edit = {k: check(f"{where}.{k}", entry[k]) for k, check in _LABEL_EDIT.items() if k in entry}
        edits.append({"label": int(label), **edit})
    return edits


#: A transfer function's density scale (the extinction of opacity 1), in a ``transfer`` or a ``labels`` message.
DENSITY_SCALE = number(1e-3, 1e5)
#: Per message type: (required keys, optional keys), each key -> check. ``seq`` is optional everywhere.
SCHEMAS: dict[str, tuple[dict[str, Check], dict[str, Check]]] = {
    "orbit": ({"dx": number(-360.0, 360.0), "dy": number(-180.0, 180.0)}, {}),
    "pan": ({"dx": number(-10.0, 10.0), "dy": number(-10.0, 10.0)}, {}),
    "zoom": ({"factor": number(0.05, 20.0)}, {}),
    "reset_camera": ({}, {}),
    "set": ({"control": choice(tuple(CONTROLS)), "value": lambda key, value: value}, {}),
    "light": ({"index": integer(0, 63)}, {"azimuth": number(-360.0, 360.0), "elevation": number(-90.0, 90.0),
                                          "power": number(0.0, 1e6), "yaw": number(-360.0, 360.0)}),
    "view": ({"width": integer(MIN_SIDE, MAX_SIDE), "height": integer(MIN_SIDE, MAX_SIDE)}, {}),
    "screenshot": ({}, {"name": name}),
    "transfer": ({"points": tf_points, "density_scale": DENSITY_SCALE}, {}),
    "labels": ({}, {"labels": label_edits, "density_scale": DENSITY_SCALE}),
    "retrain": ({"action": choice(("start", "cancel"))}, {}),
}
SEQ = integer(0, (1 << 53) - 1)


def _reject_constant(token: str) -> None:
    raise MessageError(f"{token} is not a number JSON allows")


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        dup = next(k for k in keys if keys.count(k) > 1)
        raise MessageError(f"key {dup[:40]!r} appears more than once")
    return dict(pairs)


def parse(text: Any) -> Message:
    """The :class:`Message` in websocket text ``text``, or a :class:`MessageError` saying what is wrong."""
    if isinstance(text, (bytes, bytearray)):
        raise MessageError("binary frames are not accepted; send JSON text")
    if not isinstance(text, str):
        raise MessageError(f"expected JSON text, got {type(text).__name__}")
    size = len(text.encode("utf-8", errors="replace"))
    if size > MAX_MESSAGE_BYTES:
        raise MessageError(f"message of {size} bytes is larger than the {MAX_MESSAGE_BYTES} allowed")
    try:
        data = json.loads(text, parse_constant=_reject_constant, object_pairs_hook=_no_duplicates)
    except MessageError:
        raise
    except (ValueError, RecursionError) as exc:
        raise MessageError(f"not JSON: {exc}") from None
    return validate(data)


def validate(data: Any) -> Message:
    """Check a decoded JSON value against :data:`SCHEMAS` (see the module docstring)."""
    if not isinstance(data, dict):
        raise MessageError(f"a message must be a JSON object, got {type(data).__name__}")
    kind = data.get("type")
    if not isinstance(kind, str) or kind not in SCHEMAS:
        shown = repr(kind[:40]) if isinstance(kind, str) else type(kind).__name__
        raise MessageError(f"unknown message type {shown}; known: {', '.join(SCHEMAS)}")
    required, optional = SCHEMAS[kind]
    allowed = {"type", "seq", *required, *optional}
    unknown = [k for k in data if k not in allowed]
    if unknown:
        raise MessageError(f"{kind}: unknown key(s) {', '.join(repr(k[:40]) for k in unknown[:5])}; allowed: "
                           f"{', '.join(sorted(allowed))}")
    missing = [k for k in required if k not in data]
    if missing:
        raise MessageError(f"{kind}: missing {', '.join(repr(k) for k in missing)}")
    fields = {key: check(key, data[key]) for key, check in {**required, **optional}.items() if key in data}
    if kind == "set":
        fields["value"] = CONTROLS[fields["control"]](fields["control"], data["value"])
    if kind == "labels" and not fields:
        raise MessageError("labels: missing 'labels' or 'density_scale' (at least one)")
    if kind == "view" and fields["width"] * fields["height"] > MAX_PIXELS:
        raise MessageError(f"view: {fields['width']}x{fields['height']} is more than {MAX_PIXELS} pixels")
    seq = SEQ("seq", data["seq"]) if "seq" in data else None
    return Message(kind, fields, seq)
