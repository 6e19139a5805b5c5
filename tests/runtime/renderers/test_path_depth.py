"""What ``max_depth`` means, for every light kind and both estimators: the image holds exactly the light
of paths with 1 .. ``max_depth`` scattering vertices.

The independent estimator for the environment is pure phase sampling (no NEE: it reaches the environment
only by escaping), compared with NEE + MIS at depths 1, 2 and the default, layer by layer (block z-scores
over seeds). Delta lights are reachable only by NEE; for them (and the environment) single scattering is
the same whatever else follows, so L_d at depth 1 and 2 must equal L_d at the default depth, and the ray
marcher (tests/runtime/renderers/test_path_tracer.py) checks depth 1 against quadrature. A light outside the box, a
coloured, density-dependent albedo and an anisotropic phase (g = -0.4) keep the cases general.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_estimates_agree, mean_and_error, small_camera, smooth_field

from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, PointLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume

DEFAULT_DEPTH = 16


def _coloured_tf() -> TransferFunction:
    """Albedo differs per channel and with density; extinction ramps with density."""
    return TransferFunction(np.array([0.0, 0.5, 1.0]), np.array([[0.95, 0.6, 0.3], [0.5, 0.9, 0.7], [0.8, 0.7, 0.98]]),
                            np.array([0.0, 0.6, 1.0]), 9.0, "coloured")


def _scene(light: object, g: float = -0.4) -> Scene:
    vol = make_volume(smooth_field(20), window=(0.0, 1.0), name="smooth")
    return Scene(vol, _coloured_tf(), (light,), small_camera(18), g, "depth")


def _stats(scene: Scene, seeds: range, **kw: object) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per layer: block means over independent renders, (mean, standard error)."""
    renders = [render_path_traced(scene, seed=s, progress=False, **kw).layers for s in seeds]
    return {layer: mean_and_error([r[layer] for r in renders]) for layer in ("L_d", "L_i")}


@pytest.mark.parametrize("depth", [1, 2, DEFAULT_DEPTH])
def test_environment_nee_and_phase_sampling_agree_at_every_depth(depth: int) -> None:
    """The environment cut at ``max_depth``: NEE + MIS must equal pure phase sampling per layer. Before
    the last vertex took the full NEE weight, depth 1 gave ~35 % of the single-scattering image."""
    scene = _scene(EnvironmentLight([0.9, 1.0, 1.1], 1.0))
    nee = _stats(scene, range(10), spp=8, max_depth=depth, nee=True)
    phase = _stats(scene, range(100, 110), spp=8, max_depth=depth, nee=False)
    for layer in ("L_d", "L_i"):
        assert_estimates_agree(nee[layer], phase[layer], f"{layer} at depth {depth}")
    if depth == 1:
        assert nee["L_i"][0].max() == 0.0 and phase["L_i"][0].max() == 0.0  # single scattering: no L_i
    else:
        assert nee["L_i"][0].mean() > 0.05 * nee["L_d"][0].mean()


LIGHTS = {
    "environment": EnvironmentLight([0.9, 1.0, 1.1], 1.0),
    "directional": DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0),
    "point outside the box": PointLight([1.4, 1.1, 0.9], [1.0, 1.0, 1.0], 4.0),
}


# Delta lights are reachable by NEE only, so pure phase sampling is checked with the environment alone.
@pytest.mark.parametrize(("name", "nee"), [*((name, True) for name in LIGHTS), ("environment", False)])
def test_single_scattering_does_not_depend_on_max_depth(name: str, nee: bool) -> None:
    """L_d is the light of one-vertex paths: cutting paths after 1 or 2 vertices must not change it."""
    scene = _scene(LIGHTS[name])
    full = _stats(scene, range(8), spp=8, max_depth=DEFAULT_DEPTH, nee=nee)["L_d"]
    for depth in (1, 2):
        cut = _stats(scene, range(200 + 10 * depth, 208 + 10 * depth), spp=8, max_depth=depth, nee=nee)["L_d"]
        assert_estimates_agree(cut, full, f"{name}: L_d at depth {depth} vs {DEFAULT_DEPTH}")


def test_depth_counts_vertices_without_nee() -> None:
    """``--no-nee`` with ``max_depth = 1`` is single scattering (it used to count one vertex less and
    give a black image), and depth 2 adds L_i."""
    scene = _scene(EnvironmentLight([1.0, 1.0, 1.0], 1.0))
    one = render_path_traced(scene, spp=4, max_depth=1, nee=False, seed=0, progress=False).layers
    two = render_path_traced(scene, spp=4, max_depth=2, nee=False, seed=0, progress=False).layers
    assert one["L_d"].mean() > 0.05 and one["L_i"].max() == 0.0
    assert two["L_i"].mean() > 0.0
