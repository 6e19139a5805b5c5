"""Tests for the ``pfn-render`` command line: outputs, determinism and one-line errors for bad input.

Renders are tiny (16x16, 1 spp). The first render of the session may compile numba kernels (~30 s
without a warm cache), so a module-scoped fixture renders once and the other tests reuse its output.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from photon_fields.runtime.cli.render import _main
from photon_fields.runtime.io.images import EXPOSURE_METADATA, auto_exposure_stops, read_exr, tonemap_srgb
from photon_fields.runtime.scene.scene import BUILTIN_SCENES

TINY = ["--size", "16x16", "--spp", "1", "--quiet"]
LAYERS = {"L", "L_d", "L_i", "L_e"}


def render(out: Path, *extra: str, scene: str = "blobs") -> int:
    return _main(["--scene", scene, *TINY, *extra, "--out", str(out)])


def files_in(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def one_error_line(stderr: str) -> str:
    lines = stderr.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {stderr!r}"
    assert lines[0].startswith("error: "), lines[0]
    assert "Traceback" not in stderr
    return lines[0]


@pytest.fixture(scope="module")
def warm(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One path-traced render (seed 3) of the builtin 'blobs' scene; also compiles the kernels."""
    out = tmp_path_factory.mktemp("warm") / "blobs.exr"
    assert render(out, "--seed", "3") == 0
    return out


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A JSON scene with a 16^3 .npy volume next to it (referenced by a relative path)."""
    folder = tmp_path_factory.mktemp("tiny_scene")
    x = (np.arange(16) + 0.5) / 16
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    np.save(folder / "ball.npy", np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / 0.04))
    scene = {
        "name": "ball",
        "volume": {"path": "ball.npy"},
        "transfer_function": {"preset": "grey_ramp", "density_scale": 20},
        "lights": [
            {"type": "directional", "direction": [-1, -1, -0.5], "power": 3},
            {"type": "environment", "color": [0.2, 0.3, 0.5], "power": 0.5},
        ],
        "camera": {"eye": [1.2, 0.7, 1.5], "target": [0, 0, 0], "fov": 40, "width": 8, "height": 8},
        "phase": {"g": 0.4},
    }
    (folder / "ball.json").write_text(json.dumps(scene))
    return folder / "ball.json"


# ----------------------------------------------------------------------------------------------------------
# success


def test_render_writes_exr_png_and_json(warm: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert files_in(warm.parent) == ["blobs.exr", "blobs.json", "blobs.png"]  # and no temporary files
    layers, meta = read_exr(warm)
    assert set(layers) == LAYERS
    for name, arr in layers.items():
        assert arr.shape == (16, 16, 3) and arr.dtype == np.float32, name
        assert np.all(np.isfinite(arr)) and np.all(arr >= 0), name
    assert float(layers["L"].max()) > 0  # something is lit
    np.testing.assert_allclose(layers["L"], layers["L_d"] + layers["L_i"] + layers["L_e"], rtol=1e-4, atol=1e-6)
    assert meta["photon_fields.method"] == "pt" and meta["photon_fields.scene"] == "blobs"
    assert meta["photon_fields.seed"] == "3" and meta["photon_fields.spp"] == "1"
    with Image.open(warm.with_suffix(".png")) as im:
        assert im.size == (16, 16) and im.mode == "RGB"

    report = json.loads(warm.with_suffix(".json").read_text())
    assert report["scene"] == "blobs" and report["method"] == "pt"
    assert report["spp"] == 1 and report["seed"] == 3 and report["size"] == [16, 16]
    assert report["g"] == BUILTIN_SCENES["blobs"]["g"]
    assert report["options"] == {"max_depth": 16, "nee": True}  # the renderer's settings, to reproduce it
    assert report["wall_s"] > 0
    timings = report["timings_ms"]
    assert isinstance(timings, dict) and timings
    assert all(isinstance(v, (int, float)) and v >= 0 for v in timings.values())
    assert report["scene_description"]["camera"]["width"] == 16
    assert isinstance(report["stats"], dict)


def test_render_prints_summary(tmp_path: Path, warm: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "nested" / "deeper" / "r.exr"  # missing folders are created
    assert render(out, "--g", "-0.3", "--exposure", "1.5") == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert "rendered in" in captured.out and str(out) in captured.out
    assert files_in(out.parent) == ["r.exr", "r.json", "r.png"]
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["g"] == -0.3 and report["scene_description"]["phase"]["g"] == -0.3
    assert read_exr(out)[1]["photon_fields.g"] == "-0.3"


def test_same_seed_is_bit_identical(tmp_path: Path, warm: Path) -> None:
    out = tmp_path / "again.exr"
    assert render(out, "--seed", "3") == 0
    first, _ = read_exr(warm)
    second, _ = read_exr(out)
    assert set(first) == set(second) == LAYERS
    for name in LAYERS:
        assert np.array_equal(first[name], second[name]), name


def test_different_seeds_differ(tmp_path: Path, warm: Path) -> None:
    out = tmp_path / "other.exr"
    assert render(out, "--seed", "4") == 0
    first, _ = read_exr(warm)
    other, _ = read_exr(out)
    assert not np.array_equal(first["L"], other["L"])


def test_seed_independent_of_threads_and_batch_size(tmp_path: Path, warm: Path) -> None:
    import numba

    before = numba.get_num_threads()
    out = tmp_path / "one_thread.exr"
    try:
        assert render(out, "--seed", "3", "--threads", "1", "--batch-size", "37") == 0
    finally:
        numba.set_num_threads(before)  # --threads is process-wide state: do not slow down later tests
    first, _ = read_exr(warm)
    second, _ = read_exr(out)
    for name in LAYERS:
        assert np.array_equal(first[name], second[name]), name


def test_raymarch(tmp_path: Path) -> None:
    out = tmp_path / "marched.exr"
    assert render(out, "--method", "raymarch", "--seed", "1") == 0
    assert files_in(tmp_path) == ["marched.exr", "marched.json", "marched.png"]
    layers, meta = read_exr(out)
    assert meta["photon_fields.method"] == "raymarch"
    assert layers["L"].shape == (16, 16, 3) and np.all(np.isfinite(layers["L"]))
    assert float(layers["L"].max()) > 0
    assert json.loads(out.with_suffix(".json").read_text())["method"] == "raymarch"
    out2 = tmp_path / "marched2.exr"
    assert render(out2, "--method", "raymarch", "--seed", "1") == 0
    assert np.array_equal(read_exr(out2)[0]["L"], layers["L"])
    out3 = tmp_path / "coarse.exr"
    assert render(out3, "--method", "raymarch", "--seed", "1", "--level", "1") == 0
    coarse = read_exr(out3)[0]["L"]
    assert coarse.shape == layers["L"].shape and not np.array_equal(coarse, layers["L"])
    assert json.loads(out3.with_suffix(".json").read_text())["options"]["level"] == 1


def test_json_scene_file(tmp_path: Path, tiny_scene: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # the volume path is relative to the scene file, not to the cwd
    assert _main(["--scene", str(tiny_scene), "--spp", "1", "--quiet", "--out", "ball.exr"]) == 0
    layers, meta = read_exr(tmp_path / "ball.exr")
    assert layers["L"].shape == (8, 8, 3)  # the scene camera's size
    assert meta["photon_fields.scene"] == "ball"
    report = json.loads((tmp_path / "ball.json").read_text())
    assert report["g"] == 0.4 and report["size"] == [8, 8]
    assert report["scene_description"]["volume"]["dims"] == [16, 16, 16]


@pytest.mark.parametrize("existing", [".exr", ".png", ".json"])
def test_an_earlier_render_is_kept_unless_forced(tmp_path: Path, warm: Path, existing: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Any one of the three outputs existing is refused in one line naming it; its bytes stay; --force
    replaces all three."""
    out = tmp_path / "r.exr"
    out.with_suffix(existing).write_bytes(b"old")
    assert render(out) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "--force" in line and str(out.with_suffix(existing)) in line
    assert files_in(tmp_path) == [f"r{existing}"] and out.with_suffix(existing).read_bytes() == b"old"
    assert render(out, "--force") == 0
    assert files_in(tmp_path) == ["r.exr", "r.json", "r.png"]
    for suffix in (".exr", ".png", ".json"):
        assert out.with_suffix(suffix).read_bytes() != b"old"


def test_png_out_writes_the_exr_and_report_beside_it(tmp_path: Path, warm: Path) -> None:
    assert render(tmp_path / "r.png", "--seed", "3") == 0
    assert files_in(tmp_path) == ["r.exr", "r.json", "r.png"]
    assert np.array_equal(read_exr(tmp_path / "r.exr")[0]["L"], read_exr(warm)[0]["L"])


def test_the_recorded_exposure_reproduces_the_png(tmp_path: Path, warm: Path) -> None:
    """The report and the EXR header record the exposure the PNG was made with; tone-mapping the EXR with
    it gives the PNG byte for byte. Automatic exposure is the image's own (auto_exposure_stops)."""
    report = json.loads(warm.with_suffix(".json").read_text())
    layers, meta = read_exr(warm)
    stops = report["exposure"]["stops"]
    assert report["exposure"]["mode"] == "auto" and stops == pytest.approx(auto_exposure_stops(layers["L"]))
    assert float(meta[EXPOSURE_METADATA]) == stops
    png = np.asarray(Image.open(warm.with_suffix(".png")).convert("RGB"))
    assert np.array_equal(png, tonemap_srgb(layers["L"], stops))


def test_exposure_from_shows_two_renders_alike(tmp_path: Path, warm: Path) -> None:
    """Two renders of one scene with other spp get different automatic exposures; --exposure-from the
    first's report gives the second the same one, so equal radiance shows as equal PNG values."""
    other = tmp_path / "other.exr"
    assert render(other, "--seed", "4", "--spp", "1", "--method", "raymarch") == 0
    auto = json.loads(other.with_suffix(".json").read_text())["exposure"]["stops"]
    first = json.loads(warm.with_suffix(".json").read_text())["exposure"]["stops"]
    assert auto != first  # the case the option exists for
    same = tmp_path / "same.exr"
    assert render(same, "--seed", "4", "--spp", "1", "--method", "raymarch",
                  "--exposure-from", str(warm.with_suffix(".json"))) == 0
    report = json.loads(same.with_suffix(".json").read_text())
    assert report["exposure"]["stops"] == first and report["exposure"]["mode"].startswith("--exposure-from")
    png = np.asarray(Image.open(same.with_suffix(".png")).convert("RGB"))
    assert np.array_equal(png, tonemap_srgb(read_exr(same)[0]["L"], first))


@pytest.mark.parametrize(("content", "match"), [
    (None, "not found"), ("{", "JSON"), ('{"method": "pt"}', "records no exposure"),
    ('{"exposure": {"stops": "bright"}}', "finite number"), ('{"exposure": {"stops": 1, "stop": 2}}', "stop"),
])
def test_exposure_from_refuses_a_bad_report(tmp_path: Path, content: str | None, match: str,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "rep.json"
    if content is not None:
        report.write_text(content)
    out = tmp_path / "o" / "r.exr"
    assert render(out, "--exposure-from", str(report)) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "--exposure-from" in line and match in line
    assert files_in(tmp_path / "o") == []


# ----------------------------------------------------------------------------------------------------------
# bad input: exit 2, one line on stderr naming the input, nothing written


BAD_ARGS = [
    (["--spp", "0"], "--spp"),
    (["--spp", "-3"], "--spp"),
    (["--spp", "abc"], "--spp"),
    (["--size", "0x10"], "--size"),
    (["--size", "16x0"], "--size"),
    (["--size", "abc"], "--size"),
    (["--size", "16x16x16"], "--size"),
    (["--size", ""], "--size"),
    (["--g", "2"], "--g"),
    (["--g", "-1.5"], "--g"),
    (["--g", "nan"], "--g"),
    (["--g", "forward"], "--g"),
    (["--out", "{tmp}/x.tiff"], "--out"),
    (["--exposure", "1", "--exposure-from", "{tmp}/r.json"], "--exposure-from"),
    (["--out", "{tmp}/x"], "--out"),
    (["--scene", "teapot"], "teapot"),
    (["--scene", "{tmp}/missing.json"], "missing.json"),
    (["--threads", "0"], "--threads"),
    (["--threads", "100000"], "--threads"),
    (["--method", "magic"], "--method"),
    (["--step", "0"], "--step"),
    (["--method", "raymarch", "--level", "6"], "--level"),
    (["--method", "raymarch", "--level", "-1"], "--level"),
    (["--max-depth", "0"], "--max-depth"),
    (["--batch-size", "0"], "--batch-size"),
    (["--exposure", "nan"], "--exposure"),
    (["--seed", str(1 << 70)], "--seed"),
    (["--denoise", "magic"], "--denoise"),
    (["--denoise", "oidn", "--orbit", "2"], "--orbit"),
    (["--denoise", "wrls"], "--denoise wrls"),  # a sequence denoiser needs --orbit
    (["--bogus"], "--bogus"),
]


@pytest.mark.parametrize(("args", "needle"), BAD_ARGS, ids=[" ".join(a) for a, _ in BAD_ARGS])
def test_bad_input_exits_2_with_one_line(
    tmp_path: Path, args: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out_dir = tmp_path / "out"
    argv = ["--scene", "blobs", "--size", "16x16", "--spp", "1", "--quiet", "--out", str(out_dir / "r.exr")]
    argv += [a.replace("{tmp}", str(out_dir)) for a in args]  # later options win
    assert _main(argv) == 2
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    assert needle in line, line
    assert captured.out == ""
    assert files_in(out_dir) == []  # not even the folder's contents
    assert files_in(tmp_path) == []


def test_orbit_denoised_with_wrls(tmp_path: Path, warm: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--orbit N --denoise wrls``: every frame's L denoised, the renderer's kept as L_noisy, and frame i rendered
    with seed --seed + i (a temporal denoiser needs fresh samples per frame): its L_noisy is, bit for bit, frame i
    of an undenoised orbit with --seed + i."""
    from photon_fields.runtime.renderers.orbit import orbit_frame_paths, orbit_noisy_png_path

    out = tmp_path / "wrls" / "f.exr"
    assert render(out, "--orbit", "3", "--orbit-degrees", "6", "--seed", "5", "--denoise", "wrls") == 0
    assert "denoised: wrls" in capsys.readouterr().out
    frames = orbit_frame_paths(out, 3)
    layers = [read_exr(f)[0] for f in frames]
    assert all(orbit_noisy_png_path(f).is_file() and f.with_suffix(".png").is_file() for f in frames)
    for frame in layers:
        assert set(frame) == LAYERS | {"L_noisy"}
        assert not np.array_equal(frame["L"], frame["L_noisy"])
    for i in (1, 2):
        plain = tmp_path / f"plain{i}" / "f.exr"
        assert render(plain, "--orbit", "3", "--orbit-degrees", "6", "--seed", str(5 + i)) == 0
        assert np.array_equal(read_exr(orbit_frame_paths(plain, 3)[i])[0]["L"], layers[i]["L_noisy"]), i
    timings = json.loads((tmp_path / "wrls" / "f_timings.json").read_text())
    assert timings["denoiser"]["name"] == "wrls" and len(timings["denoiser"]["denoise_ms"]) == 3
    assert (timings["seed"], timings["seeds"], timings["method"]) == (5, "seed + frame index", "pt")


def test_unknown_scene_lists_builtins(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _main(["--scene", "teapot", *TINY, "--out", str(tmp_path / "r.exr")]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert all(name in line for name in BUILTIN_SCENES)


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ('{"volume": ', "JSON"),
        (
            json.dumps(
                {
                    "volume": {"builtin": "blobs", "resolution": 16},
                    "transfer_function": {"preset": "cloud"},
                    "lights": [{"type": "point", "position": [1, 1, 1], "power": -1}],
                    "camera": {"eye": [1, 1, 1], "target": [0, 0, 0]},
                }
            ),
            "lights[0] power",
        ),
        (
            json.dumps(
                {
                    "volume": {"builtin": "blobs", "resolution": 16},
                    "transfer_function": {"preset": "cloud"},
                    "lights": [],
                    "camera": {"eye": [1, 1, 1], "target": [0, 0, 0]},
                }
            ),
            "lights",
        ),
        (
            json.dumps(
                {
                    "volume": {"path": "nope.npy"},
                    "transfer_function": {"preset": "cloud"},
                    "lights": [{"type": "environment"}],
                    "camera": {"eye": [1, 1, 1], "target": [0, 0, 0]},
                }
            ),
            "nope.npy",
        ),
    ],
)
def test_bad_scene_file(tmp_path: Path, content: str, needle: str, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "scene_in" / "bad.json"
    scene.parent.mkdir()
    scene.write_text(content)
    out_dir = tmp_path / "out"
    assert _main(["--scene", str(scene), *TINY, "--out", str(out_dir / "r.exr")]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert needle in line and ("bad.json" in line or needle.endswith(".npy")), line
    assert files_in(out_dir) == []


def test_nan_volume_in_scene_file(tmp_path: Path, tiny_scene: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = np.ones((16, 16, 16))
    data[1, 2, 3] = np.nan
    np.save(tmp_path / "ball.npy", data)
    scene = tmp_path / "nan_scene.json"
    scene.write_text(tiny_scene.read_text())  # same scene, but next to the NaN volume
    assert _main(["--scene", str(scene), *TINY, "--out", str(tmp_path / "out" / "r.exr")]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "ball.npy" in line and "non-finite" in line
    assert files_in(tmp_path / "out") == []


@pytest.mark.parametrize("bad", [["--g", "2"], ["--scene", "teapot"], ["--spp", "0"], ["--size", "0x0"]])
def test_failed_render_keeps_old_outputs(
    tmp_path: Path, warm: Path, bad: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "keep.exr"
    old = {}
    for suffix in (".exr", ".png", ".json"):
        shutil.copyfile(warm.with_suffix(suffix), out.with_suffix(suffix))
        old[suffix] = out.with_suffix(suffix).read_bytes()
    assert render(out, *bad) == 2
    one_error_line(capsys.readouterr().err)
    for suffix, content in old.items():
        assert out.with_suffix(suffix).read_bytes() == content, suffix
    assert files_in(tmp_path) == ["keep.exr", "keep.json", "keep.png"]  # no temporary files left


def test_folder_in_the_way_fails_before_rendering(
    tmp_path: Path, warm: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "r.exr"
    shutil.copyfile(warm, out)
    (tmp_path / "r.png").mkdir()  # the PNG preview cannot be written
    assert render(out) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "r.png" in line
    assert out.read_bytes() == warm.read_bytes()  # the old EXR was not replaced by a half-written set
    assert not (tmp_path / "r.json").exists()


def test_out_folder_cannot_be_created(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").write_text("I am a file")
    assert render(tmp_path / "file" / "r.exr") == 2
    line = one_error_line(capsys.readouterr().err)
    assert "--out" in line and "file" in line


def test_help_mentions_method(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        _main(["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "--method" in text and "raymarch" in text and "--spp" in text


# ----------------------------------------------------------------------------------------------------------
# the installed console script, as a real process


def _console_script() -> str:
    exe = Path(sys.executable).parent / "pfn-render"
    found = str(exe) if exe.is_file() else shutil.which("pfn-render")
    if found is None:
        pytest.skip("the pfn-render console script is not installed (pip install -e .)")
    return found


def _run(args: list[str], cwd: Path, **env_vars: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONWARNINGS": "ignore", **env_vars}
    return subprocess.run(
        [_console_script(), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300, check=False
    )


def test_console_script_success(tmp_path: Path, warm: Path) -> None:
    proc = _run(["--scene", "blobs", *TINY, "--seed", "3", "--out", "sub/r.exr"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert files_in(tmp_path / "sub") == ["r.exr", "r.json", "r.png"]
    # a separate process gives the same image as the in-process render
    a, _ = read_exr(warm)
    b, _ = read_exr(tmp_path / "sub" / "r.exr")
    assert all(np.array_equal(a[n], b[n]) for n in LAYERS)


def test_progress_in_a_log_is_plain_lines(tmp_path: Path) -> None:
    """stderr is a pipe here, as in a log file or CI: progress comes as plain lines (one per update with
    PFN_PROGRESS_SECONDS=0), never tqdm's carriage-return redraws."""
    args = ["--scene", "blobs", "--size", "16x16", "--spp", "2", "--batch-size", "128", "--out", "r.exr"]
    proc = _run(args, tmp_path, PFN_PROGRESS_SECONDS="0")
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert any(re.fullmatch(r"path tracing: \d+% \([\d.]+k?/512 spl\), [\d.]+ s, ~[\d.]+ s left", ln) for ln in lines)
    assert any(re.fullmatch(r"path tracing: done, 512 spl in [\d.]+ s", ln) for ln in lines)


def test_console_script_bad_input(tmp_path: Path) -> None:
    proc = _run(["--scene", "blobs", *TINY, "--g", "2", "--out", "r.exr"], tmp_path)
    assert proc.returncode == 2
    line = one_error_line(proc.stderr)
    assert "--g" in line
    assert proc.stdout == ""
    assert files_in(tmp_path) == []
    proc = _run(["--spp", "many"], tmp_path)  # an argparse type error is one line too
    assert proc.returncode == 2 and "--spp" in one_error_line(proc.stderr)


def test_ctrl_c_inside_a_numba_call_is_an_interrupt(capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C during a numba kernel call reaches Python as a SystemError caused (through more SystemErrors) by the
    KeyboardInterrupt: still 'error: interrupted' and status 130, not a traceback; any other SystemError is raised."""
    from photon_fields.runtime.cli.common import guarded

    def interrupted_in_a_kernel(argv: object) -> int:
        try:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise SystemError("<function _numba_unpickle> returned a result with an exception set") from exc
        except SystemError as exc:
            raise SystemError("CPUDispatcher(<function _camera_rays>) returned a result with an exception set") from exc

    assert guarded(interrupted_in_a_kernel)(None) == 130
    assert capsys.readouterr().err == "error: interrupted\n"

    def broken(argv: object) -> int:
        raise SystemError("a real one")

    with pytest.raises(SystemError, match="a real one"):
        guarded(broken)(None)
