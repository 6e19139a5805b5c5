"""Issue 11: a photon map or bundle used for another scene names what differs (volume, transfer function,
lights, each separately), refused or forced; files without per-part fingerprints say the parts cannot be
compared; the scene's part fingerprints are recorded by tracing and export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import tiny_scene_dict

from photon_fields.models_spec.fingerprint import (
    FINGERPRINT_PARTS,
    fingerprint_parts,
    mismatch_detail,
    scene_fingerprint,
)
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.estimate import check_map_matches_scene
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.scene.scene import Scene, scene_from_dict

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
        # A moved light. The case, another power only (L_i 40 % too dark when forced), is now a rescale for
        # a field (tests/runtime/field/test_light_rescale.py) and still a mismatch for a photon map.
        d["lights"][0]["direction"] = [0.5, -0.8, 0.3]
    if "tf" in kind or kind == "all":
        d["transfer_function"] = {"preset": "cloud", "density_scale": 60}
    if kind in ("volume", "all"):
        d["volume"]["resolution"] = 20
    d["camera"]["fov"] = 25  # camera and g never count (variant("none") is the same light distribution)
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
    assert "cannot be told: the file records no per-part fingerprints" in mismatch_detail(a, None)
    assert "not compared part by part" in mismatch_detail(None, a)  # a caller that passed no parts


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
    from photon_fields.train.photons.tracing import trace_photons

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


# ----------------------------------------------------------------------------------------------------------
# Bundles: the manifest records the parts and the scene; loads name what differs; pfn-render without --scene

torch = pytest.importorskip("torch")

from conftest import make_model, make_run, small_field_config  # noqa: E402

SMALL = small_field_config()

from photon_fields.runtime.cli.render import _main as render_main  # noqa: E402
from photon_fields.runtime.field.bundle_reader import scene_for_bundle  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.train.export.bundle import export_bundle, write_run_domain  # noqa: E402

RENDER = ["--size", "8x8", "--spp", "1", "--quiet"]


@pytest.fixture(scope="module")
def bundle(base: Scene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small field 'trained' for ``base`` (random weights: the scene bookkeeping is what is tested)."""
    folder = tmp_path_factory.mktemp("bundle")
    run = make_run(folder / "run", make_model(SMALL), [0.0] * 3, [1.0] * 3, fp=base.fingerprint())
    return export_bundle(run, folder / "field.pfn", scene=base).path


def manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def as_version_1(src: Path, dst: Path) -> Path:
    """The same bundle as an older exporter wrote it (no ``scene``; the manifest is not checksummed)."""
    import shutil

    shutil.copytree(src, dst)
    doc = manifest(dst)
    del doc["scene"]
    doc["version"] = 1
    (dst / "manifest.json").write_text(json.dumps(doc))
    return dst


def test_export_records_the_scene(base: Scene, bundle: Path) -> None:
    rec = manifest(bundle)["scene"]
    assert rec["name"] == base.name and rec["parts"] == base.fingerprint_parts() and rec["spec"] == base.spec()


def test_export_from_the_run_folder_records_the_scene(base: Scene, tmp_path: Path) -> None:
    """``pfn-train fit`` writes domain.json (version 2: parts and spec); the export reads them back. A version 1
    domain.json still exports, with the scene's parts and spec unknown."""
    run = make_run(tmp_path / "run", make_model(SMALL), [0.0] * 3, [1.0] * 3, fp=base.fingerprint())
    write_run_domain(run, base, "somewhere/scene.json")
    rec = export_bundle(run, tmp_path / "a.pfn", verify=False).manifest["scene"]
    assert rec == {"name": base.name, "parts": base.fingerprint_parts(), "spec": base.spec()}
    make_run(run, make_model(SMALL), [0.0] * 3, [1.0] * 3, fp=base.fingerprint())  # a version 1 domain.json
    rec = export_bundle(run, tmp_path / "b.pfn", verify=False).manifest["scene"]
    assert rec == {"name": "test", "parts": None, "spec": None}


@pytest.mark.parametrize("kind", list(VARIANTS))
def test_bundle_mismatch_names_what_differs(bundle: Path, kind: str) -> None:
    other = variant(kind)
    kw = {"expected_fingerprint": other.fingerprint(), "expected_parts": other.fingerprint_parts()}
    with pytest.raises(InputError) as err:
        PhotonField.load(bundle, **kw)
    msg = str(err.value)
    assert msg.startswith(f"{bundle}: was trained for another scene ('blobs32'): {VARIANTS[kind]}; "), msg
    field = PhotonField.load(bundle, force=True, **kw)
    assert field.scene_warning == f"{bundle} was trained for another scene ('blobs32'): {VARIANTS[kind]}; " \
                                  "L_i will be wrong"
    assert field.describe()["scene_warning"] == field.scene_warning
    assert PhotonField.load(bundle, expected_fingerprint=variant("none").fingerprint()).scene_warning is None


def test_version_1_bundle_loads_and_says_parts_cannot_be_compared(bundle: Path, tmp_path: Path) -> None:
    old = as_version_1(bundle, tmp_path / "old.pfn")
    other = variant("lights")
    with pytest.raises(InputError, match=r"another scene: volume, transfer function or lights differ \(which cannot "
                                         r"be told: the file records no per-part fingerprints\)"):
        PhotonField.load(old, expected_fingerprint=other.fingerprint(), expected_parts=other.fingerprint_parts())
    assert PhotonField.load(old).manifest.scene is None


def _render(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], dict | None]:
    capsys.readouterr()
    code = render_main(argv)
    err = capsys.readouterr().err.splitlines()
    out = Path(argv[argv.index("--out") + 1]).with_suffix(".json")
    return code, err, json.loads(out.read_text()) if out.exists() else None


def test_render_without_scene_uses_the_scene_the_bundle_records(base: Scene, bundle: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    code, err, report = _render(["--method", "field", "--bundle", str(bundle), *RENDER, "--out",
                                 str(tmp_path / "r.exr")], capsys)
    assert code == 0 and err == [], err
    assert report["scene"] == base.name and report["scene_from"] == "bundle" and report["warnings"] == []
    assert report["scene_description"]["volume"]["fingerprint"] == base.volume.fingerprint()
    assert scene_for_bundle(bundle)[0].fingerprint() == base.fingerprint()


def test_final_gather_reaches_the_field_renderer_and_its_report(bundle: Path, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    from photon_fields.runtime.io.images import read_exr

    images = {}
    for flags in (["--final-gather-after", "never"], ["--final-gather-after", "0"]):
        out = tmp_path / f"r{flags[1]}.exr"
        code, err, report = _render(["--method", "field", "--bundle", str(bundle), *RENDER, *flags, "--out",
                                     str(out)], capsys)
        assert code == 0 and err == [], err
        gathers = flags[1] == "0"
        assert report["options"] == {"camera": "auto", "light_sampling": "one",
                                     "final_gather_after": 0 if gathers else None}
        assert report["stats"]["camera_estimator"] in ("forced", "marched")  # what auto chose
        images[gathers] = read_exr(out)[0]
    np.testing.assert_array_equal(images[False]["L_d"], images[True]["L_d"])
    assert not np.array_equal(images[False]["L_i"], images[True]["L_i"])


def test_render_without_scene_of_an_old_bundle_says_which_scene_was_used(bundle: Path, tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    old = as_version_1(bundle, tmp_path / "old.pfn")
    code, err, report = _render(["--method", "field", "--bundle", str(old), *RENDER, "--out",
                                 str(tmp_path / "r.exr")], capsys)
    assert code == 2 and report is None and len(err) == 1, err
    assert err[0].startswith(f"error: {old}: no --scene given, so the default scene 'vortex' was used; the bundle "
                             "was trained for another scene: "), err
    assert err[0].endswith("; pass --scene"), err


@pytest.mark.parametrize("kind", ["lights", "tf", "volume"])
def test_forced_render_warns_naming_what_differs(base: Scene, bundle: Path, tmp_path: Path, kind: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's case: another light, forced, rendered a wrong L_i (40 % too dark after a power edit) with nothing
    said."""
    other = variant(kind)
    scene_file = tmp_path / "other.json"
    scene_file.write_text(json.dumps(other.spec()))
    pmap_path = fake_map(base).save(tmp_path / "m.npz")
    for method, source, verb in (("field", ["--bundle", str(bundle)], "trained for"),
                                 ("photonmap", ["--map", str(pmap_path), "--radius", "0.5", "--k", "8"],
                                  "traced for")):
        argv = ["--method", method, *source, "--scene", str(scene_file), "--g", "0", *RENDER, "--out",
                str(tmp_path / f"{method}.exr")]
        code, err, report = _render(argv, capsys)
        assert code == 2 and len(err) == 1 and VARIANTS[kind] in err[0] and "force" in err[0], err
        code, err, report = _render([*argv, "--force"], capsys)
        assert code == 0 and len(err) == 1, err
        assert err[0].startswith(f"warning: {source[1]} was {verb} another scene") and \
            err[0].endswith(f": {VARIANTS[kind]}; L_i will be wrong"), err
        assert report["warnings"] == [err[0][len("warning: "):]]


def test_checkpoint_domain_and_log_are_strict(base: Scene, tmp_path: Path) -> None:
    run = make_run(tmp_path / "run", make_model(SMALL), [0.0] * 3, [1.0] * 3, fp=base.fingerprint())
    write_run_domain(run, base)
    dom = json.loads((run / "domain.json").read_text())
    (run / "domain.json").write_text(json.dumps({**dom, "bsise": [1, 1, 1]}))
    with pytest.raises(InputError, match=r"domain.json: unknown key 'bsise' \(did you mean 'bsize'\?\)"):
        export_bundle(run, tmp_path / "x.pfn", verify=False)
    (run / "domain.json").write_text(json.dumps({**dom, "scene_parts": {"volume": "1" * 64}}))
    with pytest.raises(InputError, match="domain.json scene.parts.transfer_function: missing"):
        export_bundle(run, tmp_path / "x.pfn", verify=False)
    (run / "domain.json").write_text(json.dumps(dom))
    log = json.loads((run / "log.json").read_text())
    (run / "log.json").write_text(json.dumps({**log, "setings": {}}))
    with pytest.raises(InputError, match=r"log.json: unknown key 'setings' \(did you mean 'settings'\?\)"):
        export_bundle(run, tmp_path / "x.pfn", verify=False)
    (run / "log.json").write_text(json.dumps({**log, "settings": {"preset": "tiny", "batch": "512"}}))
    with pytest.raises(InputError, match="log.json settings batch: must be a positive integer"):
        export_bundle(run, tmp_path / "x.pfn", verify=False)
    (run / "log.json").write_text(json.dumps(log))
    data = torch.load(run / "checkpoint.pt", weights_only=True)
    torch.save({**data, "stepp": 3}, run / "checkpoint.pt")
    with pytest.raises(InputError, match=r"checkpoint.pt: unknown key 'stepp' \(did you mean 'step'\?\)"):
        export_bundle(run, tmp_path / "x.pfn", verify=False)
    del data["field_config"]
    torch.save(data, run / "checkpoint.pt")
    with pytest.raises(InputError, match="checkpoint.pt: missing 'field_config'"):
        export_bundle(run, tmp_path / "x.pfn", verify=False)
    assert not list(tmp_path.glob("*.pfn"))
