"""pfn-eval in its --quick form: every section of docs/results.md is generated, with its figures."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("torch")

from photon_fields.train.eval import report as eval_report  # noqa: E402
from photon_fields.train.eval.report import QUICK, _main  # noqa: E402

#: --quick's own plan trains with the tiny preset for 30 steps, whose field has not learnt anything (its
#: numbers "mean nothing"); this test gives the same sections a field that has (cpu-phases preset, 80 steps,
#: 100k photons, +8 s), so the reported numbers can be bounded and a broken pipeline fails.
LEARNT = dataclasses.replace(QUICK, preset="cpu-phases", steps=80, train_photons=100_000)


def test_quick_evaluation_writes_every_section_and_figure_with_sane_numbers(tmp_path, monkeypatch) -> None:  # noqa: ANN001
    """Every section and figure is written, and its numbers are in the range a working pipeline gives.
    Measured (seeds 0, 1, 2): naive-schedule final loss 0.082-0.092 (an untrained field ~1); field L_i vs
    photon-map L_i 0.27-0.38, neural / photon-map / ray-marcher L vs the 16-spp path tracer 0.36-0.42 /
    0.34-0.39 / 0.78-0.80 (the marcher lacks multiple scattering); path tracer noise 0.91-1.03 at 1 spp,
    0.31-0.34 at 16; neural 0.31-0.42; per-view phase errors 0.17-0.57. A zero field scores 1.0 against the
    photon map, a field off by a constant factor more. Bounds: 0.25, 0.6, 0.6, 1.0, 0.6, 0.8."""
    monkeypatch.setattr(eval_report, "QUICK", LEARNT)
    out, work = tmp_path / "docs", tmp_path / "work"
    assert _main(["--quick", "--out", str(out), "--work", str(work), "--quiet"]) == 0
    md = (out / "results.md").read_text()
    for title in ("1. Training", "2. Photon tracing", "3. Render timings", "4. Image quality", "5. Noise",
                  "6. Phase awareness"):
        assert f"## {title}" in md
    for png in ("training.png", "images_blobs.png", "noise.png", "phases.png"):
        assert (out / "results" / png).stat().st_size > 5_000 and f"results/{png}" in md
    data = json.loads((out / "results.json").read_text())
    assert data["seed"] == 0 and set(data["phases"]["per_g"]) == {"-0.75", "-0.35", "0", "0.35", "0.75"}

    # 1. training: the naive schedule's validation fell (the share of the light that is wrong, which does not depend
    # on the loss, well below its early value) with the default loss. Not the loss itself: blobs has two lights,
    # which the default keeps apart, and each light's part of a 20k-photon map's targets is so noisy that the
    # validation loss sits at its noise floor from the first validations on (1.06 at step 8, 1.18 at 80).
    naive = data["training"]["0.02M naive"]
    first, last = naive["first_validation"], naive["validation"]
    assert naive["loss"] == "linear" and np.isfinite(last["val_loss"]), naive
    assert last["val_rel_l1"] < min(0.7, 0.75 * first["val_rel_l1"]), naive
    # 2. tracing: at least the requested records, at most max_bounces - 1 = 15 records per path.
    tr = data["tracing"]["blobs/20000"]
    assert 20_000 <= tr["records"] <= 15 * tr["emitted"] and tr["seconds"] > 0
    # 3. timings: positive, and the speedups are the ratios of the reported times.
    t = data["timings"]["blobs"]
    assert min(t["neural"]["L_s"], t["neural"]["L_d_s"], t["path_tracer"]["L_s"]) > 0
    assert t["speedup"]["L"] == pytest.approx(t["path_tracer"]["L_s"] / t["neural"]["L_s"])
    # 4. images
    img = data["images"]["blobs"]
    assert img["neural_L_i_vs_photon_map_L_i"]["rel_l2"] < 0.6
    assert img["neural_L_vs_path_tracer"]["rel_l2"] < 0.6 and img["photon map_L_vs_path_tracer"]["rel_l2"] < 0.6
    assert img["photon map_L_vs_path_tracer"]["rel_l2"] < img["ray marcher_L_vs_path_tracer"]["rel_l2"] < 1.0
    assert img["neural_L_vs_path_tracer"]["ssim"] > 0.7
    # Every fig-8 PNG of a scene shares the reference's L exposure (recorded), so rows compare by eye.
    from photon_fields.runtime.io.images import EXPOSURE_METADATA, read_exr

    recorded = {float(read_exr(p)[1][EXPOSURE_METADATA]) for p in (work / "blobs").glob("fig8_*.exr")}
    assert len(recorded) == 1 and recorded == {img["exposure_stops"]["L"]}
    assert data["cpu"]["model"]
    # 5. noise: the path tracer's error falls with spp (~1 / sqrt(spp) while noise dominates).
    pt = {spp: err for spp, _, err in data["noise"]["curves"]["path tracer"]}
    assert pt[1] > pt[4] > pt[16] and pt[1] > 2.0 * pt[16]
    assert all(err < 0.6 for _, _, err in data["noise"]["curves"]["neural"])
    # 6. phase awareness: every g, every view.
    assert all(v["rel_l2"] < 0.8 for v in data["phases"]["per_view"]), data["phases"]["per_view"]


def test_eval_refuses_unknown_scenes_and_impossible_settings_in_one_line(tmp_path, capsys) -> None:  # noqa: ANN001
    for argv, word in ((["--scenes", "vortex,nowhere"], "nowhere"), (["--spp", "0"], "--spp"),
                       (["--size", "0"], "--size")):
        assert _main(["--quick", *argv, "--out", str(tmp_path / "d"), "--work", str(tmp_path / "w")]) == 2
        err = capsys.readouterr().err
        assert word in err and err.count("\n") == 1
    assert not (tmp_path / "d").exists() and not (tmp_path / "w").exists()
