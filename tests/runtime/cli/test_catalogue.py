"""The bad-input catalogue: every command refuses every kind of bad input with one line and nothing written.

One table across scene files, volumes, transfer functions, lights, cameras, photon maps, bundles and the
arguments of pfn-render, pfn-train, pfn-demo, pfn-eval, pfn-view and pfn-resident. Each case builds its inputs in a
fresh folder, runs the command in-process, and checks: exit status 2, exactly one ``error: ...`` line on stderr naming
the input (``needle``), nothing on stdout that claims success, and no file written to the output folder.
Hypothesis fuzzes the two parsers users feed by hand (scene files, bundle manifests): any input either
parses or raises the one-line error type, never anything else.
"""

from __future__ import annotations

import argparse
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("torch")

from conftest import REPO, tiny_scene_dict  # noqa: E402

from photon_fields.models_spec import DEFAULT_PHASES  # noqa: E402
from photon_fields.models_spec.bundle import BundleError, validate_manifest  # noqa: E402
from photon_fields.runtime.cli.render import _main as render_main  # noqa: E402
from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.photons.photon_map import PhotonMap  # noqa: E402
from photon_fields.runtime.resident.cli import _main as resident_main  # noqa: E402
from photon_fields.runtime.scene.scene import scene_from_dict  # noqa: E402
from photon_fields.runtime.viewer.cli import _main as view_main  # noqa: E402
from photon_fields.train.cli.demo import _main as demo_main  # noqa: E402
from photon_fields.train.cli.train import _main as train_main  # noqa: E402
from photon_fields.train.eval.report import _main as eval_main  # noqa: E402

SIZE = ["--size", "8x8", "--spp", "1", "--quiet"]


@pytest.fixture(scope="module")
def assets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A scene file, its photon map, a trained run and its bundle (tiny, ~10 s)."""
    from photon_fields.train.export.bundle import export_bundle
    from photon_fields.train.fit.loop import fit
    from photon_fields.train.fit.settings import FitSettings
    from photon_fields.train.photons.tracing import trace_photons

    folder = tmp_path_factory.mktemp("assets")
    scene_file = folder / "scene.json"
    scene_file.write_text(json.dumps(tiny_scene_dict()))
    scene = scene_from_dict(tiny_scene_dict(), folder)
    pmap = trace_photons(scene, 20_000, phases=DEFAULT_PHASES, seed=1, progress=False)  # a map of a few phases
    pmap.save(folder / "map.npz")
    fit(scene, pmap, folder / "run", FitSettings.from_preset("tiny", steps=5, batch=256, val_points=256, k=32),
        progress=False)
    export_bundle(folder / "run", folder / "field.pfn", scene=scene)
    other = tiny_scene_dict()  # another light: a moved one (a power or colour edit is a rescale, not a mismatch)
    other["lights"][0]["direction"] = [0.5, -0.8, 0.3]
    (folder / "other.json").write_text(json.dumps(other))
    return {"scene": scene_file, "map": folder / "map.npz", "run": folder / "run", "bundle": folder / "field.pfn",
            "other": folder / "other.json"}


def scene_file(d: Path, **changes: object) -> str:
    """tiny_scene_dict with top-level entries replaced (None removes one), written to d/scene.json."""
    s = tiny_scene_dict()
    for k, v in changes.items():
        if v is None:
            s.pop(k, None)
        else:
            s[k] = v
    (d / "scene.json").write_text(json.dumps(s))
    return str(d / "scene.json")


def npy_scene(d: Path, arr: np.ndarray) -> str:
    np.save(d / "vol.npy", arr)
    return scene_file(d, volume={"path": "vol.npy"})


def copy_bundle(a: dict[str, Path], d: Path) -> Path:
    dst = d / "copy.pfn"
    shutil.copytree(a["bundle"], dst)
    return dst


def flip_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def newer_version(b: Path) -> Path:
    m = json.loads((b / "manifest.json").read_text())
    m["version"] = 99
    (b / "manifest.json").write_text(json.dumps(m))
    return b


def map_without_a_phase(a: dict[str, Path], d: Path) -> str:
    pmap = PhotonMap.load(a["map"])
    keep = pmap.phase != 1
    PhotonMap(pmap.position[keep], pmap.direction[keep], pmap.power[keep], pmap.phase[keep], pmap.phases,
              pmap.scene_fingerprint, pmap.emitted, pmap.meta).save(d / "holey.npz")
    return str(d / "holey.npz")


Case = tuple[str, Callable[[dict[str, Path], Path, Path], list[str]], str]
R, T, D, E, V, S = "render", "train", "demo", "eval", "view", "resident"

CASES: list[Case] = [
    # scene files
    (R, lambda a, d, o: ["--scene", str(d / "missing.json"), *SIZE, "--out", str(o / "r.exr")], "missing.json"),
    (R, lambda a, d, o: ["--scene", (d / "s.json").write_text("{") and str(d / "s.json"), *SIZE, "--out",
                         str(o / "r.exr")], "JSON"),
    (R, lambda a, d, o: ["--scene", scene_file(d, sparkle=1), *SIZE, "--out", str(o / "r.exr")], "sparkle"),
    (R, lambda a, d, o: ["--scene", scene_file(d, camera=None), *SIZE, "--out", str(o / "r.exr")], "camera"),
    (R, lambda a, d, o: ["--scene", scene_file(d, camera={"eye": [0, 0, 0], "target": [0, 0, 0]}), *SIZE,
                         "--out", str(o / "r.exr")], "camera"),
    (R, lambda a, d, o: ["--scene", scene_file(d, camera={"eye": [2, 0, 0], "target": [0, 0, 0], "fov": 0}), *SIZE,
                         "--out", str(o / "r.exr")], "fov"),
    (R, lambda a, d, o: ["--scene", scene_file(d, phase={"g": 1.5}), *SIZE, "--out", str(o / "r.exr")], "g"),
    # volumes
    (R, lambda a, d, o: ["--scene", scene_file(d, volume={"path": "nope.raw"}), *SIZE, "--out", str(o / "r.exr")],
     "nope.raw"),
    (R, lambda a, d, o: ["--scene", npy_scene(d, np.full((8, 8, 8), np.nan)), *SIZE, "--out", str(o / "r.exr")],
     "vol.npy"),
    (R, lambda a, d, o: ["--scene", npy_scene(d, np.ones((8, 8))), *SIZE, "--out", str(o / "r.exr")], "vol.npy"),
    (R, lambda a, d, o: ["--scene", npy_scene(d, np.ones((4, 4, 4), complex)), *SIZE, "--out", str(o / "r.exr")],
     "vol.npy"),
    (R, lambda a, d, o: ["--scene", (d / "vol.npy").write_bytes(b"\x93NUMPY garbage") and
                         scene_file(d, volume={"path": "vol.npy"}), *SIZE, "--out", str(o / "r.exr")], "vol.npy"),
    # transfer functions and lights
    (R, lambda a, d, o: ["--scene", scene_file(d, transfer_function={"preset": "rainbow"}), *SIZE, "--out",
                         str(o / "r.exr")], "rainbow"),
    (R, lambda a, d, o: ["--scene", scene_file(d, transfer_function={"preset": "cloud", "density_scale": -1}),
                         *SIZE, "--out", str(o / "r.exr")], "density_scale"),
    (R, lambda a, d, o: ["--scene", scene_file(d, lights=[{"type": "laser"}]), *SIZE, "--out", str(o / "r.exr")],
     "laser"),
    (R, lambda a, d, o: ["--scene", scene_file(d, lights=[]), *SIZE, "--out", str(o / "r.exr")], "lights"),
    # render arguments
    (R, lambda a, d, o: ["--spp", "0", "--out", str(o / "r.exr")], "--spp"),
    (R, lambda a, d, o: ["--size", "0x8", "--out", str(o / "r.exr")], "--size"),
    (R, lambda a, d, o: ["--g", "1.01", "--out", str(o / "r.exr")], "--g"),
    (R, lambda a, d, o: ["--out", str(o / "r.tif")], "--out"),
    # photon maps
    (R, lambda a, d, o: ["--method", "photonmap", "--out", str(o / "r.exr")], "--map"),
    (R, lambda a, d, o: ["--method", "photonmap", "--map", str(d / "none.npz"), "--scene", str(a["scene"]), *SIZE,
                         "--out", str(o / "r.exr")], "none.npz"),
    (R, lambda a, d, o: ["--method", "photonmap", "--map", (d / "bad.npz").write_bytes(b"PK junk") and
                         str(d / "bad.npz"), "--scene", str(a["scene"]), *SIZE, "--out", str(o / "r.exr")], "bad.npz"),
    (R, lambda a, d, o: ["--method", "photonmap", "--map", str(a["map"]), "--scene", str(a["other"]), *SIZE,
                         "--out", str(o / "r.exr")], "another scene"),
    (R, lambda a, d, o: ["--method", "photonmap", "--map", str(a["map"]), "--scene", str(a["scene"]), "--g", "0.3",
                         *SIZE, "--out", str(o / "r.exr")], "0.3"),
    (T, lambda a, d, o: ["fit", str(a["scene"]), "--map", map_without_a_phase(a, d), "--preset", "tiny",
                         "--out", str(o / "run")], "phase"),
    (T, lambda a, d, o: ["fit", str(a["other"]), "--map", str(a["map"]), "--out", str(o / "run")], "another scene"),
    # bundles
    (R, lambda a, d, o: ["--method", "field", "--scene", str(a["scene"]), *SIZE, "--out", str(o / "r.exr")],
     "--bundle"),
    (R, lambda a, d, o: ["--method", "raymarch-field", "--scene", str(a["scene"]), *SIZE, "--out",
                         str(o / "r.exr")], "--bundle"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(d / "none.pfn"), "--scene", str(a["scene"]), *SIZE,
                         "--out", str(o / "r.exr")], "none.pfn"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str((lambda b: (b / "field.onnx").unlink() or b)(
        copy_bundle(a, d))), "--scene", str(a["scene"]), *SIZE, "--out", str(o / "r.exr")], "field.onnx"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str((lambda b: flip_byte(b / "tables.npz") or b)(
        copy_bundle(a, d))), "--scene", str(a["scene"]), *SIZE, "--out", str(o / "r.exr")], "tables.npz"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(newer_version(copy_bundle(a, d))), "--scene",
                         str(a["scene"]), *SIZE, "--out", str(o / "r.exr")], "version"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(a["bundle"]), "--scene", str(a["other"]), *SIZE,
                         "--out", str(o / "r.exr")], "another scene"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(a["bundle"]), "--scene", str(a["scene"]),
                         "--precision", "int8", *SIZE, "--out", str(o / "r.exr")], "int8 was removed"),
    (T, lambda a, d, o: ["export", str(d / "norun"), "--out", str(o / "f.pfn")], "norun"),
    # training, demo and evaluation arguments
    (T, lambda a, d, o: ["trace", "blobs", "--photons", "lots", "--out", str(o / "m.npz")], "--photons"),
    (T, lambda a, d, o: ["trace", "blobs", "--phases", "0", "2", "--out", str(o / "m.npz")], "--phases"),
    (T, lambda a, d, o: ["fit", str(a["scene"]), "--map", str(a["map"]), "--steps", "0", "--out", str(o / "run")],
     "--steps"),
    (T, lambda a, d, o: ["fit", str(a["scene"]), "--map", str(a["map"]), "--schedule", "zigzag", "--out",
                         str(o / "run")], "--schedule"),
    (D, lambda a, d, o: ["--spp", "0", "--out", str(o / "demo")], "--spp"),
    (D, lambda a, d, o: ["--scene", "teapot", "--out", str(o / "demo")], "teapot"),
    (E, lambda a, d, o: ["--quick", "--scenes", "teapot", "--out", str(o / "docs"), "--work", str(o / "w")],
     "teapot"),
    (E, lambda a, d, o: ["--quick", "--size", "0", "--out", str(o / "docs"), "--work", str(o / "w")], "--size"),
]

# Issue 11, part 3: inputs that were wrong but accepted (or refused without naming the entry).
_TF_PTS = [{"s": 0.0, "albedo": [0.9, 0.9, 0.9], "opacity": 0.0}, {"s": 1.0, "albedo": [0.9, 0.9, 0.9], "opacity": 1.0}]


def tf_file(d: Path, tf: dict) -> str:
    (d / "tf.json").write_text(json.dumps(tf))
    return scene_file(d, transfer_function="tf.json")


def raw_scene(d: Path, sidecar: dict | None = None, **entry: object) -> str:
    (d / "vol.raw").write_bytes(bytes(range(64)))
    if sidecar is not None:
        (d / "vol.raw.json").write_text(json.dumps(sidecar))
    return scene_file(d, volume={"path": "vol.raw", **entry})


CASES += [
    (R, lambda a, d, o: ["--scene", scene_file(d, transfer_function={"preset": "cloud", "densty_scale": 80}), *SIZE,
                         "--out", str(o / "r.exr")], "scene.json transfer_function: unknown key 'densty_scale'"),
    (R, lambda a, d, o: ["--scene", tf_file(d, {"points": _TF_PTS, "densty_scale": 80}), *SIZE, "--out",
                         str(o / "r.exr")], "tf.json: unknown key 'densty_scale'"),
    (R, lambda a, d, o: ["--scene", tf_file(d, {"points": [_TF_PTS[0], {**_TF_PTS[1], "opacty": 1}]}), *SIZE,
                         "--out", str(o / "r.exr")], "tf.json points[1]: unknown key 'opacty'"),
    (R, lambda a, d, o: ["--scene", tf_file(d, {"points": [_TF_PTS[0], {"s": 1.0, "albedo": [1, 1, 1]}]}), *SIZE,
                         "--out", str(o / "r.exr")], "tf.json points[1]: missing 'opacity'"),
    (R, lambda a, d, o: ["--scene", scene_file(d, camera={"eye": [2, 0, 0], "target": [0, 0, 0], "fow": 20}), *SIZE,
                         "--out", str(o / "r.exr")], "camera: unknown key 'fow'"),
    (R, lambda a, d, o: ["--scene", raw_scene(d), *SIZE, "--out", str(o / "r.exr")],
     'vol.raw: a raw volume has no header, so its dimensions and data type must be given: add "dims"'),
    (R, lambda a, d, o: ["--scene", raw_scene(d, {"dims": [4, 4, 4], "dtype": "uint8", "spacng": [1, 1, 2]}), *SIZE,
                         "--out", str(o / "r.exr")], "vol.raw.json: unknown key 'spacng'"),
]


# Issue 17: the .vti and TIFF readers' refusals reach the command line as one line naming the file.
_VTI = ('<?xml version="1.0"?>\n<VTKFile type="{kind}" version="1.0" byte_order="LittleEndian">\n'
        '<{kind} WholeExtent="0 1 0 1 0 1" Spacing="1 1 1"><Piece Extent="0 1 0 1 0 1"><PointData>\n'
        '<DataArray type="Float32" Name="f" NumberOfComponents="{nc}" format="ascii">{values}</DataArray>\n'
        '</PointData></Piece></{kind}>\n</VTKFile>\n')


def vti_scene(d: Path, kind: str = "ImageData", nc: int = 1, n: int = 8, cut: int = 0) -> str:
    text = _VTI.format(kind=kind, nc=nc, values=" ".join(str(i) for i in range(n * nc)))
    (d / "vol.vti").write_text(text[:len(text) - cut])
    return scene_file(d, volume={"path": "vol.vti"})


def tiff_folder_scene(d: Path, shapes: list[tuple[int, int]]) -> str:
    import tifffile

    (d / "slices").mkdir()
    for i, shape in enumerate(shapes):
        tifffile.imwrite(d / "slices" / f"s{i}.tif", np.zeros(shape, np.uint8))
    return scene_file(d, volume={"path": "slices"})


CASES += [
    (R, lambda a, d, o: ["--scene", vti_scene(d, cut=30), *SIZE, "--out", str(o / "r.exr")],
     "vol.vti: not valid VTK XML"),
    (R, lambda a, d, o: ["--scene", vti_scene(d, n=7), *SIZE, "--out", str(o / "r.exr")],
     "vol.vti: array 'f': data shorter than the extent"),
    (R, lambda a, d, o: ["--scene", vti_scene(d, kind="RectilinearGrid"), *SIZE, "--out", str(o / "r.exr")],
     "vol.vti: VTK dataset type 'RectilinearGrid' is not read"),
    (R, lambda a, d, o: ["--scene", vti_scene(d, nc=3), *SIZE, "--out", str(o / "r.exr")],
     "vol.vti: array 'f' has 3 components"),
    (R, lambda a, d, o: ["--scene", tiff_folder_scene(d, [(4, 4), (4, 4), (4, 5)]), *SIZE, "--out",
                         str(o / "r.exr")], "slices: slice s2.tif is 5x4 uint8 but s0.tif is 4x4 uint8"),
    (R, lambda a, d, o: ["--scene", tiff_folder_scene(d, []), *SIZE, "--out", str(o / "r.exr")],
     "slices: folder has no .tif/.tiff slices"),
]


# Issue 17: the Zarr / OME-Zarr and DICOM readers' refusals reach the command line as one line naming the input.
def zarr_scene(d: Path, kind: str, **entry: object) -> str:
    """A Zarr store written by zarr: ``empty`` (a group without arrays), ``ome`` (a one-level OME-Zarr image
    whose c axis has ``channels`` entries), ``cut`` (an array with a truncated chunk)."""
    import zarr

    path = d / "vol.zarr"
    if kind == "cut":
        arr = zarr.create_array(path, shape=(4, 4, 4), dtype="u2", chunks=(4, 4, 4), zarr_format=2)
        arr[...] = np.arange(64).reshape(4, 4, 4)
        (path / "0.0.0").write_bytes((path / "0.0.0").read_bytes()[:5])
    else:
        group = zarr.open_group(path, mode="w")
        if kind == "ome":
            channels = int(entry.pop("channels", 1))  # type: ignore[call-overload]
            arr = group.create_array("0", shape=(channels, 4, 4, 4), dtype="u2")
            arr[...] = 1
            axes = [{"name": n, "type": "channel" if n == "c" else "space"} for n in "czyx"]
            group.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
                {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1, 1]}]}]}]}})
    return scene_file(d, volume={"path": "vol.zarr", **entry})


def dicom_scene(d: Path, kind: str) -> str:
    """A folder of 4 x 4 CT slices written by pydicom: ``mixed`` (two series), ``corrupt`` (one file is not
    DICOM), ``cut`` (one file's pixel data truncated), ``gap`` (the third of four slices missing)."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder = d / "ct"
    folder.mkdir()
    for k in range(4):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = CTImageStorage, generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta, ds.SOPClassUID, ds.SOPInstanceUID = meta, CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.SeriesInstanceUID = "1.2.3.5" if kind == "mixed" and k == 3 else "1.2.3.4"
        ds.Rows = ds.Columns = 4
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
        ds.ImagePositionPatient, ds.ImageOrientationPatient = [0, 0, 2 * k], [1, 0, 0, 0, 1, 0]
        ds.PixelSpacing = [1, 1]
        ds.PixelData = np.full(16, k, "<u2").tobytes()
        ds.save_as(folder / f"IM{k}.dcm", enforce_file_format=True)
    if kind == "corrupt":
        (folder / "IM1.dcm").write_bytes(b"not DICOM")
    elif kind == "cut":
        (folder / "IM1.dcm").write_bytes((folder / "IM1.dcm").read_bytes()[:-10])
    elif kind == "gap":
        (folder / "IM2.dcm").unlink()
    return scene_file(d, volume={"path": "ct"})


CASES += [
    (R, lambda a, d, o: ["--scene", zarr_scene(d, "empty"), *SIZE, "--out", str(o / "r.exr")],
     "vol.zarr: Zarr group without arrays and without OME-Zarr multiscales metadata"),
    (R, lambda a, d, o: ["--scene", zarr_scene(d, "ome", level=1), *SIZE, "--out", str(o / "r.exr")],
     "vol.zarr: level 1 does not exist: this OME-Zarr image has 1 resolution level"),
    (R, lambda a, d, o: ["--scene", zarr_scene(d, "ome", level="0"), *SIZE, "--out", str(o / "r.exr")],
     "vol.zarr: level must be a resolution level number"),
    (R, lambda a, d, o: ["--scene", zarr_scene(d, "ome", channels=2), *SIZE, "--out", str(o / "r.exr")],
     "vol.zarr: OME-Zarr level 0 (array '0') has 2 channels"),
    (R, lambda a, d, o: ["--scene", zarr_scene(d, "cut"), *SIZE, "--out", str(o / "r.exr")],
     "vol.zarr: Zarr array: cannot decode its chunks"),
    (R, lambda a, d, o: ["--scene", dicom_scene(d, "mixed"), *SIZE, "--out", str(o / "r.exr")],
     "ct: folder holds 2 DICOM series: 1.2.3.4 (3 files); 1.2.3.5 (1 file)"),
    (R, lambda a, d, o: ["--scene", dicom_scene(d, "corrupt"), *SIZE, "--out", str(o / "r.exr")],
     "ct: cannot read DICOM file IM1.dcm"),
    (R, lambda a, d, o: ["--scene", dicom_scene(d, "cut"), *SIZE, "--out", str(o / "r.exr")],
     "ct: cannot decode the pixels of DICOM file IM1.dcm"),
    (R, lambda a, d, o: ["--scene", dicom_scene(d, "gap"), *SIZE, "--out", str(o / "r.exr")],
     "ct: slice positions are not evenly spaced"),
]


def old_bundle(a: dict[str, Path], d: Path) -> Path:
    """The assets' bundle as a version 1 exporter wrote it: no ``scene`` entry (the manifest is not hashed)."""
    b = copy_bundle(a, d)
    m = json.loads((b / "manifest.json").read_text())
    del m["scene"]
    m["version"] = 1
    (b / "manifest.json").write_text(json.dumps(m))
    return b


def moved_volume_bundle(a: dict[str, Path], d: Path) -> Path:
    """A bundle whose recorded scene references a volume file that is no longer there."""
    b = copy_bundle(a, d)
    m = json.loads((b / "manifest.json").read_text())
    m["scene"]["spec"]["volume"] = {"path": str(d / "gone.raw"), "dims": [4, 4, 4], "dtype": "uint8"}
    (b / "manifest.json").write_text(json.dumps(m))
    return b


def run_with(a: dict[str, Path], d: Path, name: str, edit: Callable[[dict], None]) -> str:
    """A copy of the assets' run folder with a domain.json, and ``name`` (domain.json or log.json) edited."""
    from photon_fields.train.export.bundle import write_run_domain

    run = d / "run"
    shutil.copytree(a["run"], run)
    write_run_domain(run, scene_from_dict(tiny_scene_dict(), d))
    doc = json.loads((run / name).read_text())
    edit(doc)
    (run / name).write_text(json.dumps(doc))
    return str(run)


CASES += [
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(a["bundle"]), "--scene", str(a["other"]), *SIZE,
                         "--out", str(o / "r.exr")], "lights differ (volume and transfer function match)"),
    (R, lambda a, d, o: ["--method", "photonmap", "--map", str(a["map"]), "--scene", str(a["other"]), *SIZE,
                         "--out", str(o / "r.exr")], "lights differ (volume and transfer function match)"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(old_bundle(a, d)), *SIZE, "--out", str(o / "r.exr")],
     "no --scene given, so the default scene 'vortex' was used; the bundle was trained for another scene"),
    (R, lambda a, d, o: ["--method", "field", "--bundle", str(moved_volume_bundle(a, d)), *SIZE, "--out",
                         str(o / "r.exr")], "gone.raw: file not found; pass --scene"),
    (R, lambda a, d, o: ["--method", "photonmap", "--map", str(a["map"]), *SIZE, "--out", str(o / "r.exr")],
     "no --scene given, so the default scene 'vortex' was used; the map was traced for another scene"),
    (T, lambda a, d, o: ["export", run_with(a, d, "domain.json", lambda m: m.update(bsise=[1, 1, 1])), "--out",
                         str(o / "f.pfn")], "domain.json: unknown key 'bsise'"),
    (T, lambda a, d, o: ["export", run_with(a, d, "log.json", lambda m: m.update(setings={})), "--out",
                         str(o / "f.pfn")], "log.json: unknown key 'setings'"),
]



def existing(path: Path, *names: str) -> str:
    """An earlier result at ``path`` (a file, or a folder holding ``names``), for the no-overwrite cases."""
    if names:
        path.mkdir(parents=True, exist_ok=True)
        for name in names:
            (path / name).write_bytes(b"earlier")
    else:
        path.write_bytes(b"earlier")
    return str(path)


# Earlier results are not replaced without --force (their bytes are checked in tests/runtime/cli/test_no_overwrite.py).
CASES += [
    (R, lambda a, d, o: [*SIZE, "--out", existing(d / "r.json") and str(d / "r.exr")], "--force"),
    (R, lambda a, d, o: ["--exposure-from", str(d / "none.json"), *SIZE, "--out", str(o / "r.exr")],
     "--exposure-from"),
    (R, lambda a, d, o: ["--exposure", "1", "--exposure-from", str(d / "r.json"), *SIZE, "--out", str(o / "r.exr")],
     "not both"),
    (T, lambda a, d, o: ["trace", str(a["scene"]), "--photons", "3k", "--out", existing(d / "m.npz")], "--force"),
    (T, lambda a, d, o: ["fit", str(a["scene"]), "--map", str(a["map"]), "--preset", "tiny", "--out",
                         existing(d / "run", "checkpoint.pt")], "--force"),
    (T, lambda a, d, o: ["all", str(a["scene"]), "--photons", "3k", "--preset", "tiny", "--out",
                         existing(d / "run", "map.npz")], "--force"),
    (D, lambda a, d, o: ["--scene", "blobs", "--out", existing(d / "demo", "summary.json")], "--force"),
    (E, lambda a, d, o: ["--quick", "--out", existing(d / "docs", "results.md"), "--work", str(o / "w")], "--force"),
]

HUGE_SEED = str(1 << 64)


def FIELD(a: dict[str, Path]) -> list[str]:  # noqa: N802
    return ["--method", "field", "--bundle", str(a["bundle"]), "--scene", str(a["scene"])]


def PHOTONMAP(a: dict[str, Path]) -> list[str]:  # noqa: N802
    return ["--method", "photonmap", "--map", str(a["map"]), "--scene", str(a["scene"])]


def FIT(a: dict[str, Path]) -> list[str]:  # noqa: N802
    return ["fit", str(a["scene"]), "--map", str(a["map"])]


# Every option that takes a checked value, refused by name (test_catalogue_covers_every_cli_and_option).
CASES += [
    (R, lambda a, d, o: ["--method", "teleport", *SIZE, "--out", str(o / "r.exr")], "--method"),
    (R, lambda a, d, o: ["--max-depth", "0", *SIZE, "--out", str(o / "r.exr")], "--max-depth"),
    (R, lambda a, d, o: ["--method", "raymarch", "--step", "0", *SIZE, "--out", str(o / "r.exr")], "--step"),
    (R, lambda a, d, o: ["--method", "raymarch", "--max-step", "-1", *SIZE, "--out", str(o / "r.exr")],
     "--max-step"),
    (R, lambda a, d, o: ["--method", "raymarch", "--shadow-step", "0", *SIZE, "--out", str(o / "r.exr")],
     "--shadow-step"),
    (R, lambda a, d, o: ["--method", "raymarch", "--shadows", "none", *SIZE, "--out", str(o / "r.exr")],
     "--shadows"),
    (R, lambda a, d, o: ["--method", "raymarch", "--light-grid-scale", "8", *SIZE, "--out", str(o / "r.exr")],
     "--light-grid-scale"),
    (R, lambda a, d, o: ["--method", "raymarch", "--min-transmittance", "1", *SIZE, "--out", str(o / "r.exr")],
     "--min-transmittance"),
    (R, lambda a, d, o: ["--method", "raymarch", "--level", "9", *SIZE, "--out", str(o / "r.exr")], "--level"),
    (R, lambda a, d, o: [*PHOTONMAP(a), "--k", "0", *SIZE, "--out", str(o / "r.exr")], "--k"),
    (R, lambda a, d, o: [*PHOTONMAP(a), "--camera-estimator", "ratio", *SIZE, "--out", str(o / "r.exr")],
     "--camera-estimator"),
    (R, lambda a, d, o: [*PHOTONMAP(a), "--radius", "-1", *SIZE, "--out", str(o / "r.exr")], "--radius"),
    (R, lambda a, d, o: [*FIELD(a), "--light-sampling", "some", *SIZE, "--out", str(o / "r.exr")],
     "--light-sampling"),
    (R, lambda a, d, o: [*PHOTONMAP(a), "--final-gather-after", "soon", *SIZE, "--out", str(o / "r.exr")],
     "--final-gather-after"),
    (R, lambda a, d, o: [*FIELD(a), "--precision", "int4", *SIZE, "--out", str(o / "r.exr")], "--precision"),
    (R, lambda a, d, o: [*FIELD(a), "--orbit", "0", *SIZE, "--out", str(o / "r.exr")], "--orbit"),
    (R, lambda a, d, o: [*FIELD(a), "--orbit", "2", "--orbit-degrees", "nan", *SIZE, "--out", str(o / "r.exr")],
     "--orbit-degrees"),
    (R, lambda a, d, o: ["--threads", "0", *SIZE, "--out", str(o / "r.exr")], "--threads"),
    (R, lambda a, d, o: ["--batch-size", "0", *SIZE, "--out", str(o / "r.exr")], "--batch-size"),
    (R, lambda a, d, o: ["--exposure", "nan", *SIZE, "--out", str(o / "r.exr")], "--exposure"),
    (R, lambda a, d, o: ["--seed", HUGE_SEED, *SIZE, "--out", str(o / "r.exr")], "--seed"),
    (R, lambda a, d, o: ["--denoise", "wavelet", *SIZE, "--out", str(o / "r.exr")], "--denoise"),
    # OIDN denoises single images: refused with --orbit (before the pyoidn check, so on any machine).
    (R, lambda a, d, o: ["--denoise", "oidn", "--orbit", "2", *SIZE, "--out", str(o / "r.exr")], "--denoise oidn"),
    # WRLS denoises frame sequences: refused without --orbit.
    (R, lambda a, d, o: ["--denoise", "wrls", *SIZE, "--out", str(o / "r.exr")], "--denoise wrls"),
    (T, lambda a, d, o: ["trace", "blobs", "--max-bounces", "1", "--out", str(o / "m.npz")], "max_bounces"),
    (T, lambda a, d, o: ["trace", "blobs", "--threads", "0", "--out", str(o / "m.npz")], "--threads"),
    (T, lambda a, d, o: ["trace", "blobs", "--record-floor", "1", "--out", str(o / "m.npz")], "--record-floor"),
    (T, lambda a, d, o: ["all", "blobs", "--record-floor", "nan", "--out", str(o / "run")], "--record-floor"),
    (T, lambda a, d, o: ["trace", "blobs", "--seed", HUGE_SEED, "--out", str(o / "m.npz")], "--seed"),
    (T, lambda a, d, o: ["trace", "blobs", "--progress-file", str(d / "no" / "p.json"), "--out", str(o / "m.npz")],
     "--progress-file"),
    (T, lambda a, d, o: [*FIT(a), "--batch", "0", "--out", str(o / "run")], "--batch"),
    (T, lambda a, d, o: [*FIT(a), "--lr", "-1", "--out", str(o / "run")], "--lr"),
    (T, lambda a, d, o: [*FIT(a), "--k", "0", "--out", str(o / "run")], "--k"),
    (T, lambda a, d, o: [*FIT(a), "--average", "1.5", "--out", str(o / "run")], "--average"),
    (T, lambda a, d, o: [*FIT(a), "--k", "1", "--out", str(o / "run")], "--k"),
    (T, lambda a, d, o: ["update", str(a["run"]), "--scene", str(a["other"]), "--budget", "0", "--out",
                         str(o / "new")], "--budget"),
    (T, lambda a, d, o: ["update", str(a["run"]), "--scene", str(a["other"]), "--max-steps", "-1", "--out",
                         str(o / "new")], "--max-steps"),
    (T, lambda a, d, o: ["update", str(a["run"]), "--scene", str(a["other"]), "--out", str(o / "new"),
                         "--progress-file", str(d / "nope" / "p.json")], "--progress-file"),
    (T, lambda a, d, o: [*FIT(a), "--sampling", "magic", "--out", str(o / "run")], "--sampling"),
    (R, lambda a, d, o: ["--method", "pvrt", *SIZE, "--out", str(o / "r.exr")], "--transfer"),
    (R, lambda a, d, o: ["--direct", "sharp", *SIZE, "--out", str(o / "r.exr")], "--direct"),
    (R, lambda a, d, o: ["--light-grid", "2", *SIZE, "--out", str(o / "r.exr")], "--light-grid"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--basis", "srbf", "--out", str(o / "t.pvrt")], "--basis"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--order", "4", "--out", str(o / "t.pvrt")], "--order"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--grid", "1", "--out", str(o / "t.pvrt")], "--grid"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--paths", "0", "--out", str(o / "t.pvrt")], "--paths"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--exitance-order", "5", "--out", str(o / "t.pvrt")], "--exitance-order"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--exitance-order", "best", "--out", str(o / "t.pvrt")],
     "--exitance-order"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--clusters", "0", "--out", str(o / "t.pvrt")], "--clusters"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--pca-bases", "-1", "--out", str(o / "t.pvrt")], "--pca-bases"),
    (T, lambda a, d, o: ["pvrt", "blobs", "--g", "1.5", "--out", str(o / "t.pvrt")], "--g"),
    (T, lambda a, d, o: [*FIT(a), "--loss", "l1", "--out", str(o / "run")], "--loss"),
    (T, lambda a, d, o: [*FIT(a), "--lights", "some", "--out", str(o / "run")], "--lights"),
    (T, lambda a, d, o: [*FIT(a), "--g-sampling", "random", "--out", str(o / "run")], "--g-sampling"),
    # The default preset trains any g from a kernel in g: a map of a few phases is refused, naming the way out.
    (T, lambda a, d, o: [*FIT(a), "--out", str(o / "run")], "--g-sampling discrete"),
    (T, lambda a, d, o: [*FIT(a), "--checkpoint-every", "0", "--out", str(o / "run")], "--checkpoint-every"),
    (T, lambda a, d, o: [*FIT(a), "--preset", "huge", "--out", str(o / "run")], "--preset"),
    (T, lambda a, d, o: ["export", str(a["run"]), "--tables-dtype", "int8", "--out", str(o / "f.pfn")],
     "--tables-dtype"),
    (D, lambda a, d, o: ["--photons", "lots", "--out", str(o / "demo")], "--photons"),
    (D, lambda a, d, o: ["--preset", "huge", "--out", str(o / "demo")], "--preset"),
    (D, lambda a, d, o: ["--steps", "0", "--out", str(o / "demo")], "--steps"),
    (D, lambda a, d, o: ["--size", "0x10", "--out", str(o / "demo")], "--size"),
    (D, lambda a, d, o: ["--reference-spp", "0", "--out", str(o / "demo")], "--reference-spp"),
    (D, lambda a, d, o: ["--threads", "0", "--out", str(o / "demo")], "--threads"),
    (D, lambda a, d, o: ["--seed", HUGE_SEED, "--out", str(o / "demo")], "--seed"),
    (E, lambda a, d, o: ["--quick", "--spp", "0", "--out", str(o / "docs"), "--work", str(o / "w")], "--spp"),
    (E, lambda a, d, o: ["--quick", "--threads", "0", "--out", str(o / "docs"), "--work", str(o / "w")],
     "--threads"),
    (E, lambda a, d, o: ["--quick", "--seed", HUGE_SEED, "--out", str(o / "docs"), "--work", str(o / "w")],
     "--seed"),
]

# pfn-view (runtime/viewer/cli.py): refused before anything is served or written.
VIEW = ["--no-browser", "--size", "16x16"]
CASES += [
    (V, lambda a, d, o: [str(d / "missing.json"), *VIEW, "--out", str(o / "shots")], "missing.json"),
    (V, lambda a, d, o: [*VIEW, "--out", str(o / "shots")], "SCENE"),
    (V, lambda a, d, o: [str(a["other"]), "--bundle", str(a["bundle"]), *VIEW, "--out", str(o / "shots")],
     "another scene"),
    (V, lambda a, d, o: [str(a["scene"]), "--bundle", str(d / "none.pfn"), *VIEW, "--out", str(o / "shots")],
     "none.pfn"),
    (V, lambda a, d, o: [str(a["other"]), "--map", str(a["map"]), *VIEW, "--out", str(o / "shots")], "another scene"),
    (V, lambda a, d, o: [str(a["scene"]), "--transfer", str(d / "none.pvrt"), *VIEW, "--out", str(o / "shots")],
     "transfer"),
    (V, lambda a, d, o: [str(a["scene"]), *VIEW, "--out", (d / "f").write_text("x") and str(d / "f")], "--out"),
    (V, lambda a, d, o: [str(a["scene"]), "--renderer", "neural", *VIEW, "--out", str(o / "shots")], "--renderer"),
    (V, lambda a, d, o: [str(a["scene"]), "--direct", "blurred", *VIEW, "--out", str(o / "shots")], "--direct"),
    (V, lambda a, d, o: [str(a["scene"]), "--camera-estimator", "ratio", *VIEW, "--out", str(o / "shots")],
     "--camera-estimator"),
    (V, lambda a, d, o: [str(a["scene"]), "--light-grid", "2", *VIEW, "--out", str(o / "shots")], "--light-grid"),
    (V, lambda a, d, o: [str(a["scene"]), "--host", "999.1.1.1", *VIEW, "--out", str(o / "shots")], "--host"),
    (V, lambda a, d, o: [str(a["scene"]), "--port", "65536", *VIEW, "--out", str(o / "shots")], "--port"),
    (V, lambda a, d, o: [str(a["scene"]), "--no-browser", "--size", "9x9", "--out", str(o / "shots")], "--size"),
    (V, lambda a, d, o: [str(a["scene"]), "--seed", HUGE_SEED, *VIEW, "--out", str(o / "shots")], "--seed"),
    (V, lambda a, d, o: [str(a["scene"]), "--max-spp", "0", *VIEW, "--out", str(o / "shots")], "--max-spp"),
    (V, lambda a, d, o: [str(a["scene"]), "--threads", "0", *VIEW, "--out", str(o / "shots")], "--threads"),
    (V, lambda a, d, o: [str(a["scene"]), "--drag-scale", "0.1", *VIEW, "--out", str(o / "shots")], "--drag-scale"),
    (V, lambda a, d, o: [str(a["scene"]), "--interactive-level", "6", *VIEW, "--out", str(o / "shots")],
     "--interactive-level"),
    (V, lambda a, d, o: [str(a["scene"]), "--retrain-photons", "1.5", *VIEW, "--out", str(o / "shots")],
     "--retrain-photons"),
    (V, lambda a, d, o: [str(a["scene"]), "--final-gather-after", "later", *VIEW, "--out", str(o / "shots")],
     "--final-gather-after"),
    # pfn-resident: refused before any folder is made or any server started
    (S, lambda a, d, o: ["start", "--idle-minutes", "0"], "--idle-minutes"),
    (S, lambda a, d, o: ["start", "--idle-minutes", "inf"], "--idle-minutes"),
    (S, lambda a, d, o: ["start", "--idle-minutes", "soon"], "--idle-minutes"),
    (S, lambda a, d, o: ["start", "--ready-fd", "1"], "--ready-fd"),
    (S, lambda a, d, o: ["restart"], "COMMAND"),
]

MAINS = {R: render_main, T: train_main, D: demo_main, E: eval_main, V: view_main, S: resident_main}
#: Options whose refusals name the offending value (a file, folder or scene name), not the option: their
#: cases are the scene-file, volume, photon-map, bundle and run-folder sections above.
NAMED_BY_VALUE = {"--scene", "--map", "--bundle", "--out", "--work", "--scenes"}


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Long names of the options that take a value, subcommands included."""
    out: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out |= _value_options(sub)
        elif action.option_strings and action.nargs != 0:
            out.add(action.option_strings[-1])
    return out


def test_catalogue_covers_every_cli_and_option() -> None:
    """Every console script the package installs (pyproject.toml [project.scripts]) is a catalogued command,
    and every option of every command that takes a value has a case refusing a bad value by the option's name
    (or is named by value). A new command or option without a refusal case fails here."""
    import importlib
    from importlib import metadata

    from photon_fields.runtime.cli.render import build_parser as render_parser
    from photon_fields.runtime.resident.cli import build_parser as resident_parser
    from photon_fields.runtime.viewer.cli import build_parser as view_parser
    from photon_fields.train.cli.demo import build_parser as demo_parser
    from photon_fields.train.cli.train import build_parser as train_parser
    from photon_fields.train.eval.report import build_parser as eval_parser

    scripts = metadata.distribution("photon-fields").entry_points.select(group="console_scripts")
    assert len(scripts) >= len(MAINS)
    for script in scripts:
        module = importlib.import_module(script.module)
        assert any(module._main is m for m in MAINS.values()), f"{script.name} ({script.value}) has no cases"
    parsers = {R: render_parser(), T: train_parser(), D: demo_parser(), E: eval_parser(), V: view_parser(),
               S: resident_parser()}
    for cli, parser in parsers.items():
        needles = {c[2].lstrip("-").replace("_", "-") for c in CASES if c[0] == cli}
        missing = sorted(opt for opt in _value_options(parser) - NAMED_BY_VALUE if opt.lstrip("-") not in needles)
        assert not missing, f"{cli}: no case refuses a bad value of {missing}"


@pytest.mark.parametrize(("cli", "build", "needle"), CASES, ids=[f"{i:02d}-{c[0]}-{c[2]}" for i, c in enumerate(CASES)])
def test_bad_input_one_line_nothing_written(assets: dict[str, Path], tmp_path: Path, cli: str,
                                            build: Callable[..., list[str]], needle: str,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    inputs, out = tmp_path / "in", tmp_path / "out"
    inputs.mkdir()
    argv = build(assets, inputs, out)
    capsys.readouterr()
    assert MAINS[cli](argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in captured.err, captured.err
    assert needle in lines[0], lines[0]
    written = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file()) if out.exists() else []
    assert written == [], written


# ----------------------------------------------------------------------------------------------------------
# Fuzzing the hand-written inputs: scene files and bundle manifests

JSON = st.recursive(st.none() | st.booleans() | st.integers(-10, 10) | st.floats(allow_nan=True) | st.text(max_size=8),
                    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=8), kids, max_size=4),
                    max_leaves=12)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(["volume", "transfer_function", "lights", "camera", "phase", "name", "extra"]), value=JSON)
def test_fuzz_scene_entries(tmp_path: Path, key: str, value: object) -> None:
    d = tiny_scene_dict()
    d[key] = value
    try:
        scene_from_dict(d, tmp_path, "fuzz.json")
    except InputError as err:
        assert "\n" not in str(err) and str(err)


@pytest.fixture(scope="module")
def manifest_doc(assets: dict[str, Path]) -> dict:
    return json.loads((assets["bundle"] / "manifest.json").read_text())


def _paths(doc: object, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), value=JSON)
def test_fuzz_manifest_fields(manifest_doc: dict, data: st.DataObject, value: object) -> None:
    doc = json.loads(json.dumps(manifest_doc))
    path = data.draw(st.sampled_from([p for p in _paths(doc) if p]))
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    try:
        validate_manifest(doc)
    except BundleError as err:
        assert "\n" not in str(err) and str(err)


# ----------------------------------------------------------------------------------------------------------
# Killed midway


def test_killed_render_leaves_earlier_outputs_intact(tmp_path: Path) -> None:
    """SIGKILL a long --force render that would overwrite earlier outputs: they stay byte for byte."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "r.exr"
    old = {s: f"old {s}".encode() for s in (".exr", ".png", ".json")}
    for s, data in old.items():
        out.with_suffix(s).write_bytes(data)
    cmd = [sys.executable, "-c", "from photon_fields.runtime.cli.render import main; main()", "--scene", "blobs",
           "--size", "256x256",
           "--spp", "4096", "--quiet", "--force", "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(REPO)})
    time.sleep(4.0)
    assert proc.poll() is None, "the render finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    for s, data in old.items():
        assert out.with_suffix(s).read_bytes() == data
