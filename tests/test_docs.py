"""The documentation's references to the test suite and the developer tools point at things that exist."""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_cited_test_files_exist() -> None:
    """Docstrings and docs cite the tests that back their claims by path; each cited file must exist (one
    cited a file that never did)."""
    sources = [*ROOT.glob("runtime/**/*.py"), *ROOT.glob("train/**/*.py"), *ROOT.glob("models_spec/*.py"),
               *ROOT.glob("bench/*.py"), *ROOT.glob("tests/**/*.py"), *ROOT.glob("docs/*.md"), *ROOT.glob("*.md"),
               *ROOT.glob("bench/*.md")]
    cited = {(src.relative_to(ROOT), m) for src in sources
             for m in re.findall(r"tests/(?:\w+/)*test_\w+\.py", src.read_text(encoding="utf-8"))}
    assert len(cited) > 10
    missing = sorted(f"{src} cites {name}" for src, name in cited if not (ROOT / name).is_file())
    assert not missing, missing


def test_mutation_check_table_applies() -> None:
    """Every mutant of bench/mutants.py still finds its original text exactly once and names tests that
    exist (running the mutants is a benchmark: ~1 min each)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("mutants", ROOT / "bench" / "mutants.py")
    assert spec is not None and spec.loader is not None
    mutants = importlib.util.module_from_spec(spec)
    sys.modules["mutants"] = mutants  # dataclasses look their module up there
    try:
        spec.loader.exec_module(mutants)
    finally:
        del sys.modules["mutants"]
    assert len(mutants.MUTANTS) >= 4
    for m in mutants.MUTANTS:
        assert mutants.check_mutant(ROOT, m) is None, m.name
        for node in m.tests:
            path, _, name = node.partition("::")
            func = name.split("[")[0]
            assert re.search(rf"^def {func}\(", (ROOT / path).read_text(), re.MULTILINE), node


def test_cli_help_names_every_builtin_scene() -> None:
    """A CLI's help that lists the builtin scenes lists all of them (pfn-train's listed three of four)."""
    from photon_fields.runtime.cli.render import build_parser as render_parser
    from photon_fields.runtime.scene.scene import BUILTIN_SCENES
    from photon_fields.runtime.viewer.cli import build_parser as view_parser
    from photon_fields.train.cli.train import build_parser as train_parser

    def actions(parser):  # the parser's arguments, its subcommands' included
        for action in parser._actions:
            yield action
            if isinstance(action.choices, dict):  # subcommands
                for sub in action.choices.values():
                    yield from actions(sub)

    lists = [(a.dest, m) for parser in (render_parser(), view_parser(), train_parser()) for a in actions(parser)
             for m in re.findall(r"builtin scenes? (?:name )?\(([a-z, ]+)\)", a.help or "")]
    assert len(lists) >= 3
    wrong = [(dest, names) for dest, names in lists if set(names.split(", ")) != set(BUILTIN_SCENES)]
    assert not wrong, wrong
