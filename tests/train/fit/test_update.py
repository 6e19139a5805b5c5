"""``pfn-train update`` / :func:`update_run`: refuses what it cannot do (one line, exit 2, RUN untouched), starts
from RUN's field, retraces with RUN's seed (correlated maps), is reproducible, stops on a plateau or the budget,
and writes a run folder whose bundle is NEW's."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")

from conftest import tiny_scene_dict  # noqa: E402

from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.io.progress import read_progress  # noqa: E402
from photon_fields.runtime.photons.photon_map import PhotonMap  # noqa: E402
from photon_fields.runtime.scene.scene import load_scene  # noqa: E402
from photon_fields.train.cli.train import _main as train_main  # noqa: E402
from photon_fields.train.export.bundle import torch_encoded, verification_inputs  # noqa: E402
from photon_fields.train.field.network import TorchPhotonField  # noqa: E402
from photon_fields.train.fit import update as update_module  # noqa: E402
from photon_fields.train.fit.checkpoint import load_checkpoint  # noqa: E402
from photon_fields.train.fit.presets import PRESETS, UPDATE_LR_SHARE  # noqa: E402
from photon_fields.train.fit.update import read_run, update_run  # noqa: E402

FIT = ["--preset", "tiny", "--steps", "20", "--batch", "256", "--k", "32", "--quiet"]


def write_scene(folder: Path, name: str, **changes: object) -> Path:
    d = tiny_scene_dict()
    for key, value in changes.items():
        d[key] = value
    path = folder / f"{name}.json"
    path.write_text(json.dumps(d))
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """RUN (a tiny ``all`` of the 32^3 blobs scene) and edited scenes."""
    root = tmp_path_factory.mktemp("update")
    base = write_scene(root, "base")
    run = root / "run"
    assert train_main(["all", str(base), "--photons", "3k", *FIT, "--seed", "3", "--out", str(run)]) == 0
    light = dict(tiny_scene_dict()["lights"][0])
    zero_tf = {"points": [{"s": 0, "albedo": [1, 1, 1], "opacity": 0}, {"s": 1, "albedo": [1, 1, 1], "opacity": 0}]}
    return {
        "root": root, "base": base, "run": run,
        "denser": write_scene(root, "denser", transfer_function={"preset": "cloud", "density_scale": 75}),
        "brighter": write_scene(root, "brighter", lights=[{**light, "power": 6.0}]),
        "shell": write_scene(root, "shell", volume={"builtin": "shell", "resolution": 32}),
        "coarser": write_scene(root, "coarser", volume={"builtin": "blobs", "resolution": 24}),
        "empty": write_scene(root, "empty", transfer_function=zero_tf),
        "dark": write_scene(root, "dark", lights=[{**light, "power": 0.0}]),
    }


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def update_args(runs: dict[str, Path], scene: str, out: Path, *extra: str) -> list[str]:
    return ["update", str(runs["run"]), "--scene", str(runs[scene]), "--out", str(out), "--quiet", *extra]


@pytest.mark.parametrize(("scene", "extra", "named"), [
    ("shell", (), "another volume"),
    ("coarser", (), "another volume"),
    ("denser", ("--budget", "0"), "--budget"),
    ("denser", ("--budget", "-3"), "--budget"),
    ("empty", (), "nothing visible"),
    ("dark", (), "zero power"),
])
def test_refusals_are_one_line_and_leave_run_untouched(runs: dict[str, Path], tmp_path: Path, scene: str,
                                                       extra: tuple[str, ...], named: str,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    before = digest(runs["run"])
    out = tmp_path / "new"
    assert train_main(update_args(runs, scene, out, *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and named in err[0], err
    assert digest(runs["run"]) == before and not out.exists()


def test_an_earlier_run_in_out_is_kept_without_force(runs: dict[str, Path], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "new"
    out.mkdir()
    (out / "checkpoint.pt").write_bytes(b"earlier")
    before = digest(runs["run"])
    assert train_main(update_args(runs, "denser", out, "--max-steps", "1")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "--force" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt"] and (out / "checkpoint.pt").read_bytes() == \
        b"earlier"
    assert digest(runs["run"]) == before
    assert train_main(update_args(runs, "denser", out, "--max-steps", "1", "--force")) == 0
    assert (out / "field.pfn" / "manifest.json").is_file()


def test_out_equal_to_run_is_refused(runs: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    before = digest(runs["run"])
    for extra in ((), ("--force",)):
        assert train_main(update_args(runs, "denser", runs["run"], *extra)) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: --out") and "RUN" in err[0], err
    assert digest(runs["run"]) == before


def test_update_writes_new_scenes_run_and_bundle(runs: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "new"
    progress = tmp_path / "progress.json"
    assert train_main(update_args(runs, "denser", out, "--max-steps", "30", "--progress-file", str(progress))) == 0
    new = load_scene(runs["denser"])
    old = load_scene(runs["base"])
    assert new.fingerprint() != old.fingerprint()
    field = PhotonField.load(out / "field.pfn")
    manifest = json.loads((out / "field.pfn" / "manifest.json").read_text())
    assert manifest["scene_fingerprint"] == new.fingerprint() == field.scene_fingerprint
    assert PhotonMap.load(out / "map.npz", expected_fingerprint=new.fingerprint()).meta["seed"] == 3
    log = json.loads((out / "log.json").read_text())
    assert log["warm_start_from"]["run"] == str(runs["run"])
    assert log["warm_start_from"]["scene_fingerprint"] == old.fingerprint()
    assert log["stop"]["reason"] in ("plateau", "max_steps") and 1 <= log["stop"]["steps"] <= 30
    assert log["validation"][0]["step"] == 0 and len(log["validation"]) >= 2
    kept = log["totals"]["final_validation"]  # the bundle tells what the field is good for: its validation error
    assert manifest["training"]["validation"]["val_rel_l1"] == kept["val_rel_l1"]
    assert kept["val_rel_l1"] == min(v["val_rel_l1"] for v in log["validation"])
    p = read_progress(progress)
    assert p.status == "done" and p.stages == ("trace", "fit", "export")
    assert {"checkpoint.pt", "log.json", "loss.png", "domain.json", "map.npz", "field.pfn"} <= \
        {q.name for q in out.iterdir()}
    # The updated run can be updated in turn (back to the base scene).
    assert train_main(["update", str(out), "--scene", str(runs["base"]), "--out", str(tmp_path / "back"),
                       "--max-steps", "2", "--quiet"]) == 0


def inputs(bundle: Path) -> tuple[np.ndarray, ...]:
    field = PhotonField.load(bundle)
    bmin, bsize = np.asarray(field.bmin), np.asarray(field.bsize)
    return (*verification_inputs(bmin, bsize, field.config.phases, n=512, seed=5), bmin, bsize)


def outputs(bundle: Path) -> np.ndarray:
    x, d, g, _, _ = inputs(bundle)
    return PhotonField.load(bundle).query_encoded(x, d, g).astype(np.float64)


def test_the_update_starts_from_runs_field(runs: dict[str, Path], tmp_path: Path) -> None:
    old = outputs(runs["run"] / "field.pfn")
    new = load_scene(runs["denser"])
    res0 = update_run(runs["run"], new, tmp_path / "zero", max_steps=0, progress=False)
    assert res0.fit.log["stop"]["steps"] == 0
    assert np.array_equal(outputs(res0.bundle.path), old)  # no step: exactly RUN's field
    model, _ = load_checkpoint(runs["run"] / "checkpoint.pt")
    x, d, g, bmin, bsize = inputs(runs["run"] / "field.pfn")
    cold = torch_encoded(TorchPhotonField(model.cfg, seed=res0.fit.log["settings"]["seed"]), x, d, g, bmin, bsize)
    assert np.abs(cold - old).mean() > 0.1  # a fresh initialization would not pass
    first = res0.fit.log["validation"][0]
    assert first["step"] == 0 and res0.fit.log["totals"]["final_validation"] == first


def test_a_field_from_before_its_presets_direction_gain_keeps_its_own(runs: dict[str, Path], tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """RUN's field has no direction gain; its preset takes one now (as ``cpu`` did on 2026-11-27): the update still
    starts from RUN's field, exactly, and keeps RUN's architecture instead of refusing it."""
    from dataclasses import replace

    monkeypatch.setitem(PRESETS, "tiny", replace(PRESETS["tiny"], direction_gain="g"))
    res = update_run(runs["run"], load_scene(runs["denser"]), tmp_path / "zero", max_steps=0, progress=False)
    assert PhotonField.load(res.bundle.path).config.direction_gain == "none"
    assert np.array_equal(outputs(res.bundle.path), outputs(runs["run"] / "field.pfn"))


def test_the_surface_input_follows_the_edited_scene(runs: dict[str, Path], tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A field with the surface input, updated for a transfer-function edit, takes the edited medium's surface grid
    (a threshold moves the surfaces; a density scale alone would not: the grid is scale-free); RUN, from before its
    preset took the input, keeps its own architecture."""
    from dataclasses import replace

    from photon_fields.train.field.surface_grid import medium_surface_grid

    monkeypatch.setitem(PRESETS, "tiny", replace(PRESETS["tiny"], surface=True))
    res = update_run(runs["run"], load_scene(runs["denser"]), tmp_path / "old", max_steps=0, progress=False)
    assert PhotonField.load(res.bundle.path).surface_grid is None
    run = tmp_path / "run"
    assert train_main(["all", str(runs["base"]), "--photons", "3k", *FIT, "--seed", "3", "--out", str(run)]) == 0
    before = PhotonField.load(run / "field.pfn").surface_grid
    assert np.array_equal(before, medium_surface_grid(load_scene(runs["base"]).medium()))
    assert np.array_equal(medium_surface_grid(load_scene(runs["denser"]).medium()), before)  # scale-free
    white = {"albedo": [1, 1, 1]}
    edge = load_scene(write_scene(tmp_path, "edge", transfer_function={"points": [
        {"s": 0, "opacity": 0, **white}, {"s": 0.3, "opacity": 0, **white}, {"s": 0.35, "opacity": 1, **white},
        {"s": 1, "opacity": 1, **white}]}))
    res = update_run(run, edge, tmp_path / "new", max_steps=0, progress=False)
    after = PhotonField.load(res.bundle.path).surface_grid
    assert np.array_equal(after, medium_surface_grid(edge.medium())) and not np.array_equal(after, before)


def test_same_seed_same_field(runs: dict[str, Path], tmp_path: Path) -> None:
    new = load_scene(runs["denser"])
    a = update_run(runs["run"], new, tmp_path / "a", max_steps=4, progress=False)
    b = update_run(runs["run"], new, tmp_path / "b", max_steps=4, progress=False)
    for name in ("field.onnx", "tables.npz"):
        assert (a.bundle.path / name).read_bytes() == (b.bundle.path / name).read_bytes()
    c = update_run(runs["run"], new, tmp_path / "c", max_steps=4, seed=11, progress=False)
    assert (c.bundle.path / "tables.npz").read_bytes() != (a.bundle.path / "tables.npz").read_bytes()


def test_retrace_is_correlated_with_runs_map(runs: dict[str, Path], tmp_path: Path) -> None:
    """Same seed: a light twice as bright sends every photon along the same path with twice the power."""
    res = update_run(runs["run"], load_scene(runs["brighter"]), tmp_path / "bright", max_steps=0, progress=False)
    old = PhotonMap.load(runs["run"] / "map.npz")
    new = PhotonMap.load(res.out / "map.npz")
    assert len(new) >= len(old) and new.phases == old.phases
    for ph in range(len(old.phases)):  # a phase's records in path order: identical streams, identical vertices
        a, b = old.subset(ph), new.subset(ph)
        n = min(len(a), len(b))
        assert n > 0 and np.array_equal(a.position[:n], b.position[:n])
        assert np.array_equal(a.direction[:n], b.direction[:n])
        ratio = b.power[:n] / a.power[:n]  # 2 x (old paths / new paths of the phase: powers are per path emitted)
        np.testing.assert_allclose(ratio, ratio[0, 0], rtol=1e-5)
        assert 1.0 < ratio[0, 0] <= 2.0


def test_stops_on_a_plateau_and_at_the_budget(runs: dict[str, Path], tmp_path: Path) -> None:
    new = load_scene(runs["denser"])
    # No validation can be 99 % better than the one before: the rule stops at the first validation after step 0.
    plateau = update_run(runs["run"], new, tmp_path / "p", max_steps=200, min_improvement=0.99, patience=1,
                         progress=False)
    assert plateau.fit.log["stop"]["reason"] == "plateau" and plateau.fit.log["stop"]["steps"] == 25
    # A budget the retrace alone exceeds: no step, RUN's field exported as NEW's.
    budget = update_run(runs["run"], new, tmp_path / "b", budget_s=1e-3, max_steps=200, progress=False)
    assert budget.fit.log["stop"]["reason"] == "budget" and budget.fit.log["stop"]["steps"] == 0
    assert (budget.out / "field.pfn" / "manifest.json").is_file()


class StopHereError(Exception):
    """Raised by a stand-in for a stage of update_run once it has recorded what it was called with."""


class StillClock:
    """``time`` for update_run whose ``perf_counter`` stands at 100 s: deadlines become exact."""

    @staticmethod
    def perf_counter() -> float:
        return 100.0


def test_training_stops_early_enough_for_the_outputs_to_fit_the_budget(runs: dict[str, Path], tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """The budget covers the written bundle, not only training: the fine-tune's deadline is the call's start plus
    the budget less the outputs' reserve (at most half the budget). A clock that stands still makes it exact."""
    from photon_fields.train.fit.presets import UPDATE_OUTPUT_RESERVE_S

    deadlines: list[float] = []

    def capture(*args: object, deadline: float, **kwargs: object) -> None:
        deadlines.append(deadline)
        raise StopHereError

    monkeypatch.setattr(update_module, "time", StillClock)
    monkeypatch.setattr(update_module, "fine_tune", capture)
    new = load_scene(runs["denser"])
    for budget in (15.0, 2.0):
        with pytest.raises(StopHereError):
            update_run(runs["run"], new, tmp_path / f"d{budget:g}", budget_s=budget, progress=False)
    # pfn-train update's clock starts with its process: the start-up before the call is part of the budget
    for started in (96.0, 130.0):  # a start 4 s before the call; a "start" after it counts from the call
        with pytest.raises(StopHereError):
            update_run(runs["run"], new, tmp_path / f"s{started:g}", budget_s=15.0, progress=False, started=started)
    assert deadlines == pytest.approx([100.0 + 15.0 - UPDATE_OUTPUT_RESERVE_S, 100.0 + 1.0,
                                       96.0 + 15.0 - UPDATE_OUTPUT_RESERVE_S, 100.0 + 15.0 - UPDATE_OUTPUT_RESERVE_S])


def test_the_retrace_gets_a_share_of_the_budget_left(runs: dict[str, Path], tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """On sparse media a photon record costs many paths (vortex's 1M took 6-12 s of the 15 s): the retrace stops
    at UPDATE_TRACE_SHARE of the budget left when it starts, once it holds UPDATE_MIN_PHOTONS records."""
    from photon_fields.train.fit.presets import UPDATE_MIN_PHOTONS, UPDATE_TRACE_SHARE

    seen: list[dict[str, object]] = []

    def capture(*args: object, **kwargs: object) -> None:
        seen.append(kwargs)
        raise StopHereError

    monkeypatch.setattr(update_module, "time", StillClock)
    monkeypatch.setattr(update_module, "trace_photons", capture)
    new = load_scene(runs["denser"])
    for started, photons in ((None, 2_000_000), (96.0, 3_000)):
        with pytest.raises(StopHereError):
            update_run(runs["run"], new, tmp_path / f"t{photons}", budget_s=15.0, photons=photons, progress=False,
                       started=started)
    assert seen[0]["deadline"] == pytest.approx(100.0 + UPDATE_TRACE_SHARE * 15.0)
    assert seen[0]["min_photons"] == UPDATE_MIN_PHOTONS
    assert seen[1]["deadline"] == pytest.approx(100.0 + UPDATE_TRACE_SHARE * 11.0)  # 4 s of start-up spent
    assert seen[1]["min_photons"] == 3_000


@pytest.mark.parametrize(("errors", "kept"), [
    ([0.10, 0.20, 0.15, 0.30], 50),  # the earlier field scores lowest: the best trained one is kept all the same
    ([0.30, 0.20, 0.10, 0.15], 50),  # the lowest trained one
    ([0.30, 0.20, 0.25, 0.22], 25),
])
def test_an_update_keeps_a_trained_field_not_the_earlier_one(runs: dict[str, Path], tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch, errors: list[float],
                                                             kept: int) -> None:
    """The earlier field answers another scene; after a small edit the noisy validation cannot tell it from the
    trained fields, and keeping it whenever it scored lowest left a chain of small edits unfollowed. The kept
    field is the lowest-scoring *trained* one, and it is the field the checkpoint holds."""
    from photon_fields.train.fit import fine_tune as fine_tune_module

    scores = iter(errors)
    snapshots: dict[int, list[np.ndarray]] = {}
    real = fine_tune_module.validate_field

    def scripted(model: TorchPhotonField, val: object, **kw: object) -> dict[str, float]:
        out = real(model, val, **kw)
        snapshots[25 * len(snapshots)] = [p.detach().numpy().copy() for p in model.parameters()]
        return {**out, "val_rel_l1": next(scores)}

    monkeypatch.setattr(fine_tune_module, "validate_field", scripted)
    res = update_run(runs["run"], load_scene(runs["denser"]), tmp_path / "new", max_steps=75, budget_s=1e6,
                     patience=10, progress=False)
    assert res.fit.log["stop"]["kept_step"] == kept and res.fit.log["stop"]["steps"] == 75
    model, _ = load_checkpoint(res.out / "checkpoint.pt", None)
    for p, want in zip(model.parameters(), snapshots[kept], strict=True):
        np.testing.assert_array_equal(p.detach().numpy(), want)


def test_the_command_counts_its_budget_from_its_process_start(runs: dict[str, Path], tmp_path: Path) -> None:
    """``pfn-train update`` as a process of its own (as the viewer's retrain runs it): its log records the
    start-up before the call as part of the budget (0 for an in-process call)."""
    import subprocess
    import sys

    out = tmp_path / "cli"
    argv = [sys.executable, "-m", "photon_fields.train.cli.train",
            *update_args(runs, "denser", out, "--max-steps", "1")]
    subprocess.run(argv, check=True, capture_output=True, timeout=600)
    split = json.loads((out / "log.json").read_text())["update_time"]
    assert split["startup_s"] > 0.0
    in_process = tmp_path / "in_process"
    assert train_main(update_args(runs, "denser", in_process, "--max-steps", "1")) == 0
    assert json.loads((in_process / "log.json").read_text())["update_time"]["startup_s"] == 0.0


def test_process_started_is_when_the_process_started() -> None:
    """``pfn-train update`` counts its budget from :func:`process_started`: a process that slept 1 s before asking
    must be told it started >= 1 s earlier (and not before the test launched it)."""
    import subprocess
    import sys
    import time

    code = ("import time\ntime.sleep(1.0)\nfrom photon_fields.runtime.cli.common import process_started\n"
            "print(time.perf_counter() - process_started())")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    wall = time.perf_counter() - t0
    age = float(out.stdout)
    if sys.platform != "linux":
        pytest.skip("process_started reads /proc: elsewhere the budget counts from the call")
    assert 1.0 <= age <= wall + 0.05


def test_run_is_read_without_its_photons(runs: dict[str, Path], tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """RUN's map is read for its metadata only (a full load of a 5M map took ~2 s of the 15 s budget)."""
    def no_load(*args: object, **kwargs: object) -> None:
        raise AssertionError("PhotonMap.load called")

    monkeypatch.setattr(PhotonMap, "load", no_load)
    record = read_run(runs["run"])
    assert record.map_seed == 3 and record.photons >= 3000 and record.max_bounces == 16
    res = update_run(runs["run"], load_scene(runs["denser"]), tmp_path / "new", max_steps=1, progress=False)
    assert res.fit.log["stop"]["steps"] == 1


def test_default_photons_are_capped(runs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without --photons the retrace keeps RUN's map size up to UPDATE_PHOTONS records (tiny here: 2000)."""
    old = read_run(runs["run"]).photons
    monkeypatch.setattr(update_module, "UPDATE_PHOTONS", 2000)
    new = load_scene(runs["denser"])
    capped = update_run(runs["run"], new, tmp_path / "capped", max_steps=0, progress=False)
    assert 2000 <= capped.fit.log["photons"] < old
    asked = update_run(runs["run"], new, tmp_path / "asked", max_steps=0, photons=old, progress=False)
    assert asked.fit.log["photons"] >= old  # an explicit count wins over the cap
    monkeypatch.setattr(update_module, "UPDATE_PHOTONS", 10 * old)
    kept = update_run(runs["run"], new, tmp_path / "kept", max_steps=0, progress=False)
    assert old <= kept.fit.log["photons"] < 2 * old  # a smaller earlier map keeps its count


def test_the_progress_file_says_done_before_the_loss_plot(runs: dict[str, Path], tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A viewer waiting on ``--progress-file`` swaps the field in as soon as the bundle is written; the loss plot
    (1-3.6 s in a fresh process on a busy core) comes after."""
    progress_path = tmp_path / "progress.json"
    seen: list[str] = []
    real = update_module.plot_loss

    def spy(log: dict, png: Path) -> None:
        seen.append(read_progress(progress_path).status)
        real(log, png)

    monkeypatch.setattr(update_module, "plot_loss", spy)
    out = tmp_path / "new"
    assert train_main(update_args(runs, "denser", out, "--max-steps", "1", "--progress-file",
                                  str(progress_path))) == 0
    assert seen == ["done"] and (out / "loss.png").is_file()


def test_the_time_split_accounts_for_the_wall_time(runs: dict[str, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """log.json's ``update_time`` (and the CLI's ``time:`` line) say where the budget went: the stages before
    training and the fine-tune's together take the wall time to the end of training, none counted twice; the
    export ends the budget's part (``bundle_s``) and the loss plot comes after it."""
    out = tmp_path / "new"
    assert train_main(update_args(runs, "denser", out, "--max-steps", "30", "--budget", "300")) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("time: ")]
    assert len(line) == 1 and "retrace" in line[0] and "validation targets" in line[0]
    t = json.loads((out / "log.json").read_text())["update_time"]
    assert t["budget_s"] == 300.0 and all(v >= 0 for v in t.values())
    inner = t["setup_s"] + t["targets_s"] + t["train_s"] + t["validate_s"]
    assert t["index_build_s"] + t["validation_targets_s"] <= t["setup_s"] and inner <= t["fine_tune_s"]
    assert inner >= 0.5 * t["fine_tune_s"]  # the named stages are most of the fine-tune
    res = update_run(runs["run"], load_scene(runs["denser"]), tmp_path / "again", max_steps=30, budget_s=300,
                     progress=False)
    s = res.time_split
    parts = (s["startup_s"] + s["read_run_s"] + s["trace_s"] + s["save_map_s"] + s["fine_tune_s"] + s["outputs_s"]
             + s["export_s"])
    assert 0.95 * s["bundle_s"] <= parts <= s["bundle_s"] + 1e-3  # the bundle is written before the loss plot
    assert 0.95 * s["wall_s"] <= parts + s["plot_s"] <= s["wall_s"] + 1e-3
    assert (res.out / "loss.png").is_file() and (res.out / "loss.png").stat().st_mtime >= (
        res.out / "field.pfn" / "manifest.json").stat().st_mtime


@pytest.mark.parametrize("share", [0.0, -0.1, 1.5, float("nan"), True, "0.1"])
def test_a_learning_rate_share_outside_0_1_is_refused(runs: dict[str, Path], tmp_path: Path, share: object) -> None:
    scene = load_scene(runs["denser"])
    with pytest.raises(InputError, match="lr share"):
        update_run(runs["run"], scene, tmp_path / "new", lr_share=share, progress=False)  # type: ignore[arg-type]
    assert not (tmp_path / "new").exists()


def test_the_fine_tune_runs_at_its_share_of_the_preset_learning_rate(runs: dict[str, Path], tmp_path: Path) -> None:
    scene = load_scene(runs["denser"])
    for share in (UPDATE_LR_SHARE, 0.5):
        res = update_run(runs["run"], scene, tmp_path / f"s{share}", max_steps=1, lr_share=share, progress=False)
        preset = res.fit.log["settings"]["preset"]
        assert res.fit.log["settings"]["lr"] == pytest.approx(PRESETS[preset].lr * share)


def test_an_update_for_a_power_edit_says_the_run_renders_it_already(runs: dict[str, Path], tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A light's power or colour edit needs no update (the field is rescaled exactly at load): pfn-train update says
    so, and still updates when asked; an edit of the transfer function gets no such note."""
    assert read_run(runs["run"]).light_rescale(load_scene(runs["brighter"])) == pytest.approx([2.0, 2.0, 2.0])
    assert read_run(runs["run"]).light_rescale(load_scene(runs["denser"])) is None
    assert train_main(update_args(runs, "brighter", tmp_path / "b", "--max-steps", "0")) == 0
    err = capsys.readouterr().err
    assert "only in its lights' power or colour" in err and "(2, 2, 2)" in err and "updating anyway" in err
    assert train_main(update_args(runs, "denser", tmp_path / "d", "--max-steps", "0")) == 0
    assert "only in its lights'" not in capsys.readouterr().err


def test_an_albedo_edit_reweights_runs_map_instead_of_retracing(runs: dict[str, Path], tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Only the albedo changed: the new map is RUN's paths, reweighted (runtime/photons/albedo_reweight.py), thinned
    to the update's photon count; nothing is traced. A density edit still retraces."""
    tf = load_scene(runs["base"]).tf.to_dict()
    for p in tf["points"]:
        p["albedo"] = [0.6 * p["albedo"][0], p["albedo"][1], p["albedo"][2]]
    bluer = write_scene(tmp_path, "bluer", transfer_function=tf)
    traced = []
    monkeypatch.setattr(update_module, "trace_photons", lambda *a, **k: traced.append(1))
    monkeypatch.setattr(update_module, "UPDATE_PHOTONS", 2000)
    res = update_run(runs["run"], load_scene(bluer), tmp_path / "new", max_steps=1, progress=False)
    assert res.map_from == "reweighted" and not traced and res.fit.log["warm_start_from"]["map"] == "reweighted"
    old, new = PhotonMap.load(runs["run"] / "map.npz"), PhotonMap.load(res.out / "map.npz")
    assert 1000 < len(new) < 3000 < len(old) and new.scene_fingerprint == load_scene(bluer).fingerprint()
    monkeypatch.undo()
    denser = update_run(runs["run"], load_scene(runs["denser"]), tmp_path / "denser", max_steps=0, progress=False)
    assert denser.map_from == "retraced"
    capsys.readouterr()
    assert train_main(["update", str(runs["run"]), "--scene", str(bluer), "--out", str(tmp_path / "cli"),
                       "--max-steps", "1", "--quiet"]) == 0
    assert "the albedo edit reweighted RUN's map" in capsys.readouterr().out
