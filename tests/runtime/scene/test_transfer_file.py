"""Transfer-function files round-trip with the viewer's editor: a ``transfer`` message becomes a
TransferFunction (runtime/viewer/transfer_edit.py), is saved as a ``.json`` file, read back by a scene that names
it, and turns into the same message; a screenshot's recorded ``transfer_function`` is that file's content."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.scene import builtin_scene, scene_from_dict
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.viewer.messages import parse
from photon_fields.runtime.viewer.transfer_edit import transfer_from_message, transfer_message

#: What the page's editor sends after a user moved points (values not representable exactly in binary too).
EDITED = {"type": "transfer", "density_scale": 73.3,
          "points": [{"s": 0.0, "opacity": 0.0, "albedo": [0.1, 0.2, 0.3]},
                     {"s": 0.37, "opacity": 0.45, "albedo": [0.9, 0.8, 0.7]},
                     {"s": 1.0, "opacity": 1.0, "albedo": [1.0, 0.5, 0.25]}]}


def _scene(tf: object) -> dict:
    return {"name": "s", "volume": {"builtin": "blobs", "resolution": 16}, "transfer_function": tf,
            "lights": [{"type": "directional", "direction": [0, -1, 0], "color": [1, 1, 1], "power": 2}],
            "camera": {"eye": [1, 1, 1], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40, "width": 8, "height": 8}}


def test_message_to_file_to_scene_to_message(tmp_path: Path) -> None:
    msg = parse(json.dumps(EDITED))
    tf = transfer_from_message(msg.fields, builtin_scene("blobs", 16).tf)
    tf.save(tmp_path / "tf.json")
    scene = scene_from_dict(_scene("tf.json"), tmp_path)
    back = transfer_message(scene.tf)
    assert back == {"points": EDITED["points"], "density_scale": EDITED["density_scale"], "name": "cloud (edited)"}
    assert scene.fingerprint() == scene_from_dict(_scene(tf.to_dict()), tmp_path).fingerprint()
    # the editor's own message form (points, density_scale, name) is a TF file as it is
    (tmp_path / "as_sent.json").write_text(json.dumps(back))
    assert transfer_message(TransferFunction.load(tmp_path / "as_sent.json")) == back


def test_screenshot_record_is_a_transfer_function(tmp_path: Path) -> None:
    """A screenshot's JSON records ``transfer_function`` as ``tf.to_dict()`` (runtime/viewer/session.py): that
    object, copied into a scene (or saved as a file), is the edited function."""
    tf = transfer_from_message(parse(json.dumps(EDITED)).fields, builtin_scene("blobs", 16).tf)
    recorded = json.loads(json.dumps({"transfer_function": tf.to_dict()}))["transfer_function"]
    assert transfer_message(scene_from_dict(_scene(recorded), tmp_path).tf) == transfer_message(tf)


def test_save_refuses_to_replace(tmp_path: Path) -> None:
    tf = builtin_scene("blobs", 16).tf
    tf.save(tmp_path / "tf.json")
    with pytest.raises(InputError, match="tf.json: exists; pass force=True"):
        tf.save(tmp_path / "tf.json")
    tf.save(tmp_path / "tf.json", force=True)
