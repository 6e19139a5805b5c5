"""Issue 11: a photon map or bundle used for another scene names what differs (volume, transfer function,
lights, each separately), refused or forced; files without per-part fingerprints say the parts cannot be
compared; the scene's part fingerprints are recorded by tracing and export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import tiny_scene_dict

from models_spec.fingerprint import FINGERPRINT_PARTS, fingerprint_parts, mismatch_detail, scene_fingerprint
from runtime.errors import InputError
from runtime.photon_estimate import check_map_matches_scene
from runtime.photon_map import PhotonMap
from runtime.scene import Scene, scene_from_dict

#: What each variant changes, and the message it must produce.
VARIANTS = {
    "lights": "lights differ (volume and transfer function match)",
    "tf": "transfer function differs (volume and lights match)",
    "volume": "volume differs (transfer function and lights match)",
    "tf+lights": "transfer function and lights differ (volume matches)",
    "all": "volume, transfer function and lights differ",
}


def base_dict() -> dict:
    d = tiny_scene_dict()
    d["volume"]["resolution"] = 16
    return d


def variant(kind: str) -> Scene:
    d = base_dict()
    if "lights" in kind or kind == "all":
        d["lights"][0]["power"] = 1.8  # another light power only: the case of the issue (L_i 40 % too dark)
    if "tf" in kind or kind == "all":
        d["transfer_function"] = {"preset": "cloud", "density_scale": 60}
    if kind in ("volume", "all"):
        d["volume"]["resolution"] = 20
    d["camera"]["fov"] = 25  # camera and g never count
    d["phase"] = {"g": 0.5}
    return scene_from_dict(d)


@pytest.fixture(scope="module")
def base() -> Scene:
    return scene_from_dict(base_dict())


def fake_map(scene: Scene, parts: bool = True) -> PhotonMap:
    rng = np.random.default_rng(0)
    n = 60
    meta = {"scene_parts": scene.fingerprint_parts()} if parts else {}
    down = np.tile([[0, -1, 0]], (n, 1)).astype(np.float32)
    return PhotonMap(rng.uniform(-0.4, 0.4, (n, 3)).astype(np.float32), down,
                     np.full((n, 3), 1e-3, np.float32), (np.arange(n) % 3).astype(np.uint8), (-0.75, 0.0, 0.75),
                     scene.fingerprint(), 1000, meta)


def test_parts_identify_each_part_and_the_combined_hash_is_unchanged(base: Scene) -> None:
    parts = base.fingerprint_parts()
    assert list(parts) == list(FINGERPRINT_PARTS) and parts["volume"] == base.volume.fingerprint()
    # The combined fingerprint is the one maps and bundles have always recorded (older files still match).
    assert base.fingerprint() == scene_fingerprint(base.volume.fingerprint(), base.tf.to_dict(),
                                                   [lt.to_dict() for lt in base.lights])
    for kind in ("lights", "tf", "volume"):
        other = variant(kind).fingerprint_parts()
        changed = [p for p in FINGERPRINT_PARTS if other[p] != parts[p]]
        assert changed == [{"tf": "transfer_function"}.get(kind, kind)], (kind, changed)
    # The transfer function's display name does not count, as in the combined fingerprint.
    tf = base.tf.to_dict()
    assert fingerprint_parts("v", tf, []) == fingerprint_parts("v", {**tf, "name": "other"}, [])


def test_mismatch_detail_words() -> None:
    a = {"volume": "1", "transfer_function": "2", "lights": "3"}
    assert mismatch_detail(a, {**a, "lights": "x"}) == VARIANTS["lights"]
    assert mismatch_detail(a, {**a, "volume": "x", "transfer_function": "x"}) == \
        "volume and transfer function differ (lights match)"
    assert "cannot be told" in mismatch_detail(a, None) and "cannot be told" in mismatch_detail(None, a)


@pytest.mark.parametrize("kind", list(VARIANTS))
def test_map_mismatch_names_what_differs(base: Scene, tmp_path: Path, kind: str) -> None:
    path = fake_map(base).save(tmp_path / "m.npz")
    other = variant(kind)
    pmap = PhotonMap.load(path)
    with pytest.raises(InputError) as err:
        check_map_matches_scene(pmap, other)
    msg = str(err.value)
    assert msg.startswith(f"{path}: was traced for another scene") and VARIANTS[kind] in msg, msg
    warning = check_map_matches_scene(pmap, other, force=True)
    assert warning is not None and warning.startswith(str(path)), warning
    assert VARIANTS[kind] in warning and "L_i will be wrong" in warning and "\n" not in warning
    assert check_map_matches_scene(pmap, base.with_overrides(g=0.75)) is None  # g and camera do not count
    with pytest.raises(InputError, match=f"another scene: {VARIANTS[kind].replace('(', '.').replace(')', '.')}"):
        PhotonMap.load(path, expected_fingerprint=other.fingerprint(), expected_parts=other.fingerprint_parts())


def test_old_map_without_parts_says_they_cannot_be_compared(base: Scene, tmp_path: Path) -> None:
    path = fake_map(base, parts=False).save(tmp_path / "old.npz")
    pmap = PhotonMap.load(path)
    assert pmap.scene_parts is None
    with pytest.raises(InputError, match="which cannot be told: the file records no per-part fingerprints"):
        check_map_matches_scene(pmap, variant("lights"))


def test_traced_map_records_the_parts(base: Scene, tmp_path: Path) -> None:
    from train.photon_tracing import trace_photons

    pmap = trace_photons(base, 3000, seed=1, progress=False)
    back = PhotonMap.load(pmap.save(tmp_path / "t.npz"))
    assert back.scene_parts == base.fingerprint_parts()
    assert "lights differ (volume and transfer function match)" in back.mismatch(variant("lights").fingerprint_parts())


def _rewrite_meta(src: Path, dst: Path, edit) -> Path:  # noqa: ANN001
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(arrays["meta"].tobytes().decode())
    edit(meta)
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(dst, **arrays)
    return dst


@pytest.mark.parametrize(("edit", "needles"), [
    (lambda m: m.update(emited=5), ["metadata: unknown key 'emited'", "did you mean 'emitted'"]),
    (lambda m: m.pop("scene_fingerprint"), ["metadata: missing 'scene_fingerprint'"]),
    (lambda m: m.update(scene_fingerprint="abc"), ["'scene_fingerprint' must be a sha256"]),
    (lambda m: m["scene_parts"].update(light="0" * 64), ["metadata scene_parts: unknown key 'light'"]),
    (lambda m: m["scene_parts"].pop("lights"), ["metadata scene_parts: missing 'lights'"]),
    (lambda m: m.update(stored=7), ["'stored' is 7 but the arrays hold 60"]),
])
def test_map_metadata_is_strict(base: Scene, tmp_path: Path, edit, needles: list[str]) -> None:  # noqa: ANN001
    good = fake_map(base).save(tmp_path / "good.npz")
    bad = _rewrite_meta(good, tmp_path / "bad.npz", edit)
    with pytest.raises(InputError) as err:
        PhotonMap.load(bad)
    msg = str(err.value)
    assert msg.startswith(str(bad)) and "\n" not in msg
    for needle in needles:
        assert needle in msg, msg
