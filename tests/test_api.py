"""The five-line Python API (api/, the package ``photon_fields``): the README's example runs as written (with
a small size and spp), ``method="field"`` trains once into a cache and then reads it, volumes come as arrays,
paths or ImageData look-alikes, the image saves without replacing, and bad input is one line."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO

import photon_fields as pf
from photon_fields.runtime.scene.auto_transfer import auto_transfer_function
from photon_fields.runtime.scene.scene import builtin_volume
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.volumes import as_volume

#: What the README example becomes in a test: seconds, not minutes (only these arguments change).
SMALL = "spp=2, size=(24, 20)"
TINY_TRAINING = {"preset": "tiny", "photons": "20k", "steps": 3, "batch": 256, "k": 16, "threads": 1}


def readme_example() -> str:
    text = (REPO / "README.md").read_text()
    section = text[text.index("### Python API in five lines"):]
    block = re.search(r"```python\n(.*?)```", section, flags=re.S)
    assert block is not None
    code = block.group(1)
    assert len([ln for ln in code.splitlines() if ln.strip()]) <= 5
    return code


def _head_file(folder: Path) -> None:
    import nrrd

    nrrd.write(str(folder / "head.nrrd"), builtin_volume("head", 24).data)


def _run(code: str, folder: Path, monkeypatch: pytest.MonkeyPatch) -> dict:
    monkeypatch.chdir(folder)
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)  # noqa: S102
    return namespace


def test_readme_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    code = readme_example()
    assert 'method="field"' in code and "spp=16" in code
    _head_file(tmp_path)
    small = code.replace('method="field"', 'method="pt"').replace("spp=16", SMALL)
    img = _run(small, tmp_path, monkeypatch)["img"]
    assert {p.name for p in tmp_path.iterdir()} == {"head.nrrd", "head.exr", "head.png"}
    assert img.shape == (20, 24) and set(img.layers) >= {"L", "L_d", "L_i", "L_e"}
    assert np.allclose(img.L, img.L_e + img.L_d + img.L_i, atol=1e-5)
    assert img.L_d.mean() > 0 and img.L_i.mean() > 0  # lit, with multiple scattering
    volume = make_volume(np.asarray(__import__("nrrd").read(str(tmp_path / "head.nrrd"), index_order="F")[0]))
    assert img.info["transfer_function"] == auto_transfer_function(volume).to_dict()
    png = img._repr_png_()
    assert png.startswith(b"\x89PNG")
    with pytest.raises(pf.InputError, match="head.exr: exists; pass force=True"):
        img.save(tmp_path / "head.exr")
    assert img.save(tmp_path / "head.png", force=True)[0] == tmp_path / "head.exr"


def test_readme_example_with_a_field_trains_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The example as written (method "field") with a tiny training into a fresh cache; a second call with the
    same scene reads the cache: no trainer is started, the image is the same."""
    _head_file(tmp_path)
    cache = tmp_path / "cache"
    code = readme_example().replace("spp=16", f"spp=1, size=(16, 16), training={TINY_TRAINING!r}, cache={str(cache)!r}")
    img = _run(code, tmp_path, monkeypatch)["img"]
    entries = list((cache / "fields").iterdir())
    assert len(entries) == 1 and (entries[0] / "run" / "field.pfn").is_dir() and (entries[0] / "complete").exists()
    assert img.info["method"] == "field" and np.all(np.isfinite(img.L)) and img.L_i.mean() > 0

    def no_training(*args: object, **kwargs: object) -> None:
        raise AssertionError("trained again")

    monkeypatch.setattr("photon_fields.field_cache.subprocess.run", no_training)
    again = pf.render(tmp_path / "head.nrrd", method="field", spp=1, size=(16, 16), training=TINY_TRAINING,
                      cache=cache)
    assert np.array_equal(again.L, img.L)
    # the preview with the field's L_i reads the same cached field (no training) and has L_i too
    marched = pf.render(tmp_path / "head.nrrd", method="raymarch-field", spp=1, size=(16, 16), training=TINY_TRAINING,
                        cache=cache)
    assert marched.info["method"] == "raymarch-field" and marched.L_i.mean() > 0 and np.all(np.isfinite(marched.L))
    # the camera estimator by its command-line name (render's own ``camera`` is the view): the same field, another
    # estimator of the same image, so another image of the same mean
    thin = pf.render(tmp_path / "head.nrrd", method="field", spp=1, size=(16, 16), training=TINY_TRAINING,
                     cache=cache, camera_estimator="marched")
    assert thin.info["options"] == {"camera_estimator": "marched"} and not np.array_equal(thin.L, img.L)
    # what the default (auto) used: forced for a 16x16 frame (fewer samples than a probe); the estimator named
    assert (img.info["stats"]["camera_estimator"], thin.info["stats"]["camera_estimator"]) == ("forced", "marched")
    assert np.all(np.isfinite(thin.L)) and thin.L_i.mean() > 0
    with pytest.raises(pf.InputError, match="^camera_estimator"):
        pf.render(tmp_path / "head.nrrd", method="field", spp=1, size=(16, 16), training=TINY_TRAINING, cache=cache,
                  camera_estimator="ratio")
    # the same lights twice as bright (and bluer): the field renders them exactly, rescaled, without training
    from photon_fields.runtime.scene.rigs import light_rig

    relit = [{**light.to_dict(), "power": light.power * 2.0, "color": (light.color * [1.0, 1.0, 1.5]).tolist()}
             for light in light_rig("studio")]
    brighter = pf.render(tmp_path / "head.nrrd", lights=relit, method="field", spp=1, size=(16, 16),
                         training=TINY_TRAINING, cache=cache)
    np.testing.assert_allclose(brighter.L_i, img.L_i * [2.0, 2.0, 3.0], rtol=1e-5, atol=1e-7)
    assert len(list((cache / "fields").iterdir())) == 1
    # one light of the rig twice as bright, then the others: the field keeps the lights apart (the default), so
    # each is a rescale of its own part, and the two images' L_i add up to three times the rig's (linearity)
    rig = [light.to_dict() for light in light_rig("studio")]
    first = [{**rig[0], "power": 2.0 * rig[0]["power"]}, *rig[1:]]
    others = [rig[0], *({**lt, "power": 2.0 * lt["power"]} for lt in rig[1:])]
    a, b = (pf.render(tmp_path / "head.nrrd", lights=lights, method="field", spp=1, size=(16, 16),
                      training=TINY_TRAINING, cache=cache) for lights in (first, others))
    np.testing.assert_allclose(a.L_i + b.L_i, 3.0 * img.L_i, rtol=1e-5, atol=1e-7)
    assert not np.allclose(a.L_i, b.L_i, rtol=1e-3) and len(list((cache / "fields").iterdir())) == 1
    # another light rig is another scene: it would train (refused here by the stand-in)
    with pytest.raises(AssertionError, match="trained again"):
        pf.render(tmp_path / "head.nrrd", lights="sun", method="field", spp=1, size=(16, 16),
                  training=TINY_TRAINING, cache=cache)


def test_field_without_torch_names_the_train_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr("photon_fields.field_cache.importlib.util.find_spec",
                        lambda name, *a: None if name == "torch" else real(name, *a))
    with pytest.raises(pf.InputError, match=r"^method 'field': .*train extra.*photon-fields\[train\]"):
        pf.render(np.random.default_rng(0).random((8, 8, 8)), method="field", cache=tmp_path)
    assert not (tmp_path / "fields").exists()


class FakeArrays(dict):
    active_scalars_name = "density"


class FakeImageData:
    """What photon_fields reads of a pyvista.ImageData: dimensions, spacing, point and cell data."""

    def __init__(self, data: np.ndarray, spacing: tuple[float, float, float]) -> None:
        self.dimensions = data.shape
        self.spacing = spacing
        self.point_data = FakeArrays(other=np.zeros(data.size), density=data.ravel(order="F"))
        self.cell_data = FakeArrays()


def test_volumes_from_arrays_paths_and_image_data(tmp_path: Path) -> None:
    data = np.random.default_rng(2).random((5, 6, 7))
    from_array, source = as_volume(data)
    assert source is None and np.array_equal(from_array.data, make_volume(data).data)
    grid, _ = as_volume(FakeImageData(data, (1.0, 2.0, 0.5)))
    assert np.array_equal(grid.data, from_array.data) and grid.spacing == (1.0, 2.0, 0.5)
    np.save(tmp_path / "v.npy", data)
    from_path, source = as_volume(str(tmp_path / "v.npy"), spacing=(1, 2, 0.5))
    assert source == {"path": str(tmp_path / "v.npy"), "spacing": [1.0, 2.0, 0.5]}
    assert from_path.fingerprint() == grid.fingerprint()


def test_the_default_camera_frames_the_volume() -> None:
    """Every corner of the volume's box projects inside the image, for a flat volume and a portrait image."""
    from photon_fields.runtime.scene.rigs import framing_camera

    volume = make_volume(np.zeros((40, 10, 25)), spacing=(1, 1, 2))
    for width, height in ((64, 64), (40, 80), (80, 40)):
        cam = framing_camera(volume, width, height)
        right, up, forward = cam.basis()
        half = np.tan(np.radians(cam.fov / 2))
        half_x, half_y = (half, half * height / width) if cam.fov_axis == "x" else (half * width / height, half)
        corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]) - 0.5
        for c in corners * volume.extent:
            d = c - cam.eye
            depth = d @ forward
            assert depth > 0
            assert abs(d @ right) / depth < half_x and abs(d @ up) / depth < half_y, (width, height)


@pytest.mark.parametrize(("volume", "kwargs", "message"), [
    (np.zeros((4, 4)), {}, "volume: must be a 3-D array indexed [x, y, z], got 2-D"),
    (np.full((3, 3, 3), "a"), {}, "volume: must hold real numbers, got dtype <U1"),
    ("no_such_volume.npy", {}, "no_such_volume.npy: file not found"),
    ({"a": 1}, {}, "volume: expected a 3-D numpy array, a volume file path or a pyvista.ImageData, got dict"),
    (None, {"method": "magic"},
     "method: unknown method 'magic' (available: pt, raymarch, raymarch-field, photonmap, field, pvrt)"),
    (None, {"method": "pvrt", "training": {"grid": 4, "gird": 4}}, "training: unknown key 'gird'"),
    (None, {"lights": "disco"}, "lights: unknown light rig 'disco' (available: studio, sun, sky)"),
    (None, {"transfer_function": "nope"}, "transfer_function: unknown preset 'nope' and not a .json file"),
    (None, {"transfer_function": "missing.json"}, "missing.json: file not found"),
    (None, {"max_depth": 0}, "max_depth: must be an integer in [1, 65536], got 0"),
    (None, {"k": 4}, "k: not an option of method 'pt'"),
    (None, {"size": (0, 8)}, "size: width and height must be integers in [1, 16384]"),
    (None, {"method": "field", "training": {"steps": 3, "stpes": 4}}, "training: unknown key 'stpes'"),
])
def test_bad_input_is_one_line(volume: object, kwargs: dict, message: str, tmp_path: Path,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    if volume is None:
        volume = np.random.default_rng(0).random((6, 6, 6))
    with pytest.raises(pf.InputError) as err:
        pf.render(volume, **{"spp": 1, "size": (4, 4), "cache": tmp_path, **kwargs})
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_import_is_cheap() -> None:
    """``import photon_fields`` loads neither numba, onnxruntime nor torch; ``pf.render`` is found on use."""
    code = ("import sys, photon_fields as pf; heavy = [m for m in ('numba', 'onnxruntime', 'torch') "
            "if m in sys.modules]; print(heavy, callable(pf.render))")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "[] True"


def test_info_is_json(tmp_path: Path) -> None:
    img = pf.render(np.random.default_rng(0).random((6, 6, 6)), method="raymarch", spp=1, size=(8, 8),
                    transfer_function="grey_ramp", lights="sky", step=1.0)
    assert json.loads(json.dumps(img.info))["options"] == {"step": 1.0}
    assert [lt["type"] for lt in img.info["lights"]] == ["directional", "environment"]


def test_label_volume_with_the_labels_preset(tmp_path: Path) -> None:
    """``transfer_function="labels"``: an integer array renders with each label its own colour (the info records
    the concrete label function); a label function on a scalar volume is one line."""
    a = np.zeros((8, 8, 8), dtype=np.uint8)
    a[2:4, 2:6, 2:6], a[4:6, 2:6, 2:6] = 3, 7
    img = pf.render(a, transfer_function="labels", method="raymarch", spp=1, size=(8, 8))
    assert set(img.info["transfer_function"]["labels"]) == {"0", "3", "7"}
    assert img.L.max() > 0
    with pytest.raises(pf.InputError, match="^transfer_function: volume 'volume' is not a label volume"):
        pf.render(np.random.default_rng(0).random((6, 6, 6)), transfer_function="labels", spp=1, size=(4, 4))


def test_pvrt_precomputes_once_and_relights(tmp_path: Path) -> None:
    """``method="pvrt"``: a transfer precomputed on first use and cached by volume, transfer function and g (not
    the lights: another light reuses it); a point light is refused in one line."""
    vol = np.random.default_rng(0).random((8, 8, 8))
    tiny = {"grid": 4, "order": 0, "paths": 200, "clusters": 2}
    kwargs = {"method": "pvrt", "spp": 1, "size": (8, 8), "cache": tmp_path, "training": tiny, "g": 0.2}
    img = pf.render(vol, lights="sun", **kwargs)
    assert img.L_i.mean() > 0 and img.L_d.mean() > 0
    files = list(tmp_path.glob("fields/*/transfer.pvrt"))
    assert len(files) == 1
    stamp = files[0].stat().st_mtime_ns
    pf.render(vol, lights="sky", **kwargs)  # another light: the same transfer
    assert list(tmp_path.glob("fields/*/transfer.pvrt")) == files and files[0].stat().st_mtime_ns == stamp
    with pytest.raises(pf.InputError, match="^light 1: a point light is local"):
        pf.render(vol, lights="studio", **kwargs)


def test_a_pvrt_transfer_made_under_other_defaults_is_not_reused(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The cache key holds the defaults that fill what ``training`` leaves out (here the CPCA bases): a transfer
    cached under older defaults is made again, not handed back as today's."""
    from photon_fields.runtime.pvrt import constants

    vol = np.random.default_rng(0).random((8, 8, 8))
    kwargs = {"method": "pvrt", "spp": 1, "size": (8, 8), "cache": tmp_path, "lights": "sun",
              "training": {"grid": 4, "order": 0, "paths": 200, "clusters": 2}}
    pf.render(vol, **kwargs)
    monkeypatch.setattr(constants, "DEFAULT_PCA_BASES", constants.DEFAULT_PCA_BASES + 1)
    pf.render(vol, **kwargs)
    assert len(list(tmp_path.glob("fields/*/transfer.pvrt"))) == 2
