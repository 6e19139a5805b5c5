"""FitSettings and the presets: one source of defaults, every field documented, bad values refused."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

pytest.importorskip("torch")

from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.train.fit import presets as presets_module  # noqa: E402
from photon_fields.train.fit import settings as settings_module  # noqa: E402
from photon_fields.train.fit.presets import DEFAULT_PRESET, PRESETS  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402


def test_defaults_are_the_default_preset() -> None:
    assert FitSettings() == FitSettings.from_preset(DEFAULT_PRESET)
    preset = PRESETS[DEFAULT_PRESET]
    s = FitSettings()
    assert (s.steps, s.batch, s.lr, s.schedule_kind, s.sampling, s.loss, s.k, s.average, s.g_sampling) == (
        preset.steps, preset.batch, preset.lr, preset.schedule, preset.sampling, preset.loss, preset.k, preset.average,
        preset.g_sampling)
    assert FitSettings.from_preset("cpu-tent").g_sampling == "continuous"
    assert FitSettings.from_preset("paper").loss == "log"  # the paper's loss, as published


@pytest.mark.parametrize("name", list(PRESETS))
def test_from_preset_takes_the_preset_and_overrides(name: str) -> None:
    p = PRESETS[name]
    s = FitSettings.from_preset(name, steps=7, lr=None)
    assert s.preset == name and s.steps == 7 and s.lr == p.lr and s.batch == p.batch
    s.validate()


def _undocumented_fields(path: Path, cls: str) -> list[str]:
    """Annotated class attributes not followed by a docstring (the nerfstudio convention)."""
    tree = ast.parse(path.read_text())
    node = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls)
    missing = []
    for stmt, after in zip(node.body, [*node.body[1:], None], strict=True):
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            documented = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and \
                isinstance(after.value.value, str)
            if not documented:
                missing.append(stmt.target.id)
    return missing


@pytest.mark.parametrize(("module", "cls"), [(presets_module, "Preset"), (settings_module, "FitSettings")])
def test_every_field_has_a_docstring(module, cls: str) -> None:  # noqa: ANN001
    assert _undocumented_fields(Path(module.__file__), cls) == []
    assert dataclasses.fields(getattr(module, cls))


@pytest.mark.parametrize(("change", "option"), [({"steps": 0}, "--steps"), ({"lr": float("nan")}, "--lr"),
                                                 ({"schedule_kind": "fast"}, "--schedule"),
                                                 ({"sampling": "grid"}, "--sampling"), ({"loss": "l1"}, "--loss"),
                                                 ({"preset": "huge"}, "--preset")])
def test_validate_names_the_option(change: dict, option: str) -> None:
    with pytest.raises(InputError) as info:
        dataclasses.replace(FitSettings(), **change).validate()
    assert info.value.what == option
