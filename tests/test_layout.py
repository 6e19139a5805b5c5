"""The package layout: one photon_fields namespace over the three fixed folders, every package installed,
imports pointing one way, the OpenMP default set in one place, and the README's Python imports resolving."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys

import pytest
from conftest import REPO

FOLDERS = {"photon_fields": "api", "photon_fields.runtime": "runtime", "photon_fields.train": "train",
           "photon_fields.models_spec": "models_spec"}


def test_every_package_folder_is_installed() -> None:
    """pyproject.toml lists packages explicitly (package-dir maps the fixed folders into the namespace): a
    new subpackage missing from the list would be left out of a wheel."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib is in the standard library from Python 3.11")
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert config["package-dir"] == FOLDERS
    folders = {package + "".join(f".{part}" for part in init.relative_to(REPO / folder).parts[:-1])
               for package, folder in FOLDERS.items() for init in (REPO / folder).rglob("__init__.py")}
    assert set(config["packages"]) == folders


def _imports(path: os.PathLike) -> set[str]:
    with open(path) as f:
        tree = ast.parse(f.read())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def test_imports_point_one_way() -> None:
    """runtime -> models_spec; train -> runtime, models_spec; models_spec -> itself. The runtime never
    imports torch or train (nor does api/, the package photon_fields itself), and nothing imports the old
    top-level names."""
    for top in FOLDERS.values():
        for path in (REPO / top).rglob("*.py"):
            for name in _imports(path):
                assert not re.match(r"(runtime|train|models_spec)(\.|$)", name), (path, name)
                if top in ("runtime", "api"):
                    assert not name.startswith(("photon_fields.train", "torch")), (path, name)
                if top == "models_spec":
                    assert not name.startswith(("photon_fields.runtime", "photon_fields.train", "torch")), (path, name)


def test_openmp_default_is_set_by_the_package_and_a_user_setting_wins() -> None:
    code = "import os, photon_fields.{}; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    for pkg in ("runtime", "train"):
        out = subprocess.run([sys.executable, "-c", code.format(pkg)], env=env, capture_output=True, text=True,
                             check=True).stdout.strip()
        assert out == "PASSIVE", pkg
    out = subprocess.run([sys.executable, "-c", code.format("runtime")], env={**env, "OMP_WAIT_POLICY": "ACTIVE"},
                         capture_output=True, text=True, check=True).stdout.strip()
    assert out == "ACTIVE"


def test_readme_python_imports_resolve() -> None:
    """Every ``from photon_fields... import name`` in the README's Python examples names a real object."""
    import importlib

    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks
    found = 0
    for block in blocks:
        for module, names in re.findall(r"^from (photon_fields[\w.]*) import ([\w, ]+)$", block, flags=re.M):
            mod = importlib.import_module(module)
            for name in (n.strip() for n in names.split(",")):
                assert hasattr(mod, name), f"README: {module} has no {name}"
                found += 1
        assert not re.search(r"^(from|import) (runtime|train|models_spec)\b", block, flags=re.M), block
    assert found >= 5
