"""runtime/compile_notice.py: one line at the first real compile, none when every kernel comes from the cache."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from numba import njit

from photon_fields.runtime.compile_notice import MESSAGE, announce_compiles


def test_one_line_at_the_first_compile_and_none_for_a_kernel_already_compiled() -> None:
    lines: list[str] = []
    announce_compiles(lines.append)
    first = njit(lambda x: x + 1)
    second = njit(lambda x: x * 2)
    assert first(1) == 2 and lines == [MESSAGE]
    assert second(2) == 4 and lines == [MESSAGE]  # once per process
    quiet: list[str] = []
    announce_compiles(quiet.append)
    assert first(3) == 4 and quiet == []  # an overload already compiled: nothing compiles


@pytest.mark.parametrize("quiet", [False, True])
def test_pfn_render_announces_a_compile_unless_quiet(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch, quiet: bool) -> None:
    """The command registers the notice before it renders (a kernel compiled inside the render is announced on stderr,
    once), and ``--quiet`` registers none."""
    from photon_fields.runtime.cli.render import _main
    from photon_fields.runtime.renderers.registry import Renderer

    original = Renderer.render_function

    def compiling(self: Renderer) -> Callable[..., Any]:
        render = original(self)

        def wrapped(*args: Any, **kwargs: Any) -> Any:
            assert njit(lambda x: x - 1)(1) == 0  # a new kernel: compiled now
            return render(*args, **kwargs)

        return wrapped

    monkeypatch.setattr(Renderer, "render_function", compiling)
    argv = ["--scene", "blobs", "--size", "4x4", "--spp", "1", "--no-resident", "--out", str(tmp_path / "a.exr")]
    assert _main(argv + (["--quiet"] if quiet else [])) == 0
    err = capsys.readouterr().err
    assert err.count(MESSAGE) == (0 if quiet else 1)
    if not quiet:
        assert f"pfn-render: {MESSAGE}" in err
