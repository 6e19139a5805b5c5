"""Message validation (runtime/viewer/messages.py): every kind of malformed or hostile message is refused with
one MessageError line, valid ones come back as plain checked values, and nothing else is ever raised."""

from __future__ import annotations

import contextlib
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from photon_fields.runtime.viewer.messages import (
    CONTROLS,
    MAX_MESSAGE_BYTES,
    SCHEMAS,
    Message,
    MessageError,
    parse,
)

VALID = [
    ('{"type": "orbit", "dx": 3.5, "dy": -2, "seq": 4}', "orbit", {"dx": 3.5, "dy": -2.0}, 4),
    ('{"type": "pan", "dx": 0.1, "dy": 0}', "pan", {"dx": 0.1, "dy": 0.0}, None),
    ('{"type": "zoom", "factor": 1.1}', "zoom", {"factor": 1.1}, None),
    ('{"type": "reset_camera"}', "reset_camera", {}, None),
    ('{"type": "set", "control": "g", "value": -0.7}', "set", {"control": "g", "value": -0.7}, None),
    ('{"type": "set", "control": "renderer", "value": "pt"}', "set", {"control": "renderer", "value": "pt"}, None),
    ('{"type": "set", "control": "layer", "value": "L_i"}', "set", {"control": "layer", "value": "L_i"}, None),
    ('{"type": "set", "control": "exposure", "value": "auto"}', "set", {"control": "exposure", "value": None}, None),
    ('{"type": "set", "control": "exposure", "value": 1.5}', "set", {"control": "exposure", "value": 1.5}, None),
    ('{"type": "set", "control": "format", "value": "png"}', "set", {"control": "format", "value": "png"}, None),
    ('{"type": "set", "control": "denoise", "value": false}', "set", {"control": "denoise", "value": False}, None),
    ('{"type": "set", "control": "max_spp", "value": 64}', "set", {"control": "max_spp", "value": 64}, None),
    ('{"type": "set", "control": "drag_scale", "value": 0.5}', "set", {"control": "drag_scale", "value": 0.5}, None),
    ('{"type": "set", "control": "drag_scale", "value": "auto"}', "set", {"control": "drag_scale", "value": "auto"},
     None),
    ('{"type": "set", "control": "camera_estimator", "value": "marched"}', "set",
     {"control": "camera_estimator", "value": "marched"}, None),
    ('{"type": "light", "index": 0, "azimuth": 30, "power": 2}', "light", {"index": 0, "azimuth": 30.0,
                                                                            "power": 2.0}, None),
    ('{"type": "view", "width": 640, "height": 480}', "view", {"width": 640, "height": 480}, None),
    ('{"type": "screenshot"}', "screenshot", {}, None),
    ('{"type": "screenshot", "name": "shot-1.v2"}', "screenshot", {"name": "shot-1.v2"}, None),
    ('{"type": "transfer", "points": [{"s": 0, "opacity": 0, "albedo": [1, 1, 1]}, '
     '{"s": 0.5, "opacity": 0.25, "albedo": [0.9, 0.5, 0.1]}], "density_scale": 40}', "transfer",
     {"points": [{"s": 0.0, "opacity": 0.0, "albedo": [1.0, 1.0, 1.0]},
                 {"s": 0.5, "opacity": 0.25, "albedo": [0.9, 0.5, 0.1]}], "density_scale": 40.0}, None),
    ('{"type": "labels", "labels": {"3": {"albedo": [0.9, 0.1, 0], "opacity": 0.5, "visible": true}, '
     '"-2": {"visible": false}, "0": {"opacity": 1}}, "seq": 2}', "labels",
     {"labels": [{"label": 3, "albedo": [0.9, 0.1, 0.0], "opacity": 0.5, "visible": True},
                 {"label": -2, "visible": False}, {"label": 0, "opacity": 1.0}]}, 2),
    ('{"type": "labels", "labels": {"4294967295": {"albedo": [1, 1, 1]}}}', "labels",
     {"labels": [{"label": 4294967295, "albedo": [1.0, 1.0, 1.0]}]}, None),
    ('{"type": "labels", "density_scale": 25}', "labels", {"density_scale": 25.0}, None),
    ('{"type": "labels", "labels": {"3": {"visible": true}}, "density_scale": 0.5}', "labels",
     {"labels": [{"label": 3, "visible": True}], "density_scale": 0.5}, None),
    ('{"type": "light", "index": 1, "yaw": -45}', "light", {"index": 1, "yaw": -45.0}, None),
    ('{"type": "retrain", "action": "start", "seq": 9}', "retrain", {"action": "start"}, 9),
    ('{"type": "retrain", "action": "cancel"}', "retrain", {"action": "cancel"}, None),
]


def plain(value: object) -> bool:
    """Only JSON's plain values: numbers, strings, booleans, None, and lists and dicts of them."""
    if isinstance(value, list):
        return all(plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and plain(v) for k, v in value.items())
    return type(value) in (int, float, str, bool, type(None))


@pytest.mark.parametrize(("text", "kind", "fields", "seq"), VALID)
def test_valid_messages(text: str, kind: str, fields: dict, seq: int | None) -> None:
    m = parse(text)
    assert m == Message(kind, fields, seq)
    assert plain(m.fields)


BAD = [
    ("", "not JSON"),
    ("{", "not JSON"),
    ("[1, 2]", "JSON object"),
    ("42", "JSON object"),
    ('"orbit"', "JSON object"),
    ("null", "JSON object"),
    ('{"dx": 1}', "unknown message type"),
    ('{"type": "explode"}', "unknown message type"),
    ('{"type": 7}', "unknown message type"),
    ('{"type": "orbit", "dx": 1}', "missing 'dy'"),
    ('{"type": "orbit", "dx": 1, "dy": 2, "dz": 3}', "unknown key"),
    ('{"type": "orbit", "dx": "1", "dy": 2}', "must be a number"),
    ('{"type": "orbit", "dx": true, "dy": 2}', "must be a number"),
    ('{"type": "orbit", "dx": null, "dy": 2}', "must be a number"),
    ('{"type": "orbit", "dx": [1], "dy": 2}', "must be a number"),
    ('{"type": "orbit", "dx": NaN, "dy": 2}', "NaN"),
    ('{"type": "orbit", "dx": Infinity, "dy": 2}', "Infinity"),
    ('{"type": "orbit", "dx": -Infinity, "dy": 2}', "Infinity"),
    ('{"type": "orbit", "dx": 1e400, "dy": 2}', "finite"),
    ('{"type": "orbit", "dx": 1e9, "dy": 2}', "must be in"),
    ('{"type": "orbit", "dx": 123456789012345678901234567890, "dy": 2}', "must be in"),
    ('{"type": "zoom", "factor": 0}', "must be in"),
    ('{"type": "zoom", "factor": -2}', "must be in"),
    ('{"type": "set", "control": "g", "value": 1.0000001}', "must be in"),
    ('{"type": "set", "control": "g", "value": "0.5"}', "must be a number"),
    ('{"type": "set", "control": "g"}', "missing 'value'"),
    ('{"type": "set", "control": "volume", "value": 1}', "must be one of"),
    ('{"type": "set", "control": "__class__", "value": 1}', "must be one of"),
    ('{"type": "set", "control": "renderer", "value": "raymarch"}', "must be one of"),
    ('{"type": "set", "control": "layer", "value": "L_e"}', "must be one of"),
    ('{"type": "set", "control": "exposure", "value": "bright"}', "must be a number"),
    ('{"type": "set", "control": "denoise", "value": 1}', "true or false"),
    ('{"type": "set", "control": "max_spp", "value": 2.0}', "integer"),
    ('{"type": "set", "control": "max_spp", "value": 1000000000}', "integer in"),
    ('{"type": "set", "control": "drag_scale", "value": 0.1}', "must be in"),
    ('{"type": "set", "control": "drag_scale", "value": "fast"}', "must be a number"),
    ('{"type": "set", "control": "camera_estimator", "value": "ratio"}', "must be one of"),
    ('{"type": "light", "index": -1}', "integer in"),
    ('{"type": "light", "index": 0.5}', "integer"),
    ('{"type": "light", "index": 0, "power": -1}', "must be in"),
    ('{"type": "light", "index": 0, "elevation": 91}', "must be in"),
    ('{"type": "view", "width": 100000, "height": 10}', "integer in"),
    ('{"type": "view", "width": 2048, "height": 2048}', "pixels"),
    ('{"type": "view", "width": 0, "height": 10}', "integer in"),
    ('{"type": "screenshot", "name": "../escape"}', "plain file name"),
    ('{"type": "screenshot", "name": "/etc/passwd"}', "plain file name"),
    ('{"type": "screenshot", "name": "a/b"}', "plain file name"),
    ('{"type": "screenshot", "name": ".hidden"}', "plain file name"),
    ('{"type": "screenshot", "name": ""}', "plain file name"),
    ('{"type": "screenshot", "name": "' + "a" * 65 + '"}', "plain file name"),
    ('{"type": "screenshot", "name": "a\\u0000b"}', "plain file name"),
    ('{"type": "screenshot", "name": 3}', "plain file name"),
    ('{"type": "reset_camera", "seq": -1}', "integer in"),
    ('{"type": "reset_camera", "seq": "1"}', "integer"),
    ('{"type": "orbit", "dx": 1, "dy": 2, "type": "zoom"}', "more than once"),
    ('{"type": "transfer", "points": [], "density_scale": 1}', "1 to 32 control points"),
    ('{"type": "transfer", "points": {"s": 0}, "density_scale": 1}', "list of 1 to 32"),
    ('{"type": "transfer", "points": [' + ", ".join(['{"s": 0, "opacity": 0, "albedo": [0, 0, 0]}'] * 33)
     + '], "density_scale": 1}', "got 33 points"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, 1]}, '
     '{"s": 0.5, "opacity": 1, "albedo": [1, 1, 1]}], "density_scale": 1}', "increase strictly"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, 1], "x": 1}], "density_scale": 1}',
     "exactly s, opacity, albedo"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1}], "density_scale": 1}', "exactly s, opacity, albedo"),
    ('{"type": "transfer", "points": [7], "density_scale": 1}', "exactly s, opacity, albedo"),
    ('{"type": "transfer", "points": [{"s": 1.5, "opacity": 1, "albedo": [1, 1, 1]}], "density_scale": 1}',
     "must be in"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": NaN, "albedo": [1, 1, 1]}], "density_scale": 1}', "NaN"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1]}], "density_scale": 1}',
     "three numbers"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, 2]}], "density_scale": 1}',
     "must be in"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, true]}], "density_scale": 1}',
     "must be a number"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, 1]}], "density_scale": 0}',
     "must be in"),
    ('{"type": "transfer", "points": [{"s": 0.5, "opacity": 1, "albedo": [1, 1, 1]}]}', "missing 'density_scale'"),
    # labels: each kind of bad label key, entry, albedo, opacity, visibility, and too many labels
    ('{"type": "labels"}', "missing 'labels'"),
    ('{"type": "labels", "labels": {}}', "1 to 32 labels, got 0"),
    ('{"type": "labels", "labels": [{"label": 3, "visible": true}]}', "must be an object of 1 to 32"),
    ('{"type": "labels", "labels": {' + ", ".join(f'"{i}": {{"visible": true}}' for i in range(33)) + "}}",
     "got 33 labels"),
    ('{"type": "labels", "labels": {"liver": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {"3.0": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {"03": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {"+3": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {" 3": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {"12345678901": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {"": {"visible": true}}}', "a label must be a decimal integer"),
    ('{"type": "labels", "labels": {"3": {"visible": true}, "3": {"visible": false}}}', "more than once"),
    ('{"type": "labels", "labels": {"3": {}}}', "some of albedo, opacity, visible"),
    ('{"type": "labels", "density_scale": 0}', "'density_scale' must be in [0.001, 100000]"),
    ('{"type": "labels", "density_scale": -3}', "'density_scale' must be in"),
    ('{"type": "labels", "density_scale": "x2"}', "'density_scale' must be a number"),
    ('{"type": "labels", "density_scale": true}', "'density_scale' must be a number"),
    ('{"type": "labels", "density_scale": NaN}', "NaN"),
    ('{"type": "labels", "density_scale": 1, "density": 2}', "unknown key(s) 'density'"),
    ('{"type": "light", "index": 0, "yaw": 400}', "'yaw' must be in [-360, 360]"),
    ('{"type": "labels", "labels": {"3": true}}', "some of albedo, opacity, visible"),
    ('{"type": "labels", "labels": {"3": {"visible": true, "colour": [1, 0, 0]}}}', "some of albedo, opacity, visible"),
    ('{"type": "labels", "labels": {"3": {"albedo": [1, 0]}}}', "three numbers"),
    ('{"type": "labels", "labels": {"3": {"albedo": "#ff0000"}}}', "three numbers"),
    ('{"type": "labels", "labels": {"3": {"albedo": [1, 0, 1.5]}}}', "must be in [0, 1]"),
    ('{"type": "labels", "labels": {"3": {"albedo": [1, 0, -0.1]}}}', "must be in [0, 1]"),
    ('{"type": "labels", "labels": {"3": {"albedo": [1, 0, NaN]}}}', "NaN"),
    ('{"type": "labels", "labels": {"3": {"albedo": [1, 0, 1e400]}}}', "finite"),
    ('{"type": "labels", "labels": {"3": {"albedo": [1, 0, false]}}}', "must be a number"),
    ('{"type": "labels", "labels": {"3": {"opacity": 2}}}', "must be in [0, 1]"),
    ('{"type": "labels", "labels": {"3": {"opacity": -Infinity}}}', "Infinity"),
    ('{"type": "labels", "labels": {"3": {"opacity": "1"}}}', "must be a number"),
    ('{"type": "labels", "labels": {"3": {"visible": 1}}}', "true or false"),
    ('{"type": "labels", "labels": {"3": {"visible": "no"}}}', "true or false"),
    ('{"type": "labels", "labels": {"3": {"visible": true}}, "points": []}', "unknown key"),
    ('{"type": "retrain"}', "missing 'action'"),
    ('{"type": "retrain", "action": "rm -rf"}', "must be one of"),
    ("[" * 3000 + "]" * 3000, "larger than"),
    ("[" * 2000 + "]" * 2000, "not JSON"),
    ('{"type": "orbit", "dx": 1, "dy": 2, "pad": "' + "x" * MAX_MESSAGE_BYTES + '"}', "larger than"),
]


@pytest.mark.parametrize(("text", "needle"), BAD)
def test_bad_messages_are_refused_in_one_line(text: str, needle: str) -> None:
    with pytest.raises(MessageError) as info:
        parse(text)
    line = str(info.value)
    assert needle in line, line
    assert "\n" not in line and len(line) <= 300


@pytest.mark.parametrize("payload", [b'{"type": "reset_camera"}', bytearray(b"x"), None, 5, ["x"]])
def test_non_text_payloads_are_refused(payload: object) -> None:
    with pytest.raises(MessageError):
        parse(payload)


def test_every_control_and_type_has_a_valid_example() -> None:
    """The VALID table covers the whole schema (a new control needs a test)."""
    kinds = {kind for _, kind, _, _ in VALID}
    controls = {fields["control"] for _, kind, fields, _ in VALID if kind == "set"}
    assert kinds == set(SCHEMAS)
    assert controls == set(CONTROLS)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(1 << 80), max_value=1 << 80)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12)
field_names = st.sampled_from(["dx", "dy", "factor", "control", "value", "index", "azimuth", "elevation", "power",
                               "width", "height", "name", "seq", "extra", "labels"])
messages = st.fixed_dictionaries({"type": st.sampled_from([*SCHEMAS, "nope"])},
                                 optional={"control": st.sampled_from([*CONTROLS, "nope"])}) \
    .flatmap(lambda base: st.dictionaries(field_names, json_values, max_size=5).map(lambda d: {**d, **base}))


def _finite_in_range(m: Message) -> None:
    for v in m.fields.values():
        if isinstance(v, float):
            assert math.isfinite(v) and abs(v) <= 1e6


@settings(max_examples=400, deadline=None)
@given(messages)
def test_fuzzed_messages_parse_or_are_refused(data: dict) -> None:
    """Any JSON object either validates (then every number is finite and in range, every key known) or is
    refused with MessageError, never another exception."""
    text = json.dumps(data, allow_nan=True)
    try:
        m = parse(text)
    except MessageError as err:
        assert "\n" not in str(err)
        return
    required, optional = SCHEMAS[m.type]
    assert set(m.fields) <= set(required) | set(optional)
    assert set(data) <= {"type", "seq", *required, *optional}
    _finite_in_range(m)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=200) | st.binary(max_size=200))
def test_fuzzed_text_never_raises_anything_else(payload: str | bytes) -> None:
    with contextlib.suppress(MessageError):
        parse(payload)


label_keys = st.sampled_from(["3", "0", "-7", "03", "x", "", "1e3", "99999999999"]) | st.text(max_size=6)
label_entries = st.dictionaries(st.sampled_from(["albedo", "opacity", "visible", "colour"]), json_values, max_size=3)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(label_keys, label_entries | json_values, max_size=5))
def test_fuzzed_label_edits_parse_or_are_refused(labels: dict) -> None:
    """A ``labels`` message either validates to integer labels with finite values in [0, 1] and booleans, or is
    refused in one MessageError line."""
    try:
        m = parse(json.dumps({"type": "labels", "labels": labels}, allow_nan=True))
    except MessageError as err:
        assert "\n" not in str(err)
        return
    for edit in m.fields["labels"]:
        assert type(edit["label"]) is int and set(edit) - {"label"} and set(edit) <= {"label", "albedo", "opacity",
                                                                                      "visible"}
        values = [*edit.get("albedo", []), *([edit["opacity"]] if "opacity" in edit else [])]
        assert all(type(v) is float and 0.0 <= v <= 1.0 for v in values)
        assert type(edit.get("visible", True)) is bool
