"""The renderer registry is the one place pfn-render learns its methods from: every entry resolves to a
render function with the common signature, every option's default is that function's own default, and the
command line offers exactly the registry's methods and flags."""

from __future__ import annotations

import inspect

import pytest

from photon_fields.runtime.cli.render import build_parser, renderer_options
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER, DEFAULT_MIN_TRANSMITTANCE, INPUTS, RENDERERS

COMMON = ("spp", "seed", "batch_size", "progress")
INPUT_KEYWORDS = {"map": ("pmap", "force"), "bundle": ("estimator",)}


@pytest.mark.parametrize("name", list(RENDERERS))
def test_entry_matches_its_render_function(name: str) -> None:
    renderer = RENDERERS[name]
    params = inspect.signature(renderer.render_function()).parameters
    assert list(params)[0] == "scene"
    for keyword in COMMON:
        assert keyword in params, f"{name}: render function lacks the common keyword {keyword!r}"
    for opt in renderer.options:
        assert opt.keyword in params, f"{name}: {opt.flag} sets {opt.keyword!r}, which the function does not take"
        if opt.type is not None:  # switches are inverted (--no-nee -> nee), their default is False on the CLI
            assert params[opt.keyword].default == opt.default, f"{name}: {opt.flag} default differs from the function's"
        else:
            assert opt.value(False) == params[opt.keyword].default
    assert renderer.input is None or renderer.input in INPUTS
    for keyword in INPUT_KEYWORDS.get(renderer.input or "", ()):
        assert keyword in params
    assert renderer.render_function().__doc__, f"{name}: the render function has no docstring"


def test_command_line_offers_exactly_the_registry() -> None:
    parser = build_parser()
    method = next(a for a in parser._actions if a.dest == "method")
    assert list(method.choices) == list(RENDERERS)
    flags = {s for a in parser._actions for s in a.option_strings}
    for renderer in RENDERERS.values():
        for opt in renderer.options:
            assert opt.flag in flags
    for flag, _ in INPUTS.values():
        assert flag in flags


def test_options_reach_only_their_renderer_and_are_all_checked() -> None:
    parser = build_parser()
    args = parser.parse_args(["--method", "pt", "--max-depth", "3", "--no-nee", "--step", "2", "--shadow-step", "0.25"])
    assert renderer_options(args, "pt") == {"max_depth": 3, "nee": False}
    assert renderer_options(args, "raymarch") == {"step": 2.0, "max_step": None, "shadow_step": 0.25,
                                                  "shadows": "volume", "light_grid_scale": None,
                                                  "min_transmittance": DEFAULT_MIN_TRANSMITTANCE, "level": 0}
    assert renderer_options(args, "field") == {"camera": "auto", "light_sampling": "one",
                                               "final_gather_after": DEFAULT_GATHER_AFTER}
    delta = parser.parse_args(["--method", "field", "--camera-estimator", "delta", "--final-gather-after", "0",
                               "--light-sampling", "all"])
    assert renderer_options(delta, "field") == {"camera": "delta", "light_sampling": "all",  # shared with photonmap
                                                "final_gather_after": 0}
    assert renderer_options(delta, "photonmap")["camera"] == "delta"
    assert renderer_options(delta, "photonmap")["final_gather_after"] == 0
    assert renderer_options(delta, "photonmap")["light_sampling"] == "all"
    never = parser.parse_args(["--method", "field", "--final-gather-after", "never"])
    assert renderer_options(never, "field")["final_gather_after"] is None
    bad = parser.parse_args(["--method", "pt", "--k", "0"])
    with pytest.raises(InputError, match="--k"):
        renderer_options(bad, "pt")
