"""The bundle end to end (issue: the product's promise): export a torch field, load it in the runtime, and
get the same function; every damaged or foreign bundle is refused in one line; the runtime runs without
torch; ``pfn-train export`` / ``all`` write bundles atomically and reproducibly.

Fields here are small but not trivial: hashed and dense levels in both encodings, 2-4 features, 3 hidden
layers, and hash tables randomized to trained magnitudes (uniform in [-1, 1], not the 1e-4 init), so a
wrong column, corner, level order or weight transpose shows up as an O(0.1) difference on L'.
"""

from __future__ import annotations

import dataclasses
import json
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import zipfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from conftest import FP, PHASES, REPO, make_model, make_run, small_field_config  # noqa: E402

torch = pytest.importorskip("torch")
SMALL = small_field_config()

import onnx  # noqa: E402

from photon_fields.models_spec.bundle import BUNDLE_VERSION, file_digest  # noqa: E402
from photon_fields.models_spec.encoding import FieldConfig, direction_input, normalize_position  # noqa: E402
from photon_fields.models_spec.hashgrid import level_specs  # noqa: E402
from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.field.field import FieldEstimator, PhotonField  # noqa: E402
from photon_fields.train.cli.train import _main  # noqa: E402
from photon_fields.train.export.bundle import export_bundle, mlp_onnx, mlp_weights, write_tables_npz  # noqa: E402
from photon_fields.train.field.network import TorchPhotonField as TorchField  # noqa: E402
from photon_fields.train.field.network import decode_radiance_torch  # noqa: E402
from photon_fields.train.fit.presets import PRESETS, field_config_for  # noqa: E402


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> tuple[TorchField, Path, Path]:
    """A SMALL model in the unit box (normalized = world coordinates) and its exported bundle."""
    model = make_model(SMALL)
    run = make_run(tmp_path_factory.mktemp("small") / "run", model, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    res = export_bundle(run)
    assert res.path == run / "field.pfn" and res.verify_max_abs_diff <= 1e-5
    return model, run, res.path


@pytest.fixture
def bundle_copy(small: tuple, tmp_path: Path) -> Path:
    dst = tmp_path / "copy.pfn"
    shutil.copytree(small[2], dst)
    return dst


def torch_reference(model: TorchField, x: np.ndarray, d: np.ndarray, g: np.ndarray, bmin, bsize) -> np.ndarray:
    with torch.no_grad():
        return model(torch.from_numpy(normalize_position(x, bmin, bsize)), torch.from_numpy(direction_input(d)),
                     torch.from_numpy(np.asarray(g, np.float32).reshape(-1, 1))).numpy()


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def edge_inputs(cfg: FieldConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions at 0 and 1 and on grid vertices of every level, directions at the poles and on the seam,
    g at -1, 0, 1, G and between."""
    pts = [np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], np.float64)]  # box corners
    pts.append(np.array([[0, 0.5, 1], [1, 0.25, 0], [0.5, 0.5, 0.5], [0, 0, 0.999999]]))
    for s in level_specs(cfg.position):
        # Vertex k of a level sits where scale * x + 0.5 = k: x = (k - 0.5) / scale.
        k = rng.integers(1, max(2, int(s.scale)), size=(6, 3))
        pts.append(np.clip((k - 0.5) / float(s.scale), 0.0, 1.0))
    x = np.concatenate(pts)
    n = len(x)
    d = unit(rng.standard_normal((n, 3)))
    specials = np.array([[0, 0, 1], [0, 0, -1], [-1, 0.0, 0], [-1, -0.0, 0], [-1, 1e-9, 0], [-1, -1e-9, 0],
                         [1, 0, 0], [0, 1, 0], [0, -1, 0], [0.6, 0, 0.8], [-0.6, 0, -0.8]], np.float64)
    d[:len(specials)] = unit(specials)
    gs = np.array([-1.0, 0.0, 1.0, *PHASES, -0.35, 0.35, 0.5, -0.9])
    g = np.resize(gs, n)
    return x, d, g


# --------------------------------------------------------------------------------------------------
# Parity: runtime (numba + onnxruntime) == torch model


def test_parity_random_and_edge_inputs(small: tuple) -> None:
    model, _, path = small
    field = PhotonField.load(path, chunk=1000)  # several chunks, the last one partial
    rng = np.random.default_rng(1)
    xr = rng.random((5000, 3))
    dr = unit(rng.standard_normal((5000, 3)))
    gr = rng.uniform(-1, 1, 5000)
    xe, de, ge = edge_inputs(SMALL, rng)
    x, d, g = np.concatenate([xr, xe]), np.concatenate([dr, de]), np.concatenate([gr, ge])
    want = torch_reference(model, x, d, g, np.zeros(3), np.ones(3))
    assert np.abs(want).max() > 0.1  # realistic magnitudes: a wrong mapping cannot hide below the tolerance
    got = field.query_encoded(x, d, g)
    assert got.dtype == np.float32 and got.shape == (len(x), 3)
    assert np.abs(got - want).max() <= 1e-5
    L = field.query(x, d, g)
    L_ref = decode_radiance_torch(torch.from_numpy(want), SMALL.psi).numpy().astype(np.float64)
    assert L.dtype == np.float32
    assert np.max(np.abs(L - L_ref) / np.maximum(np.abs(L_ref), 1e-30)) <= 1e-4
    # The MLP input itself: features exactly as the torch encodings produce them, g in the last column.
    feats = field.encode_inputs(xe, de, ge)
    with torch.no_grad():
        tp = model.position(torch.from_numpy(normalize_position(xe, np.zeros(3), np.ones(3)))).numpy()
        td = model.direction(torch.from_numpy(direction_input(de))).numpy()
    np.testing.assert_array_equal(feats[:, :tp.shape[1]], tp)
    np.testing.assert_array_equal(feats[:, tp.shape[1]:-1], td)
    np.testing.assert_array_equal(feats[:, -1], ge.astype(np.float32))


def test_parity_cpu_preset_in_a_non_unit_box(tmp_path: Path) -> None:
    """The default architecture, world positions in a shifted, non-cubic box (normalization from the manifest), a
    surface grid of a non-cubic volume (its axes in order)."""
    cfg = field_config_for(PRESETS["cpu"], PHASES, volume_shape=(12, 7, 9))
    assert cfg.surface == (12, 7, 9)
    model = make_model(cfg, seed=3)
    bmin, bsize = [-0.5, -0.3, -0.45], [1.0, 0.6, 0.9]
    run = make_run(tmp_path / "run", model, bmin, bsize)
    field = PhotonField.load(export_bundle(run, tmp_path / "cpu.pfn").path, threads=1)
    rng = np.random.default_rng(4)
    x = np.asarray(bmin) + rng.random((4000, 3)) * np.asarray(bsize)
    x[:8] = np.asarray(bmin) + np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)]) * np.asarray(bsize)
    d = unit(rng.standard_normal((4000, 3)))
    g = 0.35  # a scalar g, not in G
    want = torch_reference(model, x, d, np.full(4000, g), bmin, bsize)
    assert np.abs(field.query_encoded(x, d, g) - want).max() <= 1e-5


@pytest.mark.parametrize(("preset", "encoding"), [("cpu-tent", "tent"), ("cpu", "spline")])
def test_parity_phase_features(tmp_path: Path, preset: str, encoding: str) -> None:
    """The tent and the spline architectures (g plus one tent, or cubic B-spline weight, per phase as MLP inputs):
    the runtime builds the same input columns as torch, at the phases, between them, beyond them, one g per query
    and one g for all."""
    cfg = field_config_for(PRESETS[preset], PHASES, volume_shape=(5, 6, 7))
    assert cfg.phase_encoding == encoding
    assert cfg.input_dims == field_config_for(PRESETS["cpu-phases"], PHASES).input_dims + 3 + cfg.surface_dims
    model = make_model(cfg, seed=5)
    bmin, bsize = [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]
    run = make_run(tmp_path / "run", model, bmin, bsize)
    field = PhotonField.load(export_bundle(run, tmp_path / f"{encoding}.pfn").path, threads=1)
    assert field.config.phase_encoding == encoding
    rng = np.random.default_rng(6)
    x, d = rng.random((3000, 3)), unit(rng.standard_normal((3000, 3)))
    g = rng.choice([*PHASES, -0.6, -0.1, 0.35, 0.9, -1.0], 3000)
    assert np.abs(field.query_encoded(x, d, g) - torch_reference(model, x, d, g, bmin, bsize)).max() <= 1e-5
    want = torch_reference(model, x, d, np.full(3000, 0.35), bmin, bsize)
    assert np.abs(field.query_encoded(x, d, 0.35) - want).max() <= 1e-5
    # the tents matter: a scalar-g runtime reading the same weights would be another function
    assert np.abs(field.query_encoded(x, d, 0.35) - field.query_encoded(x, d, 0.0)).max() > 1e-3


def test_direction_gain_makes_the_field_isotropic_at_g_zero(tmp_path: Path) -> None:
    """``direction_gain`` "g" (the cpu preset's): the direction features enter times g, so the exported field gives
    the same L' for every direction at g = 0 (the light is isotropic there) and the torch model agrees; the same
    weights without the gain, or at g != 0, depend on the direction. (The runtime ignoring the gain fails the parity;
    the torch model ignoring it fails the isotropy of the torch side.)"""
    cfg = dataclasses.replace(SMALL, direction_gain="g")
    model = make_model(cfg, seed=9)
    run = make_run(tmp_path / "run", model, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    path = export_bundle(run, tmp_path / "gain.pfn").path
    assert json.loads((path / "manifest.json").read_text())["field"]["direction_gain"] == "g"
    field = PhotonField.load(path, threads=1)
    rng = np.random.default_rng(10)
    x = rng.random((2000, 3))
    d1, d2 = unit(rng.standard_normal((2000, 3))), unit(rng.standard_normal((2000, 3)))
    g = rng.uniform(-1.0, 1.0, 2000)
    want = torch_reference(model, x, d1, g, np.zeros(3), np.ones(3))
    assert np.abs(field.query_encoded(x, d1, g) - want).max() <= 1e-5
    np.testing.assert_array_equal(field.query_encoded(x, d1, 0.0), field.query_encoded(x, d2, 0.0))
    zero = np.zeros(2000)
    np.testing.assert_array_equal(torch_reference(model, x, d1, zero, np.zeros(3), np.ones(3)),
                                  torch_reference(model, x, d2, zero, np.zeros(3), np.ones(3)))
    assert np.abs(field.query_encoded(x, d1, 0.5) - field.query_encoded(x, d2, 0.5)).max() > 1e-2
    plain = TorchField(SMALL, seed=0)
    plain.load_state_dict(model.state_dict())
    assert np.abs(torch_reference(plain, x, d1, zero, np.zeros(3), np.ones(3))
                  - torch_reference(plain, x, d2, zero, np.zeros(3), np.ones(3))).max() > 1e-2


@pytest.mark.parametrize("psi", [3.0, 7.0])
def test_bundle_decodes_with_its_own_psi(tmp_path: Path, psi: float) -> None:
    """A field trained with psi != 5 (Eq. 6/7's decades) decodes with the bundle's psi, not the default:
    the runtime's radiance equals the torch model's decoded radiance and Eq. 7 written out with that psi.
    (Decoding with psi = 5 instead is off by a factor 10^(L' (5 - psi)): up to ~100x here.)"""
    cfg = dataclasses.replace(SMALL, psi=psi)
    model = make_model(cfg, seed=6)
    path = export_bundle(make_run(tmp_path / "run", model, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])).path
    assert json.loads((path / "manifest.json").read_text())["field"]["psi"] == psi
    field = PhotonField.load(path)
    rng = np.random.default_rng(7)
    x, d, g = rng.random((3000, 3)), unit(rng.standard_normal((3000, 3))), rng.uniform(-1, 1, 3000)
    Lp = torch_reference(model, x, d, g, np.zeros(3), np.ones(3)).astype(np.float64)
    with torch.no_grad():
        torch_L = model.radiance(torch.from_numpy(normalize_position(x, np.zeros(3), np.ones(3))),
                                 torch.from_numpy(direction_input(d)),
                                 torch.from_numpy(g.astype(np.float32).reshape(-1, 1))).numpy().astype(np.float64)
    eq7 = 10.0 ** (-Lp * psi)
    got = field.query(x, d, g).astype(np.float64)
    # L' within 1e-5 (the parity bound) is a relative radiance error of ln(10) psi 1e-5 <= 1.7e-4.
    assert np.max(np.abs(got / torch_L - 1.0)) <= 2e-4
    assert np.max(np.abs(got / eq7 - 1.0)) <= 2e-4
    assert np.max(np.abs(np.log10(eq7) - np.log10(10.0 ** (-Lp * 5.0)))) > 0.5  # the default psi would be caught


def test_fit_records_its_psi_and_the_bundle_decodes_with_it(tmp_path: Path) -> None:
    """psi from the fit settings reaches the checkpoint and the manifest (a tiny fit, a few steps)."""
    from conftest import tiny_scene_dict

    from photon_fields.runtime.scene.scene import scene_from_dict
    from photon_fields.train.fit.loop import fit
    from photon_fields.train.fit.settings import FitSettings
    from photon_fields.train.photons.tracing import trace_photons

    scene = scene_from_dict(tiny_scene_dict(), tmp_path)
    pmap = trace_photons(scene, 20_000, seed=1, progress=False)
    settings = FitSettings.from_preset("tiny", steps=3, batch=256, val_points=256, k=32)
    settings.psi = 3.5
    fit(scene, pmap, tmp_path / "run", settings, progress=False)
    field = PhotonField.load(export_bundle(tmp_path / "run", tmp_path / "f.pfn", scene=scene).path)
    assert field.config.psi == 3.5
    x = np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 0.3]])
    d = unit(np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 0.0]]))
    Lp = field.query_encoded(x, d, 0.0).astype(np.float64)
    np.testing.assert_allclose(field.query(x, d, 0.0), 10.0 ** (-Lp * 3.5), rtol=1e-5)


def test_float16_tables_equal_the_rounded_torch_model(small: tuple, tmp_path: Path) -> None:
    model, run, path32 = small
    res = export_bundle(run, tmp_path / "half.pfn", tables_dtype="float16")
    assert res.manifest["tables"]["dtype"] == "float16"
    assert res.files["tables.npz"] < 0.6 * (path32 / "tables.npz").stat().st_size
    field = PhotonField.load(res.path)
    rounded = make_model(SMALL)
    with torch.no_grad():
        for t in rounded.table_parameters():
            t.copy_(t.half().float())
    rng = np.random.default_rng(5)
    x, d, g = rng.random((3000, 3)), unit(rng.standard_normal((3000, 3))), rng.uniform(-1, 1, 3000)
    got = field.query_encoded(x, d, g)
    assert np.abs(got - torch_reference(rounded, x, d, g, np.zeros(3), np.ones(3))).max() <= 1e-5
    # Against the float32 model, the rounding of the tables (2^-11 relative) is the documented ~1e-3 bound.
    assert np.abs(got - torch_reference(model, x, d, g, np.zeros(3), np.ones(3))).max() <= 2e-3


def test_pipelined_and_chunked_queries_equal_one_call(small: tuple) -> None:
    _, _, path = small
    rng = np.random.default_rng(9)
    x, d, g = rng.random((2500, 3)), unit(rng.standard_normal((2500, 3))), rng.uniform(-1, 1, 2500)
    want = PhotonField.load(path, chunk=1 << 14).query_encoded(x, d, g)
    for kw in ({"chunk": 300}, {"chunk": 300, "pipeline": True, "threads": 1}, {"chunk": 1000, "pipeline": True}):
        field = PhotonField.load(path, **kw)
        np.testing.assert_array_equal(field.query_encoded(x, d, g), want)
        np.testing.assert_array_equal(field.query_encoded(x[:700], d[:700], g[:700]), want[:700])  # buffers reused
    bad = x.copy()
    bad[2000] = np.nan  # an error in a late chunk: the in-flight inference is waited for, the field stays usable
    with pytest.raises(InputError, match="finite"):
        field.query(bad, d, g)
    np.testing.assert_array_equal(field.query_encoded(x, d, g), want)


def test_a_frames_phase_columns_are_kept_only_while_they_hold_its_g(small: tuple) -> None:
    """A rendered frame queries with one g: its phase-feature row is computed once and a reused encode buffer keeps
    its phase columns while they hold that g's row for every row the chunk uses. Any other g, or more rows than
    were written, writes them again: the same results as fresh fields, through g changes, shorter and longer
    chunks, per-query g in between, and the pipelined buffers."""
    _, _, path = small
    rng = np.random.default_rng(4)
    x, d = rng.random((900, 3)), unit(rng.standard_normal((900, 3)))
    mixed = rng.uniform(-1, 1, 900)
    steps = [(-0.5, 700), (0.3, 100), (0.3, 700), (0.3, 250), (None, 900), (0.3, 250), (-0.5, 250), (0.3, 900),
             (0.75, 80)]
    for kw in ({"chunk": 300}, {"chunk": 300, "pipeline": True}):
        field = PhotonField.load(path, **kw)
        for g, n in steps:
            gv = mixed[:n] if g is None else g
            want = PhotonField.load(path).query_encoded(x[:n], d[:n], gv)
            np.testing.assert_array_equal(field.query_encoded(x[:n], d[:n], gv), want, err_msg=f"{kw} {g} {n}")


def test_a_frames_gain_in_the_direction_encoder_equals_the_per_query_product(tmp_path: Path) -> None:
    """With one g for every query (a frame) the direction encoder stores its features times the gain; with per-query
    g the rows are multiplied afterwards (finish_rows). The two give the same MLP inputs bit for bit: queries at one
    g against the same queries among ones at another g (``direction_gain`` "g", the cpu preset's)."""
    model = make_model(dataclasses.replace(SMALL, direction_gain="g"), seed=3)
    field = PhotonField.load(export_bundle(make_run(tmp_path / "run", model, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
                                           tmp_path / "gain.pfn").path)
    rng = np.random.default_rng(6)
    x, d = rng.random((500, 3)), unit(rng.standard_normal((500, 3)))
    cols = slice(field.config.position.output_dims, field.config.position.output_dims
                 + field.config.direction.output_dims)
    for g in (0.37, -0.6, 0.0):
        frame = field.encode_inputs(x, d, g)
        per_query = np.full(500, g)
        per_query[-1] = 0.9  # one other g: the per-query path
        np.testing.assert_array_equal(frame[:-1], field.encode_inputs(x, d, per_query)[:-1], err_msg=str(g))
        np.testing.assert_array_equal(frame[:, cols], np.float32(g) * field.encode_inputs(x, d, 1.0)[:, cols])


def test_int8_precision_is_refused_in_one_line(small: tuple) -> None:
    """int8 was removed (its accuracy depended on the CPU's VNNI, runtime/field/field.py): asking for it names
    the option and the reason, in the API and in the CLI."""
    _, _, path = small
    with pytest.raises(InputError, match="int8 was removed"):
        PhotonField.load(path, precision="int8")


def test_estimator_timers_and_inputs(small: tuple) -> None:
    _, _, path = small
    field = PhotonField.load(path, threads=1, chunk=256)
    rng = np.random.default_rng(7)
    x, d = rng.random((3, 700)), unit(rng.standard_normal((700, 3))).T.copy()
    est = field.estimator()
    assert isinstance(est, FieldEstimator)
    q = est(x, d, 0.0)
    assert q.shape == (3, 700) and q.flags.c_contiguous
    np.testing.assert_array_equal(q, field.query(x.T, d.T, np.zeros(700)).T)
    t = field.timers
    assert t.queries == 1400 and t.calls == 2
    assert min(t.encode_position_s, t.encode_direction_s, t.inference_s, t.decode_s) > 0
    assert t.total_s == pytest.approx(sum(v for k, v in t.to_dict().items() if k.endswith("_s") and k != "total_s"))
    t.reset()
    assert t.queries == 0 and t.total_s == 0
    assert field.query(np.zeros((0, 3)), np.zeros((0, 3)), 0.0).shape == (0, 3)
    for args, match in [((np.zeros((4, 2)), np.zeros((4, 3)), 0.0), "query x"),
                        ((np.zeros((4, 3)), np.zeros((3, 3)), 0.0), "query omega"),
                        ((np.zeros((4, 3)), np.ones((4, 3)), np.zeros(3)), "query g"),
                        ((np.zeros((4, 3)), np.ones((4, 3)), np.nan), "query g"),
                        ((np.full((4, 3), np.nan), np.ones((4, 3)), 0.0), "query: x must be finite")]:
        with pytest.raises(InputError, match=match):
            field.query(*args)
    for kw, match in [({"precision": "fp16"}, "precision"), ({"threads": 0}, "threads"), ({"chunk": 0}, "chunk")]:
        with pytest.raises(InputError, match=match):
            PhotonField.load(path, **kw)


def test_runtime_loads_and_queries_without_torch(small: tuple, tmp_path: Path) -> None:
    model, _, path = small
    rng = np.random.default_rng(8)
    x, d, g = rng.random((500, 3)), unit(rng.standard_normal((500, 3))), rng.uniform(-1, 1, 500)
    np.savez(tmp_path / "q.npz", x=x, d=d, g=g, want=torch_reference(model, x, d, g, np.zeros(3), np.ones(3)))
    code = (
        "import sys\n"
        "sys.modules['torch'] = None  # any 'import torch' now raises ImportError\n"
        "import numpy as np\n"
        "import photon_fields.runtime.cli.render\n"
        "from photon_fields.runtime.field.field import PhotonField\n"
        f"q = np.load({str(tmp_path / 'q.npz')!r})\n"
        f"f = PhotonField.load({str(path)!r}, threads=1)\n"
        "got = f.query_encoded(q['x'], q['d'], q['g'])\n"
        "assert np.abs(got - q['want']).max() <= 1e-5, np.abs(got - q['want']).max()\n"
        "L = f.estimator()(q['x'].T.copy(), q['d'].T.copy(), 0.5)\n"
        "assert L.shape == (3, 500) and np.all(np.isfinite(L))\n"
        "assert sys.modules['torch'] is None and 'train' not in sys.modules\n"
        "print('ok')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         cwd=REPO)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == "ok"


# --------------------------------------------------------------------------------------------------
# Export: layout, determinism, atomicity


def test_export_is_deterministic_and_self_contained(small: tuple, tmp_path: Path) -> None:
    _, run, path = small
    again = export_bundle(run, tmp_path / "again.pfn").path
    for name in ("manifest.json", "field.onnx", "tables.npz"):
        assert (again / name).read_bytes() == (path / name).read_bytes(), name
    assert sorted(p.name for p in path.iterdir()) == ["field.onnx", "manifest.json", "tables.npz"]
    man = json.loads((path / "manifest.json").read_text())
    assert man["training"] == {"preset": "tiny", "steps": 40, "batch": 512, "final_loss": 0.05,
                               "validation": {"val_loss": 0.06}, "wall_s": 12.5}
    assert man["scene_fingerprint"] == FP and man["domain"] == {"bmin": [0.0] * 3, "bsize": [1.0] * 3}
    model = onnx.load(str(path / "field.onnx"))
    assert [n.op_type for n in model.graph.node] == ["MatMul", "Relu"] * 3 + ["MatMul"]
    dims = model.graph.input[0].type.tensor_type.shape.dim
    assert dims[0].dim_param == "batch" and dims[1].dim_value == SMALL.input_dims
    with np.load(path / "tables.npz", allow_pickle=False) as z:
        assert sorted(z.files) == ["direction", "position"] and z["position"].dtype == np.float32


def test_export_refuses_to_overwrite_and_replaces_with_force(small: tuple, tmp_path: Path) -> None:
    _, run, _ = small
    out = tmp_path / "f.pfn"
    export_bundle(run, out, verify=False)
    stamp = (out / "manifest.json").stat().st_mtime_ns
    with pytest.raises(InputError, match="exists; pass --force"):
        export_bundle(run, out)
    assert (out / "manifest.json").stat().st_mtime_ns == stamp
    export_bundle(run, out, force=True, tables_dtype="float16")
    assert json.loads((out / "manifest.json").read_text())["tables"]["dtype"] == "float16"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.pfn"]  # no staging or .old leftovers
    foreign = tmp_path / "notes.pfn"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    with pytest.raises(InputError, match="is not a bundle"):
        export_bundle(run, foreign, force=True)
    assert (foreign / "thesis.tex").read_text() == "precious"


def test_interrupted_export_leaves_the_previous_bundle_intact(small: tuple, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    _, run, _ = small
    out = tmp_path / "f.pfn"
    export_bundle(run, out, verify=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def interrupted(path, arrays):  # noqa: ANN001, ANN202
        Path(path).write_bytes(b"PK partial")
        raise KeyboardInterrupt

    monkeypatch.setattr("photon_fields.train.export.bundle.write_tables_npz", interrupted)
    with pytest.raises(KeyboardInterrupt):
        export_bundle(run, out, force=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.pfn"]
    PhotonField.load(out)


@pytest.mark.parametrize("case", ["missing run", "run is a file", "no checkpoint", "corrupt checkpoint", "no domain",
                                  "foreign domain", "bad out", "bad dtype"])
def test_export_bad_inputs(small: tuple, tmp_path: Path, case: str) -> None:
    _, run, _ = small
    if case == "missing run":
        args, match = (tmp_path / "nope",), "run folder not found"
    elif case == "run is a file":
        (tmp_path / "file").write_text("x")
        args, match = (tmp_path / "file",), "is not a folder"
    elif case == "no checkpoint":
        (tmp_path / "empty").mkdir()
        args, match = (tmp_path / "empty",), "no checkpoint.pt"
    elif case == "corrupt checkpoint":
        r = tmp_path / "r"
        shutil.copytree(run, r, ignore=shutil.ignore_patterns("field.pfn"))
        (r / "checkpoint.pt").write_bytes((r / "checkpoint.pt").read_bytes()[:200])
        args, match = (r,), "not a readable checkpoint"
    elif case == "foreign domain":
        r = tmp_path / "r"
        shutil.copytree(run, r, ignore=shutil.ignore_patterns("field.pfn"))
        dom = json.loads((r / "domain.json").read_text())
        (r / "domain.json").write_text(json.dumps({**dom, "scene_fingerprint": "0" * 64}))
        args, match = (r,), "another scene"
    elif case == "no domain":
        r = tmp_path / "r"
        shutil.copytree(run, r, ignore=shutil.ignore_patterns("domain.json", "field.pfn"))
        args, match = (r,), "no domain.json"
    elif case == "bad out":
        args, match = (run, tmp_path / "bundle.zip"), "NAME.pfn"
    else:
        args, match = (run, tmp_path / "x.pfn"), "--tables-dtype"
    kw = {"tables_dtype": "int4"} if case == "bad dtype" else {}
    with pytest.raises(InputError, match=match) as err:
        export_bundle(*args, **kw)
    assert "\n" not in str(err.value)
    assert not list(tmp_path.rglob("*.pfn")) and not list(tmp_path.rglob(".*.tmp"))  # nothing written


def test_cli_export_one_line_errors_and_success(small: tuple, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    _, run, _ = small
    for argv, match in [(["export", str(tmp_path / "nope")], "run folder not found"),
                        (["export", str(tmp_path)], "no checkpoint.pt"),
                        (["export", str(run)], "exists; pass --force"),
                        (["export", str(run), "--tables-dtype", "int8"], "--tables-dtype")]:
        assert _main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and match in err and "\n" not in err, err
    out = tmp_path / "cli.pfn"
    assert _main(["export", str(run), "--out", str(out)]) == 0
    assert "exported" in capsys.readouterr().out
    PhotonField.load(out, expected_fingerprint=FP)


def test_cli_all_ends_with_a_bundle(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    scene = {"name": "blobs24", "volume": {"builtin": "blobs", "resolution": 24},
             "transfer_function": {"preset": "cloud"},
             "lights": [{"type": "directional", "direction": [-0.5, -0.8, 0.3], "color": [1, 1, 1], "power": 3.0}],
             "camera": {"eye": [1.2, 0.7, 1.4], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 38, "width": 16,
                        "height": 16}}
    scene_file = tmp_path / "blobs24.json"
    scene_file.write_text(json.dumps(scene))
    out = tmp_path / "run"
    argv = ["all", str(scene_file), "--photons", "20k", "--out", str(out), "--preset", "tiny", "--steps", "3",
            "--batch", "256", "--k", "16", "--quiet", "--threads", "1"]
    assert _main(argv) == 0
    assert "exported" in capsys.readouterr().out
    from photon_fields.runtime.scene.scene import load_scene

    sc = load_scene(str(scene_file))
    field = PhotonField.load(out / "field.pfn", expected_fingerprint=sc.fingerprint())
    assert np.allclose(field.bmin, sc.medium().bmin) and np.allclose(field.bsize, sc.medium().bsize)
    assert field.manifest.training["steps"] == 3 and field.manifest.training["preset"] == "tiny"
    # The exported bundle can be re-exported from the run folder alone (domain.json).
    assert _main(["export", str(out), "--out", str(tmp_path / "again.pfn")]) == 0


# --------------------------------------------------------------------------------------------------
# Refusals: every damaged or foreign bundle, one line


def refused(path: Path, match: str, **kw: object) -> str:
    with pytest.raises(InputError) as err:
        PhotonField.load(path, **kw)
    msg = str(err.value)
    assert "\n" not in msg and match in msg, msg
    return msg


def rewrite(bundle: Path, name: str, data: bytes) -> None:
    """Replace a payload file and update its manifest entry, so the check behind the checksum is reached."""
    (bundle / name).write_bytes(data)
    man = json.loads((bundle / "manifest.json").read_text())
    digest, size = file_digest(bundle / name)
    man["files"][name] = {"sha256": digest, "bytes": size}
    (bundle / "manifest.json").write_text(json.dumps(man))


def edit_manifest(bundle: Path, fn) -> None:  # noqa: ANN001
    man = json.loads((bundle / "manifest.json").read_text())
    fn(man)
    (bundle / "manifest.json").write_text(json.dumps(man))


@pytest.mark.parametrize("name", ["manifest.json", "field.onnx", "tables.npz"])
def test_each_file_missing(bundle_copy: Path, name: str) -> None:
    (bundle_copy / name).unlink()
    msg = refused(bundle_copy, "missing")
    assert name in msg


@pytest.mark.parametrize("name", ["field.onnx", "tables.npz"])
def test_each_file_corrupted_or_truncated(bundle_copy: Path, name: str) -> None:
    data = bytearray((bundle_copy / name).read_bytes())
    data[len(data) // 2] ^= 0x01
    (bundle_copy / name).write_bytes(bytes(data))
    refused(bundle_copy, "checksum mismatch")
    (bundle_copy / name).write_bytes(bytes(data[: len(data) // 2]))
    refused(bundle_copy, "truncated")


def test_manifest_corrupted_truncated_or_from_another_version(bundle_copy: Path) -> None:
    text = (bundle_copy / "manifest.json").read_text()
    (bundle_copy / "manifest.json").write_text(text[: len(text) // 2])
    refused(bundle_copy, "not valid JSON")
    (bundle_copy / "manifest.json").write_text(text.replace(f'"version": {BUNDLE_VERSION},',
                                                            f'"version": {BUNDLE_VERSION + 1},', 1))
    refused(bundle_copy, "newer than this build reads")
    (bundle_copy / "manifest.json").write_text(text.replace('"levels": 6', '"levels": "6"', 1))
    refused(bundle_copy, "field.position.levels: must be an integer")
    (bundle_copy / "manifest.json").write_text(text.replace("photon-fields/field-bundle", "something/else"))
    refused(bundle_copy, "not a photon-field bundle")


def test_path_problems(bundle_copy: Path, tmp_path: Path) -> None:
    refused(tmp_path / "absent.pfn", "bundle not found")
    refused(bundle_copy / "field.onnx", "is a file")
    (bundle_copy / "manifest.json").write_bytes(b" " * (2 << 20))
    refused(bundle_copy, "a manifest is at most")


def test_fingerprint_mismatch_unless_forced(bundle_copy: Path) -> None:
    refused(bundle_copy, "another scene", expected_fingerprint="0" * 64)
    assert PhotonField.load(bundle_copy, expected_fingerprint="0" * 64, force=True).scene_fingerprint == FP
    assert PhotonField.load(bundle_copy, expected_fingerprint=FP).scene_fingerprint == FP


def _npz_bytes(tmp: Path, **arrays: np.ndarray) -> bytes:
    path = tmp / "t.npz"
    write_tables_npz(path, arrays)
    return path.read_bytes()


def test_table_shape_dtype_and_values(bundle_copy: Path, tmp_path: Path) -> None:
    with np.load(bundle_copy / "tables.npz") as z:
        pos, dirs = z["position"], z["direction"]
    rewrite(bundle_copy, "tables.npz", _npz_bytes(tmp_path, position=pos[:-8], direction=dirs))
    refused(bundle_copy, "'position' has shape")
    rewrite(bundle_copy, "tables.npz", _npz_bytes(tmp_path, position=pos, direction=dirs[:, :2]))
    refused(bundle_copy, "'direction' has shape")
    rewrite(bundle_copy, "tables.npz", _npz_bytes(tmp_path, position=pos.astype(np.float64), direction=dirs))
    refused(bundle_copy, "dtype float64")
    bad = pos.copy()
    bad[3, 1] = np.inf
    rewrite(bundle_copy, "tables.npz", _npz_bytes(tmp_path, position=bad, direction=dirs))
    refused(bundle_copy, "non-finite")
    rewrite(bundle_copy, "tables.npz", _npz_bytes(tmp_path, position=pos, direction=dirs, extra=pos[:1]))
    refused(bundle_copy, "must hold exactly the arrays")
    rewrite(bundle_copy, "tables.npz", b"not a zip at all")
    refused(bundle_copy, "not an .npz archive")
    # A manifest whose table shape disagrees with its own field config is refused before any file is read.
    edit_manifest(bundle_copy, lambda m: m["tables"]["arrays"]["position"].update(shape=[8, 2]))
    refused(bundle_copy, "tables.arrays.position.shape")


def test_a_surface_bundles_grid_is_checked_like_its_tables(tmp_path: Path) -> None:
    """A field with the surface input carries its int8 grid, listed in the manifest exactly when the field has it;
    missing, reshaped, re-typed or unlisted, the bundle is refused in one line."""
    cfg = dataclasses.replace(SMALL, surface=(5, 4, 3))
    run = make_run(tmp_path / "run", make_model(cfg, seed=2), [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    path = export_bundle(run, tmp_path / "surface.pfn").path
    man = json.loads((path / "manifest.json").read_text())
    assert man["tables"]["arrays"]["surface"]["shape"] == [5, 4, 3, 3]
    assert man["inputs"]["layout"][-1] == {"name": "surface", "start": cfg.input_dims - 2, "stop": cfg.input_dims}
    assert PhotonField.load(path).surface_grid.shape == (5, 4, 3, 3)
    with np.load(path / "tables.npz") as z:
        pos, dirs, grid = z["position"], z["direction"], z["surface"]
    assert grid.dtype == np.int8 and np.abs(grid).max() > 100
    copy = tmp_path / "copy.pfn"
    for arrays, match in [({"position": pos, "direction": dirs}, "must hold exactly the arrays"),
                          ({"position": pos, "direction": dirs, "surface": grid[:4]}, "'surface' has shape"),
                          ({"position": pos, "direction": dirs, "surface": grid.astype(np.float32)}, "dtype float32")]:
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(path, copy)
        rewrite(copy, "tables.npz", _npz_bytes(tmp_path, **arrays))
        refused(copy, match)
    shutil.rmtree(copy)
    shutil.copytree(path, copy)
    edit_manifest(copy, lambda m: m["tables"]["arrays"].pop("surface"))
    refused(copy, "tables.arrays.surface")


class _Smuggler:
    """Unpickling this calls open(marker, 'w'): proof of execution if the loader ever unpickled."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):  # noqa: ANN204
        return (open, (self.marker, "w"))


def test_pickle_smuggled_into_the_npz_is_refused_not_executed(bundle_copy: Path, tmp_path: Path) -> None:
    marker = tmp_path / "executed"
    with np.load(bundle_copy / "tables.npz") as z:
        dirs = z["direction"]
    evil = np.empty(1, dtype=object)
    evil[0] = _Smuggler(str(marker))
    path = tmp_path / "evil.npz"
    with zipfile.ZipFile(path, "w") as zf:
        with zf.open("position.npy", "w") as f:
            np.lib.format.write_array(f, evil, allow_pickle=True)
        with zf.open("direction.npy", "w") as f:
            np.lib.format.write_array(f, dirs)
    rewrite(bundle_copy, "tables.npz", path.read_bytes())
    refused(bundle_copy, "pickled object array: refused")
    assert not marker.exists()


def test_onnx_width_checker_external_data_and_garbage(small: tuple, bundle_copy: Path, tmp_path: Path) -> None:
    model = small[0]
    weights = mlp_weights(model)
    wider = [np.concatenate([weights[0], np.zeros((weights[0].shape[0], 1), np.float32)], axis=1), *weights[1:]]
    rewrite(bundle_copy, "field.onnx", mlp_onnx(wider))
    refused(bundle_copy, f"input width {SMALL.input_dims + 1} does not match")
    narrower = [*weights[:-1], weights[-1][:2]]
    rewrite(bundle_copy, "field.onnx", mlp_onnx(narrower))
    refused(bundle_copy, "output width 2")
    good = onnx.load_from_string(mlp_onnx(weights))
    bad = onnx.ModelProto()
    bad.CopyFrom(good)
    bad.graph.node[1].op_type = "NoSuchOp"  # onnx.checker: no such operator in the default domain
    rewrite(bundle_copy, "field.onnx", bad.SerializeToString())
    refused(bundle_copy, "fails onnx.checker")
    ext = onnx.ModelProto()
    ext.CopyFrom(good)
    init = ext.graph.initializer[0]
    init.ClearField("raw_data")
    init.data_location = onnx.TensorProto.EXTERNAL
    init.external_data.add(key="location", value="field.onnx.data")
    rewrite(bundle_copy, "field.onnx", ext.SerializeToString())
    refused(bundle_copy, "external data")
    rewrite(bundle_copy, "field.onnx", b"\x08\x07garbage that is not protobuf \xff\xff\xff")
    refused(bundle_copy, "field.onnx")
