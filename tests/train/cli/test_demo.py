"""pfn-demo end to end in miniature: every output is written and the summary's numbers are real."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from photon_fields.train.cli.demo import _main  # noqa: E402


def test_demo_writes_renders_figure_and_summary(tmp_path, capsys) -> None:  # noqa: ANN001
    """The demo on blobs at 32^3 with a field that has learnt something (cpu preset, 100 steps, 100k photons):
    every output exists, the reported errors are those of the written images (recomputed here from the
    EXRs), and they are in the range a working pipeline gives. Measured (seeds 0, 1, 2): relative L2 of L
    against the 256-spp reference: neural 0.207-0.215, photon map 0.177-0.205, equal-time path tracer
    0.169-0.237 (18-32 spp); field L_i vs photon-map L_i 0.196-0.225; mean L ratio to the reference: neural
    0.84-0.89 (the short fit reads low), photon map 0.94-1.00. A zero field gives 1.0 on L_i."""
    import time

    from conftest import tiny_scene_dict

    from photon_fields.runtime.io.images import read_exr

    out = tmp_path / "demo"
    scene_file = tmp_path / "blobs32.json"
    scene_file.write_text(json.dumps(tiny_scene_dict()))
    t0 = time.perf_counter()
    assert _main(["--scene", str(scene_file), "--photons", "100k", "--preset", "cpu", "--steps", "100", "--size",
                  "32x32", "--spp", "8", "--reference-spp", "256", "--out", str(out), "--quiet"]) == 0
    wall = time.perf_counter() - t0
    for name in ("neural", "photonmap", "pathtraced", "pathtraced_equal_time"):
        assert (out / f"{name}.exr").exists() and (out / f"{name}.png").exists()
    assert (out / "comparison.png").stat().st_size > 10_000
    assert (out / "run" / "field.pfn" / "manifest.json").exists() and (out / "run" / "loss.png").exists()
    assert "errors against the path-traced reference" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    m, sec = summary["metrics"], summary["seconds"]
    # The reported times are real: the stages ran inside the command's wall time, and most of it.
    assert 0.3 * wall < summary["total_s"] <= wall
    assert sec["warm_up"] > 0.0  # the renderers' compile is timed apart from the comparison (shown, not hidden)
    # The reported errors are the written images' errors.
    img = {n: read_exr(out / f"{n}.exr")[0] for n in ("neural", "photonmap", "pathtraced", "pathtraced_equal_time")}
    ref = img["pathtraced"]

    def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(((a.astype(np.float64) - b) ** 2).sum() / (b.astype(np.float64) ** 2).sum()))

    for key, name in (("neural_L_vs_reference", "neural"), ("photon_map_L_vs_reference", "photonmap"),
                      ("path_traced_equal_time_L_vs_reference", "pathtraced_equal_time")):
        assert m[key]["rel_l2"] == pytest.approx(rel_l2(img[name]["L"], ref["L"]), rel=1e-3), key
    assert m["neural_L_i_vs_photon_map_L_i"]["rel_l2"] == pytest.approx(
        rel_l2(img["neural"]["L_i"], img["photonmap"]["L_i"]), rel=1e-3)
    # ... and in a working pipeline's range.
    assert m["neural_L_vs_reference"]["rel_l2"] < 0.35 and m["photon_map_L_vs_reference"]["rel_l2"] < 0.3
    # The equal-time path tracer's spp follows this machine's speed (and load), so its error is bounded by its
    # spp, not by a constant: measured 0.169-0.237 at 18-32 spp, i.e. about 1.0 / sqrt(spp) (noise-dominated).
    eq = m["path_traced_equal_time_L_vs_reference"]
    assert eq["rel_l2"] < 1.6 / np.sqrt(eq["spp"]) + 0.05, eq
    assert m["neural_L_i_vs_photon_map_L_i"]["rel_l2"] < 0.35
    # SSIM of the speed-independent images (the equal-time one's spp, hence its noise, follows the machine).
    assert min(m[k]["ssim"] for k in m if k != "path_traced_equal_time_L_vs_reference") > 0.85
    assert 0.75 < img["neural"]["L"].mean() / ref["L"].mean() < 1.05
    assert 0.88 < img["photonmap"]["L"].mean() / ref["L"].mean() < 1.06
    # Equal time: the path tracer got the spp it manages in the neural frame's time, and took about that time.
    eq_spp = m["path_traced_equal_time_L_vs_reference"]["spp"]
    per_spp = sec["render_path_traced"] / summary["reference_spp"]
    assert eq_spp >= 1 and (eq_spp == 1 or eq_spp * per_spp <= sec["render_neural"] < (eq_spp + 1) * per_spp)
    # One exposure for every PNG: the reference's L, recorded; equal radiance shows as equal pixel values.
    from PIL import Image

    from photon_fields.runtime.io.images import EXPOSURE_METADATA, auto_exposure_stops, tonemap_srgb

    stops = summary["exposure_stops"]["png"]
    assert stops == pytest.approx(auto_exposure_stops(ref["L"]))
    assert summary["exposure_stops"]["comparison_rows"]["L"] == pytest.approx(stops)
    for name, layers in img.items():
        assert float(read_exr(out / f"{name}.exr")[1][EXPOSURE_METADATA]) == stops
        png = np.asarray(Image.open(out / f"{name}.png").convert("RGB"))
        assert np.array_equal(png, tonemap_srgb(layers["L"], stops)), name
    assert summary["cpu"]["model"]


def test_demo_refuses_bad_settings_in_one_line(tmp_path, capsys) -> None:  # noqa: ANN001
    for argv, word in ((["--spp", "0"], "--spp"), (["--size", "0x10"], "--size"), (["--preset", "huge"], "--preset"),
                       (["--scene", "nowhere"], "nowhere")):
        assert _main([*argv, "--out", str(tmp_path / "d")]) == 2
        err = capsys.readouterr().err
        assert word in err and err.count("\n") == 1
    assert not (tmp_path / "d" / "summary.json").exists()


def test_the_warm_up_compiles_every_estimator_that_auto_may_take() -> None:
    """The demo's equal-time comparison times rendering, not numba's compiles: in a fresh process, after
    ``warm_up_renderers`` every camera estimator ``auto`` may choose has its kernel loaded (the timed render of a
    full view probes and may take the marched one; a warm-up with ``auto`` alone renders the tiny view forced, and
    a fresh clone's first marched render then compiled inside the timed region: 36 s against 1.6 s warm)."""
    import subprocess
    import sys

    code = """
import json
import numpy as np
from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.wavefront import first_interaction, marched_camera
from photon_fields.runtime.wavefront.camera_choice import AUTO_CHOICES
from photon_fields.train.cli.demo import warm_up_renderers

kernels = {"forced": first_interaction._first_interactions, "marched": marched_camera._march}
assert set(kernels) == set(AUTO_CHOICES), AUTO_CHOICES
before = {k: len(v.signatures) for k, v in kernels.items()}
warm_up_renderers(builtin_scene("blobs", 16), lambda x, d, g: np.ones((3, x.shape[1])), 0)
print(json.dumps([before, {k: len(v.signatures) for k, v in kernels.items()}]))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == {"forced": 0, "marched": 0}, before
    assert after["forced"] > 0 and after["marched"] > 0, after
