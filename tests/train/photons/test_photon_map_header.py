"""``read_header``: a photon map's metadata and size without its photons (what ``pfn-train update`` reads of the
earlier run's map): the same answers as a full load, the same refusals of bad metadata and arrays, and no photon
read (a map whose photons a load refuses still has a readable header)."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.photon_map import PhotonMap, read_header
from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.train.photons.tracing import trace_photons


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory) -> tuple[PhotonMap, Path]:
    scene = builtin_scene("blobs", resolution=32)
    pmap = trace_photons(scene, 4_000, seed=5, max_bounces=9, progress=False)
    return pmap, pmap.save(tmp_path_factory.mktemp("header") / "m.npz")


def rewrite(src: Path, dest: Path, **arrays: np.ndarray) -> Path:
    """``src`` with some arrays replaced (``meta`` given as a dict), others as they were."""
    with np.load(src, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    for key, value in arrays.items():
        data[key] = np.frombuffer(json.dumps(value).encode(), np.uint8) if key == "meta" else value
    with open(dest, "wb") as f:
        np.savez(f, **data)
    return dest


def test_header_answers_what_a_load_answers(saved: tuple[PhotonMap, Path]) -> None:
    pmap, path = saved
    header = read_header(path, expected_fingerprint=pmap.scene_fingerprint)
    full = PhotonMap.load(path)
    assert header.count == len(full) == len(pmap) > 0
    assert header.phases == full.phases and header.emitted == full.emitted
    assert header.scene_fingerprint == full.scene_fingerprint and header.scene_parts == full.scene_parts
    assert header.meta == full.meta and header.meta["seed"] == 5 and header.meta["max_bounces"] == 9


def test_header_reads_no_photon(saved: tuple[PhotonMap, Path], tmp_path: Path) -> None:
    pmap, path = saved
    nan = pmap.position.copy()
    nan[0, 0] = np.nan
    odd = rewrite(path, tmp_path / "nan.npz", position=nan)
    with pytest.raises(InputError, match="non-finite"):
        PhotonMap.load(odd)  # the load checks every photon ...
    assert read_header(odd).count == len(pmap)  # ... the header reader none


@pytest.mark.parametrize(("change", "match"), [
    ("unknown_key", "surprise"),
    ("version", "version 99"),
    ("format", "not a photon map"),
    ("stored", "'stored' is"),
    ("dtype", "'power' has dtype float64"),
    ("rows", "'phase' has 3 rows"),
    ("extra_array", "unknown array 'weights'"),
    ("fingerprint", "another scene"),
])
def test_header_refuses_what_a_load_refuses(saved: tuple[PhotonMap, Path], tmp_path: Path, change: str,
                                            match: str) -> None:
    pmap, path = saved
    meta = pmap.metadata()
    arrays: dict[str, object] = {}
    expected = None
    if change == "unknown_key":
        arrays["meta"] = {**meta, "surprise": 1}
    elif change == "version":
        arrays["meta"] = {**meta, "version": 99}
    elif change == "format":
        arrays["meta"] = {**meta, "format": "something else"}
    elif change == "stored":
        arrays["meta"] = {**meta, "stored": len(pmap) + 1}
    elif change == "dtype":
        arrays["power"] = pmap.power.astype(np.float64)
    elif change == "rows":
        arrays["phase"] = pmap.phase[:3]
    elif change == "extra_array":
        arrays["weights"] = np.zeros(3)
    else:
        expected = "0" * 64
    bad = rewrite(path, tmp_path / "bad.npz", **arrays)  # type: ignore[arg-type]
    for read in (lambda: PhotonMap.load(bad, expected_fingerprint=expected),
                 lambda: read_header(bad, expected_fingerprint=expected)):
        with pytest.raises(InputError, match=match) as info:
            read()
        assert "\n" not in str(info.value) and "bad.npz" in str(info.value)


def test_header_of_unreadable_files(tmp_path: Path, saved: tuple[PhotonMap, Path]) -> None:
    _, path = saved
    with pytest.raises(InputError, match="not found"):
        read_header(tmp_path / "missing.npz")
    cut = tmp_path / "cut.npz"
    cut.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match="cut.npz"):
        read_header(cut)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("position.npy", b"not an array")
    no_meta = tmp_path / "no_meta.npz"
    no_meta.write_bytes(buf.getvalue())
    with pytest.raises(InputError, match="no 'meta' entry"):
        read_header(no_meta)
