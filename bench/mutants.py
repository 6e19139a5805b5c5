"""Mutation check: plant known, plausible bugs one at a time and check that the tests named for each catch it.

Each mutant in :data:`MUTANTS` is an exact text replacement in one file plus the pytest node ids that must fail
with it. For every mutant the script

1. copies the repository (``git ls-files``: tracked files plus untracked, not ignored ones, as they are in the
   working tree) to a fresh temporary folder;
2. applies the replacement, refusing (exit 2, before anything runs) when the original text does not occur
   exactly once: after a refactor the table must be updated, it never passes silently;
3. runs the named tests there with this interpreter (the project's ``.venv``), ``PYTHONPATH`` at the copy and
   ``NUMBA_CACHE_DIR`` at a fresh empty folder (numba's ``cache=True`` does not recompile a caller in another
   module when an ``inline="always"`` kernel it uses changes, so a shared cache could hide a mutant);
4. reports **killed** (some named test failed or errored), **survived** (all passed) or **error** (pytest could
   not run them: usage error, no tests collected; or the timeout).

Before the mutants, the same tests run once on an unmodified copy and must pass (otherwise "killed" would mean
nothing), and every run first checks that ``photon_fields.runtime``, ``.train``, ``.models_spec`` and the tests
are imported from the copy, not from the editable install. Results: a table on stdout and ``bench/results/mutants.json``
(per mutant: status, the tests that failed, seconds; the machine: CPU model and ISA, cores, versions). Exit
status 1 if any mutant survived or errored.

Usage::

    .venv/bin/python bench/mutants.py                       # every mutant (~1-2 min each on 2 cores)
    .venv/bin/python bench/mutants.py --only default_psi li_without_albedo
    .venv/bin/python bench/mutants.py --list                # the table, nothing run
    .venv/bin/python bench/mutants.py --check               # only check that every original text is found

Adding a mutant: append a :class:`Mutant` to :data:`MUTANTS` with the file, the exact original text (a whole
line or a unique fragment of one; indentation included if the replacement spans lines), its replacement, the
node ids of the tests that must catch it (``tests/test_<file>.py::test_<name>[<param>]``) and a sentence on the bug.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "bench" / "results" / "mutants.json"
LIGHTS = "tests/runtime/photons/test_light_kinds.py::test_photon_map_li_matches_path_tracer_per_light_kind"
EMITTERS = "tests/runtime/transport/test_emitters.py"
TRACING = "tests/train/photons/test_photon_tracing.py"
CAMERA = "tests/runtime/wavefront/test_camera_estimators.py"
CHOICE = "tests/runtime/wavefront/test_camera_choice.py"
DEPTH = "tests/runtime/wavefront/test_depth_bounds.py"
VSESSION = "tests/runtime/viewer/test_viewer_session.py"
GATHER = "tests/runtime/wavefront/test_final_gather.py"
VGATHER = "tests/runtime/viewer/test_viewer_gather.py"
VLABELS = "tests/runtime/viewer/test_viewer_labels.py"
UPDATE = "tests/train/fit/test_update.py"
LABELS_MEDIUM = "tests/runtime/transport/test_labels_medium.py"
ENVMAP = "tests/runtime/transport/test_environment_map.py"
LSAMPLING = "tests/runtime/transport/test_light_sampling.py"
ENVRENDER = "tests/runtime/renderers/test_environment_map_render.py"
PVRT_CLI = "tests/train/cli/test_pvrt_cli.py"
PVRT_PT = "tests/runtime/pvrt/test_pvrt_vs_path_tracer.py"
PVRT_BASIS = "tests/runtime/pvrt/test_pvrt_basis_and_file.py"
PVRT_MARCH = "tests/runtime/pvrt/test_pvrt_march.py"
RAY_MARCHER = "tests/runtime/renderers/test_ray_marcher.py"
PVRT_DIRECT = "tests/runtime/pvrt/test_pvrt_direct.py"
VPVRT = "tests/runtime/viewer/test_viewer_pvrt.py"


@dataclass(frozen=True)
class Mutant:
    name: str
    file: str  # relative to the repository root
    original: str  # exact text, found exactly once in the file
    replacement: str
    tests: tuple[str, ...]  # pytest node ids; at least one must fail
    bug: str  # what the mutant plants


MUTANTS: tuple[Mutant, ...] = (
    # The four planted in issue 11, section 6.
    Mutant("point_cone_fraction", "runtime/transport/emitters.py",
           "flux[i] = 4 * math.pi * rgb[i] * (1.0 - cos_max[i]) / 2.0", "flux[i] = 4 * math.pi * rgb[i]",
           (f"{LIGHTS}[point_outside]",
            f"{TRACING}::test_distant_point_light_carries_the_power_of_a_directional_light"),
           "point-light photons keep the full 4 pi I although only the cone towards the volume is sampled "
           "(5.2x too strong for a light at distance 1.1)"),
    Mutant("default_psi", "runtime/field/field.py",
           "L = decode_lights(Lp, self.config.psi, self.light_channels, scale)",
           "L = decode_lights(Lp, 5.0, self.light_channels, scale)",
           ("tests/runtime/field/test_bundle.py::test_bundle_decodes_with_its_own_psi",
            "tests/runtime/field/test_bundle.py::test_fit_records_its_psi_and_the_bundle_decodes_with_it"),
           "the runtime decodes Eq. 7 with the default psi = 5 instead of the bundle's"),
    Mutant("li_without_albedo", "runtime/wavefront/first_interaction.py",
           'splat_runs(film, "L_i", fi.pixel, q, distinct, throughput, run)',
           'splat_runs(film, "L_i", fi.pixel, q, distinct, throughput / fi.albedo, run)',
           (f"{LIGHTS}[point_outside]", f"{LIGHTS}[directional]", f"{LIGHTS}[environment]"),
           "L_i composed without the albedo at the camera vertex (neural and photon-map renderers)"),
    Mutant("hg_cos_sign", "runtime/transport/phase.py", "denom = 1.0 + g * g - 2.0 * g * cos_theta",
           "denom = 1.0 + g * g + 2.0 * g * cos_theta",
           ("tests/runtime/transport/test_phase.py::test_sampler_pdf_matches_eval",
            "tests/runtime/transport/test_phase.py::test_mean_cosine_equals_g",
            f"{LIGHTS}[directional]"),
           "Henyey-Greenstein evaluated with the cosine's sign flipped (g > 0 scatters backwards)"),
    # More plausible bugs in the same code.
    Mutant("env_photon_power", "runtime/transport/emitters.py", "flux[i] = rgb[i] * 4 * math.pi**2 * radius**2",
           "flux[i] = rgb[i] * 4 * math.pi * radius**2",
           ("tests/runtime/photons/test_photon_estimate.py::test_photon_map_white_furnace_under_an_environment_light",
            f"{LIGHTS}[environment]"),
           "environment photons carry 4 pi R^2 L (the sphere's area) instead of 4 pi^2 R^2 L (its flux)"),
    Mutant("point_cone_angle_uniform", "runtime/transport/emitters.py", "c = 1.0 - u1 * (1.0 - cos_max)",
           "c = math.cos(u1 * math.acos(cos_max))",
           (f"{EMITTERS}::test_point_light_outside_emits_uniformly_into_the_cone_that_subtends_the_sphere",
            f"{EMITTERS}::test_point_light_inside_emits_uniformly_over_the_whole_sphere"),
           "point-light photons sampled uniformly in the angle to the cone's axis instead of its cosine "
           "(too many along the axis)"),
    Mutant("disk_radius_uniform", "runtime/transport/emitters.py", "r = radius * math.sqrt(u1)", "r = radius * u1",
           (f"{EMITTERS}::test_directional_light_emits_parallel_rays_uniformly_over_a_disk_across_the_sphere",
            f"{EMITTERS}::test_environment_emits_uniform_directions_through_a_disk_across_the_sphere"),
           "directional and environment photons start uniformly in the disk's radius instead of its area "
           "(crowded at the centre)"),
    Mutant("env_emission_reuses_disk_numbers", "runtime/transport/emitters.py",
           "dx, dy, dz = sample_uniform_sphere(u3, u4)", "dx, dy, dz = sample_uniform_sphere(u1, u2)",
           (f"{EMITTERS}::test_environment_emits_uniform_directions_through_a_disk_across_the_sphere",),
           "environment photons draw their direction from the random numbers of their disk position, so "
           "the two are correlated (each alone is still uniform)"),
    Mutant("photon_weight_without_1_over_sigma", "runtime/photons/estimate.py",
           "weights[j, c] = (np.float64(power[i, c]) * scale[b]) / inv",
           "weights[j, c] = (np.float64(power[i, c]) * scale[b]) / 1.0",
           ("tests/runtime/photons/test_photon_estimate.py::test_photon_map_li_converges_to_path_tracer",
            f"{LIGHTS}[directional]"),
           "Eq. 5 without the 1 / sigma_t weight that turns collision density into radiance"),
    Mutant("estimate_ignores_record_floor", "runtime/photons/estimate.py",
           "pos, floor = self.pmap.position, self.pmap.record_floor", "pos, floor = self.pmap.position, 0.0",
           ("tests/train/photons/test_record_floor.py::test_records_with_a_floor_estimate_the_same_light",),
           "null records weighted as real ones (Phi / sigma_t): a map with a record floor too bright where "
           "sigma_t is a sliver of its majorant"),
    Mutant("null_records_anywhere", "runtime/transport/tracking.py",
           "if mode == _RECORD and u < floor and sigma > 0.0:", "if mode == _RECORD and u < floor * 2.0:",
           ("tests/train/photons/test_record_floor.py::test_records_with_a_floor_estimate_the_same_light",),
           "null records made twice as often as their weight assumes"),
    Mutant("phase_window_unnormalized", "runtime/photons/knn_radiance.py",
           "return np.int64(b0), np.int64(b1), 1.0 / total",
           "return np.int64(b0), np.int64(b1), 0.5",
           ("tests/runtime/photons/test_phase_window.py::test_windowed_photon_map_converges_to_path_tracer_between_bins",
            "tests/runtime/photons/test_phase_window.py::test_binned_index_is_the_union_of_the_kernels_bins"),
           "the kernel in g's bin weights do not sum to one: the windowed map is not a complete map"),
    Mutant("binned_row_drops_last_bin", "runtime/photons/knn.py",
           "b = np.int64(cell_start[(base + zb + 1) * nb])",
           "b = np.int64(cell_start[(base + zb + 1) * nb - 1])",
           ("tests/runtime/photons/test_knn.py::test_binned_grid_query_searches_every_bin",),
           "a row of a binned grid read up to its last cell's last bin but one: photons missing from plain queries"),
    Mutant("binned_search_drops_last_bin", "runtime/photons/knn.py",
           "b = np.int64(cell_start[key + bin_hi + 1])",
           "b = np.int64(cell_start[key + bin_hi])",
           ("tests/runtime/photons/test_phase_window.py::test_binned_index_is_the_union_of_the_kernels_bins",),
           "the binned index's search skips the last bin of g's kernel: a kernel lopsided towards lower g"),
    Mutant("window_g_uniform", "train/fit/targets.py",
           "u = 0.5 * (1.0 - np.cos(np.pi * u))",
           "u = u",
           ("tests/train/fit/test_field_training.py::"
            "test_window_g_has_the_arcsine_density_over_whole_windows_and_its_own_kernel",),
           "training g uniform over the window range: the ends, where L_i changes fastest, get too few samples"),
    Mutant("tent_columns_random_init", "train/field/network.py",
           "layers[0].weight[:, phase_end - cfg.phase_dims + 1:phase_end] = 0.0",
           "layers[0].weight[:, phase_end - cfg.phase_dims + 1:phase_end] *= 1.0",
           ("tests/train/fit/test_field_training.py::test_tent_columns_start_at_zero",),
           "the tent columns keep their random initial weights: a random offset, and a dip in L, at every node"),
    Mutant("targets_pool_reused", "train/fit/targets.py",
           "self._pool_next += n",
           "self._pool_next += 0",
           ("tests/train/fit/test_field_training.py::test_batches_come_fresh_from_targets_estimated_ahead",),
           "every step trains on the same pooled batch instead of fresh samples"),
    Mutant("targets_beside_keep_the_old_radius", "train/fit/targets.py",
           "            if drawn_at != radius:",
           "            if False:",
           ("tests/train/fit/test_field_training.py::test_targets_beside_the_training_are_the_same_batches",),
           "the worker's pool, drawn at the radius the schedule has left, is used as it is: targets at the old radius"),
    Mutant("targets_beside_drop_the_computed_pool", "train/fit/targets.py",
           "        if self._ahead is not None and self._ahead.cancelled():",
           "        if self._ahead is not None:",
           ("tests/train/fit/test_field_training.py::test_targets_beside_the_training_are_the_same_batches",),
           "close() drops the worker's computed pool: the next refill draws past it and the stream changes"),
    Mutant("light_volume_fills_over_another_grid", "runtime/transport/light_volume.py",
           "    if lv.units.shape != m.majorant.shape:", "    if False:",
           ("tests/runtime/renderers/test_ray_marcher.py::"
            "test_a_fill_over_a_medium_of_another_macrocell_grid_is_refused",),
           "a fill over a medium of another macrocell grid reads the step units out of bounds (a hang, or garbage)"),
    Mutant("ray_marcher_terminates_late", "runtime/renderers/ray_marcher.py",
           "while t_prev < tmax and t_prev < t_far and t_min < T:",
           "while t_prev < tmax and t_prev < t_far and t_min * t_min < T:",
           ("tests/runtime/renderers/test_ray_marcher.py::"
            "test_early_termination_loses_what_scatters_behind_the_stopping_point",),
           "early ray termination at the square of the threshold: the preview marches on where it should stop"),
    Mutant("spline_ghost_node_dropped", "models_spec/encoding.py",
           "w[:, 0] += around[:, 0]",
           "w[:, 0] += 0.0 * around[:, 0]",
           ("tests/models_spec/test_encoding.py::test_phase_features_splines_are_smooth_cubic_b_spline_weights",
            "tests/models_spec/test_encoding.py::test_spline_weights_equal_b_at_every_node_bit_for_bit"),
           "the spline weights near min G lose the node outside G: they no longer sum to 1 there"),
    Mutant("spline_support_three_nodes", "models_spec/encoding.py",
           "nodes = first[:, None] + np.arange(4)[None, :]",
           "nodes = first[:, None] + np.arange(3)[None, :]",
           ("tests/models_spec/test_encoding.py::test_spline_weights_equal_b_at_every_node_bit_for_bit",),
           "the spline weights skip the fourth node of B's support: weights near every node are wrong"),
    Mutant("knn_phase_cos_sign", "runtime/photons/knn_radiance.py",
           "p = hg_eval(gi, -(dirs[j, 0] * vx + dirs[j, 1] * vy + dirs[j, 2] * vz))",
           "p = hg_eval(g[i], dirs[j, 0] * vx + dirs[j, 1] * vy + dirs[j, 2] * vz)",
           ("tests/runtime/photons/test_knn.py::test_radiance_phase_turns_photons_towards_the_camera",
            f"{LIGHTS}[point_outside]", f"{LIGHTS}[directional]"),
           "the photon estimate's phase cosine taken between the photon and the camera ray instead of the "
           "light's path towards the camera (invisible at g = 0)"),
    Mutant("first_collision_stored", "train/photons/tracing.py", "if c >= 2:  # Alg. 1",
           "if c >= 1:  # Alg. 1",
           (f"{TRACING}::test_stored_energy_matches_analytic_series", f"{LIGHTS}[directional]"),
           "photons recorded from their first collision, counting single scattering twice (NEE has it)"),
    Mutant("photon_roulette_not_reweighted", "runtime/photons/photon_path.py",
           "br, bg, bb = br * a0 / q, bg * a1 / q, bb * a2 / q", "br, bg, bb = br * a0, bg * a1, bb * a2",
           (f"{TRACING}::test_stored_energy_matches_analytic_series", f"{LIGHTS}[environment]"),
           "surviving photons not divided by the Russian-roulette survival probability"),
    Mutant("photon_albedo_channels_swapped", "runtime/photons/photon_path.py",
           "br, bg, bb = br * a0 / q, bg * a1 / q, bb * a2 / q", "br, bg, bb = br * a2 / q, bg * a1 / q, bb * a0 / q",
           (f"{LIGHTS}[point_outside]", f"{LIGHTS}[directional]", f"{LIGHTS}[environment]"),
           "red and blue albedo swapped along photon paths (invisible with a grey albedo)"),
    Mutant("nee_without_transmittance", "runtime/transport/direct_light.py", "ft = f * tr", "ft = f",
           ("tests/runtime/renderers/test_path_tracer.py::test_absorbing_furnace_loses_energy",
            "tests/runtime/renderers/test_path_tracer.py::test_ray_marcher_matches_single_scattering"),
           "next-event estimation ignores the shadow ray's transmittance"),
    Mutant("one_light_not_replayed", "runtime/transport/direct_light.py", "    state = start  # replay",
           "    pass  # replay",
           (f"{LSAMPLING}::test_one_light_and_every_light_have_one_mean[False]",
            f"{LSAMPLING}::test_one_light_and_every_light_have_one_mean[True]"),
           "one-light NEE draws an environment's direction again after choosing it by another one's contribution"),
    Mutant("one_light_chosen_by_power", "runtime/transport/direct_light.py",
           "return lx, ly, lz, lr, lg, lb, tend, f, f * (lr + lg + lb), state",
           "return lx, ly, lz, lr, lg, lb, tend, f, lr + lg + lb, state",
           (f"{LSAMPLING}::test_choice_follows_each_lights_unshadowed_contribution",),
           "one-light NEE chooses by the light's radiance alone (unbiased, but noisier: phase function ignored)"),
    Mutant("pt_roulette_not_reweighted", "runtime/renderers/path_tracer.py",
           "                beta[0, i] /= q\n                beta[1, i] /= q\n                beta[2, i] /= q\n",
           "                pass\n",
           ("tests/runtime/renderers/test_path_tracer.py::test_white_furnace",),
           "path-tracer survivors of Russian roulette not divided by the survival probability"),
    Mutant("pt_last_vertex_env_mis_share", "runtime/renderers/path_tracer.py",
           "add_direct_light(film, m, lights, scene.g, rays, last_vertex)",
           "add_direct_light(film, m, lights, scene.g, rays)",
           ("tests/runtime/renderers/test_path_depth.py::test_environment_nee_and_phase_sampling_agree_at_every_depth",
            "tests/runtime/renderers/test_path_depth.py::test_single_scattering_does_not_depend_on_max_depth"),
           "the path tracer's last vertex gives the environment's NEE only its MIS share, although no "
           "phase-sampled escape follows (the bug fixed in issue 11: 35 % of single scattering lost at depth 1)"),
    Mutant("support_correction_dropped", "runtime/photons/estimate.py",
           "est /= support_fraction(self.medium, xq, np.where(np.isfinite(r), r, 0.0), self._pattern)[:, None]",
           "pass",
           ("tests/runtime/photons/test_photon_estimate.py::test_photon_map_white_furnace_under_an_environment_light",
            "tests/runtime/photons/test_photon_estimate.py::test_photon_map_li_converges_to_path_tracer"),
           "the photon estimate's boundary correction (part of the search ball outside the medium) not applied"),
    Mutant("loss_in_log_space", "train/fit/loss.py",
           "        return linear_relative_l2_loss(pred, target, psi, lights)",
           "        return relative_l2_loss(pred, target)",
           ("tests/train/fit/test_loss.py::test_linear_loss_is_stationary_at_the_arithmetic_mean",),
           "the default loss averages targets in log space: fields converge to the geometric mean, dark"),
    Mutant("knn_counts_kth_photon", "runtime/photons/knn_radiance.py", "skip = kth if m >= k else -1.0", "skip = -1.0",
           ("tests/runtime/photons/test_knn.py::test_small_k_estimate_is_unbiased",),
           "the K-th photon, which only sets the radius, is summed too: estimates K / (K - 1) too bright"),
    Mutant("tent_columns_in_sorted_order", "models_spec/encoding.py", "out[:, 1 + j] = np.interp",
           "out[:, 1 + rank] = np.interp",
           ("tests/models_spec/test_encoding.py::test_phase_features_tents_interpolate_between_the_phases",),
           "the tent of a phase lands in the column of its rank among the sorted phases, not of its index in G"),
    Mutant("average_not_applied", "train/fit/loop.py", "                    average.apply()  # the field",
           "                    pass  # the field",
           ("tests/train/fit/test_field_training.py::test_averaging_changes_the_field_not_the_optimization",),
           "the parameter average is kept but never becomes the field: the last, noisy iterate is exported"),
    Mutant("forced_weight_dropped", "runtime/wavefront/first_interaction.py",
           "throughput = fi.albedo * fi.weight if forced else fi.albedo", "throughput = fi.albedo",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_i-forced]",),
           "the forced camera estimator's collisions are not weighted by the ray's collision probability"),
    Mutant("leap_one_cell_too_far", "runtime/transport/tracking.py", "                ix += sx * r\n",
           "                ix += sx * (r + 1)\n",
           ("tests/runtime/transport/test_leaping.py::test_leaping_changes_no_sample_on_embedded_scenes[vortex]",),
           "a leap over empty space lands one macrocell beyond the empty cube, skipping a cell that may hold medium"),
    Mutant("optical_depth_not_spent", "runtime/transport/tracking.py", "                    tau -= depth\n",
           "                    pass\n",
           ("tests/runtime/transport/test_transport.py::test_delta_and_ratio_tracking_agree_with_quadrature",),
           "the optical depth to the next tentative collision is not reduced by the macrocells the ray crosses"),
    Mutant("forced_score_after_update", "runtime/transport/tracking.py", "                    w = tr * sigma * inv_maj",
           "                    w = tr * (1.0 - sigma * inv_maj)",
           (f"{CAMERA}::test_resampled_collision_matches_delta_tracking_on_one_ray",),
           "the resampled collision scores each tentative collision with the null-collision factor"),
    Mutant("forced_environment_unweighted", "runtime/wavefront/first_interaction.py",
           "weight=np.broadcast_to(transmit[seen][None, :], (3, seen.shape[0])))", ")",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_e-forced]",),
           "the environment behind the volume is seen at full strength by every ray with a transmittance estimate"),
    Mutant("forced_roulette_unweighted", "runtime/transport/tracking.py", "        w = w_min\n",
           "",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_i-forced, roulette]",),
           "a low-weight collision that survives the roulette keeps its weight instead of the roulette's"),
    # pfn-train update (issue 16): refusals, warm start, correlated retrace, stopping, reproducibility.
    Mutant("update_other_volume", "train/fit/update.py",
           'if scene.fingerprint_parts()["volume"] != record.parts["volume"]:', "if False:",
           (f"{UPDATE}::test_refusals_are_one_line_and_leave_run_untouched",),
           "an update from a run of another volume is not refused: a field is fine-tuned for a volume it never saw"),
    Mutant("update_budget_unchecked", "train/fit/update.py", "or budget_s <= 0:", "or budget_s < -1e300:",
           (f"{UPDATE}::test_refusals_are_one_line_and_leave_run_untouched",),
           "a budget <= 0 is accepted (and silently exports the old field)"),
    Mutant("update_nothing_visible", "train/fit/update.py", "if not float(np.max(m.majorant)) > 0.0:", "if False:",
           (f"{UPDATE}::test_refusals_are_one_line_and_leave_run_untouched",),
           "an edit that leaves nothing visible is not refused before the run folder is created"),
    Mutant("update_into_run", "train/fit/update.py",
           "if dest.exists() and src.exists() and dest.resolve() == src.resolve():", "if False:",
           (f"{UPDATE}::test_out_equal_to_run_is_refused",),
           "--out RUN --force overwrites the run the update reads from"),
    Mutant("update_cold_start", "train/fit/update.py",
           'model, _ = load_checkpoint(src / "checkpoint.pt", expected_fingerprint=record.fingerprint)',
           'model, _ = load_checkpoint(src / "checkpoint.pt", expected_fingerprint=record.fingerprint)\n'
           "    model = type(model)(model.cfg, seed=seed)",
           (f"{UPDATE}::test_the_update_starts_from_runs_field",),
           "the update trains a freshly initialized field instead of RUN's"),
    Mutant("update_retrace_new_seed", "train/fit/update.py", "max_bounces=record.max_bounces, seed=seed,",
           "max_bounces=record.max_bounces, seed=seed + 1,",
           (f"{UPDATE}::test_retrace_is_correlated_with_runs_map",),
           "the retrace uses other random streams than RUN's map: the new map is not correlated with the old"),
    Mutant("update_ignores_plateau", "train/fit/fine_tune.py", "                        stopped = True\n",
           "                        pass\n", (f"{UPDATE}::test_stops_on_a_plateau_and_at_the_budget",),
           "the fine-tune runs to --max-steps although the validation error stopped improving"),
    Mutant("update_ignores_budget", "train/fit/fine_tune.py", "if time.perf_counter() >= deadline:", "if False:",
           (f"{UPDATE}::test_stops_on_a_plateau_and_at_the_budget",),
           "the fine-tune ignores the time budget"),
    Mutant("update_unseeded_sampler", "train/fit/loop.py", "psi=settings.psi, seed=settings.seed,",
           "psi=settings.psi, seed=time.perf_counter_ns(),", (f"{UPDATE}::test_same_seed_same_field",),
           "the training batches (of a fit and of the fine-tune: one sampler) do not follow the seed: two updates "
           "with one seed differ"),
    # Training points where cameras see the medium (issue 13, sampling="visible").
    Mutant("visible_disk_radius_uniform", "train/fit/visible_points.py",
           "r = radius * np.sqrt(rng.random(chunk))[:, None]", "r = radius * rng.random(chunk)[:, None]",
           ("tests/train/fit/test_visible_points.py::"
            "test_collisions_follow_the_density_of_first_collisions_of_uniform_lines",),
           "ray offsets uniform in radius instead of in area: lines crowd the volume's centre"),
    Mutant("visible_points_reversed", "train/fit/targets.py", "np.tile(dv, (VISIBLE_REUSE, 1))[:seen]",
           "np.tile(-dv, (VISIBLE_REUSE, 1))[:seen]",
           ("tests/train/fit/test_field_training.py::"
            "test_visible_sampling_mixes_seen_collisions_each_with_several_g_and_the_support",),
           "seen points paired with the opposite direction: the field learns the side no camera sees"),
    # The viewer (issue 15, step 1): session, messages, server.
    Mutant("viewer_preview_denoised", "runtime/renderers/registry.py",
           '"photon_fields.runtime.renderers.ray_marcher:render_ray_marched", MARCH_OPTIONS, noisy=False),',
           '"photon_fields.runtime.renderers.ray_marcher:render_ray_marched", MARCH_OPTIONS),',
           ("tests/runtime/viewer/test_viewer_preview.py::test_preview_frames_average_jittered_marches_and_stop",),
           "the viewer denoises the preview's jittered marches (and accumulates them to --max-spp)"),
    Mutant("viewer_edit_keeps_light_volume", "runtime/viewer/session.py",
           "lights=tuple(lt.light() for lt in s.lights), _cache={})",
           'lights=tuple(lt.light() for lt in s.lights), _cache={"light_volumes": '
           'self.base_scene.shared_cache("light_volumes")})',
           ("tests/runtime/viewer/test_viewer_preview.py::"
            "test_preview_follows_transfer_and_light_edits_with_the_edited_scenes_light_volume",),
           "an edited scene reads the light volume filled for the scene before the edit"),
    Mutant("light_edit_recomputes_step_grids", "runtime/scene/scene.py",
           'MEDIUM_CACHES = ("depth_bounds", "occupied_macrocells", "step_units")', "MEDIUM_CACHES = ()",
           ("tests/runtime/viewer/test_viewer_preview.py::test_a_light_edit_keeps_what_depends_on_the_medium_alone",),
           "a viewer's light edit computes the step grids and depth bounds of an unchanged medium again"),
    Mutant("light_edit_keeps_light_volumes", "runtime/scene/scene.py",
           'MEDIUM_CACHES = ("depth_bounds", "occupied_macrocells", "step_units")',
           'MEDIUM_CACHES = ("depth_bounds", "occupied_macrocells", "step_units", "light_volumes")',
           ("tests/runtime/viewer/test_viewer_preview.py::"
            "test_preview_follows_transfer_and_light_edits_with_the_edited_scenes_light_volume",
            "tests/runtime/viewer/test_viewer_preview.py::test_a_light_edit_keeps_what_depends_on_the_medium_alone"),
           "a viewer's light edit reads the light volume of the lights before it"),
    Mutant("viewer_camera_estimator_ignored", "runtime/viewer/session.py", "camera=s.camera_estimator)",
           "camera=None)",
           ("tests/runtime/viewer/test_viewer_camera_estimator.py::"
            "test_marched_frames_are_render_neurals_with_that_estimator",),
           "the viewer renders its neural frames with the default camera estimator whatever the page or the "
           "command line chose"),
    Mutant("viewer_auto_first_frame_waits", "runtime/viewer/field_in_use.py",
           "if camera == AUTO and n == 0 and made_choice(scene, est, LIGHT_OPTION.default) is None:",
           "if camera == AUTO and n < 0:",
           ("tests/runtime/viewer/test_viewer_camera_estimator.py::test_auto_does_not_hold_up_a_scenes_first_frame",),
           "the viewer's first frame of a scene waits for auto's probe (an edit's first image half a second later on "
           "a sparse scene at 512^2)"),
    Mutant("viewer_camera_estimator_keeps_samples", "runtime/viewer/set_controls.py",
           '"camera_estimator": (True, True, True, False),', '"camera_estimator": (False, True, True, False),',
           ("tests/runtime/viewer/test_viewer_camera_estimator.py::"
            "test_the_page_switches_the_estimator_and_the_accumulation_starts_again",),
           "switching the camera estimator keeps accumulating onto the other estimator's samples"),
    Mutant("viewer_same_samples", "runtime/viewer/field_in_use.py", "first_sample=n,", "first_sample=0,",
           (f"{VSESSION}::test_neural_accumulation_equals_one_render_with_all_samples",),
           "every progressive neural frame draws the same samples: the view never converges"),
    Mutant("viewer_transfer_not_stale", "runtime/viewer/field_in_use.py",
           "return not same_transfer(transfer, self.tf) or self.indirect_scale(lights, renderer) is None",
           "return self.indirect_scale(lights, renderer) is None",
           ("tests/runtime/viewer/test_viewer_transfer.py::"
            "test_an_edit_marks_the_fields_indirect_light_stale_until_undone",),
           "after a transfer-function edit the field's L_i is shown as if it were the edited scene's"),
    Mutant("viewer_retrain_without_rest", "runtime/viewer/updater.py",
           "start = wanted is not None and time.monotonic() - wanted_at >= self.settings.delay_s",
           "start = wanted is not None",
           ("tests/runtime/viewer/test_viewer_retrain.py::"
            "test_a_job_starts_once_edits_rest_and_a_newer_edit_replaces_it",),
           "every edit of a dragged control point starts (and kills) a training process"),
    Mutant("viewer_orbit_keeps_accumulating", "runtime/viewer/session.py",
           "            if restart:\n                self.generation += 1",
           "            if restart and msg.type != \"orbit\":\n                self.generation += 1",
           (f"{VSESSION}::test_camera_move_restarts_at_one_sample_and_newest_camera_wins",),
           "an orbit does not restart the accumulation: old views' samples smear into the new one"),
    Mutant("viewer_g_ignored", "runtime/viewer/set_controls.py", "        s.g = value", "        pass",
           (f"{VSESSION}::test_g_changes_the_indirect_layer_and_restarts",),
           "the g control is acknowledged but never reaches the renderer"),
    Mutant("viewer_screenshot_replaces", "runtime/viewer/screenshot.py",
           "existing = [p.name for p in paths if p.exists() or p.is_symlink()]", "existing = []",
           (f"{VSESSION}::test_screenshot_never_replaces_and_never_leaves_the_folder",),
           "a screenshot silently replaces an existing file"),
    Mutant("viewer_accepts_infinity", "runtime/viewer/messages.py", "if not math.isfinite(v):", "if False:",
           ("tests/runtime/viewer/test_viewer_messages.py::test_bad_messages_are_refused_in_one_line",),
           "a number like 1e400 (inf after parsing) reaches the camera"),
    Mutant("viewer_any_origin", "runtime/viewer/server.py",
           "if allowed_origins is not None and origin is not None and origin not in allowed_origins():",
           "if False:", ("tests/runtime/viewer/test_viewer_server.py::test_foreign_origin_is_refused",),
           "any web site open in the browser can drive the viewer on 127.0.0.1"),
    Mutant("viewer_render_thread_leak", "runtime/viewer/server.py", "                worker.stop()\n",
           "                pass\n",
           ("tests/runtime/viewer/test_viewer_server.py::test_closing_an_idle_page_ends_its_render_thread",),
           "a closed page's render thread lives on"),
    # The viewer's label panel (label scenes, issue 17 item 2 in pfn-view).
    Mutant("viewer_label_visibility_ignored", "runtime/viewer/transfer_edit.py",
           "np.where(self.visible, self.opacity, 0.0)", "self.opacity",
           (f"{VLABELS}::test_hiding_a_label_darkens_its_region_and_only_its_region",),
           "the label panel's visibility checkbox is acknowledged but a hidden label is still rendered"),
    Mutant("viewer_absent_label_accepted", "runtime/viewer/transfer_edit.py",
           "        if missing.size:\n            listed", "        if False:\n            listed",
           (f"{VLABELS}::test_the_other_kind_of_edit_and_absent_labels_are_refused",),
           "a labels message naming labels the volume does not have is applied instead of refused"),
    Mutant("viewer_points_on_a_label_scene", "runtime/viewer/transfer_edit.py",
           "    if panel is not None or not isinstance(base, TransferFunction):", "    if False:",
           (f"{VLABELS}::test_the_other_kind_of_edit_and_absent_labels_are_refused",),
           "a scalar transfer message turns a label scene into a scalar one (interpolated label values)"),
    # The final gather (one real bounce before the field).
    Mutant("gather_environment_halved", "runtime/wavefront/final_gather.py", "x2, w, states, False, one_light)",
           "x2, w, states, True, one_light)", (f"{GATHER}::test_gather_of_nothing_is_the_path_tracers_second_bounce",),
           "NEE at the bounce gives the environment only its MIS share, though no phase-sampled escape follows"),
    Mutant("gather_without_albedo", "runtime/wavefront/final_gather.py", "= wt * ar, wt * ag, wt * ab",
           "= wt, wt, wt", (f"{GATHER}::test_gather_of_nothing_is_the_path_tracers_second_bounce",),
           "the bounce's collision is not weighted by its albedo"),
    Mutant("gather_backwards", "runtime/wavefront/final_gather.py", "sample_hg(g, d[0, i]", "sample_hg(-g, d[0, i]",
           (f"{GATHER}::test_bounce_directions_follow_the_phase_function",),
           "the bounce samples the phase function the wrong way round"),
    Mutant("gather_switch_inside_a_batch", "runtime/wavefront/batches.py",
           "bounds = [first, end] if split is None or not first < split < end else [first, split, end]",
           "bounds = [first, end]",
           (f"{GATHER}::test_samples_from_final_gather_after_on_are_gathered_and_the_rest_plain",),
           "a work batch that straddles final_gather_after is gathered (or not) as a whole"),
    Mutant("viewer_gather_while_moving", "runtime/viewer/session.py", "render and not moved_only and self.gathers",
           "render and self.gathers", (f"{VGATHER}::test_moving_frames_never_gather_and_never_means_never",),
           "moving frames, which must be fast, take the final gather too"),
    # Environment maps (issue 18's first block).
    Mutant("env_weights_without_sin_theta", "runtime/transport/environment_map.py",
           "f = (radiance @ LUMINANCE) * sin_theta[:, None]", "f = (radiance @ LUMINANCE) * np.ones(h)[:, None]",
           (f"{ENVMAP}::test_density_follows_luminance_times_solid_angle",),
           "the sampling tables weighted by luminance alone, without sin(theta): still a valid, self-consistent "
           "density, but not proportional to the radiance in solid angle (poles oversampled)"),
    Mutant("env_pdf_without_sin_theta", "runtime/transport/environment_map.py",
           "pdf = env.pdf_uv[i, j] / (2.0 * math.pi * math.pi * st) if st > 0.0 else 0.0",
           "pdf = env.pdf_uv[i, j] / (2.0 * math.pi * math.pi) if st > 0.0 else 0.0",
           (f"{ENVMAP}::test_pdf_integrates_to_one_over_the_sphere",
            f"{ENVMAP}::test_sampler_matches_its_own_pdf_chi_square",
            f"{ENVRENDER}::test_nee_with_mis_and_phase_sampling_agree_under_a_map"),
           "the lookup's pdf forgets the sin(theta) of the Jacobian 2 pi^2 sin(theta) (the MIS weight of escapes)"),
    Mutant("env_sample_pdf_without_sin_theta", "runtime/transport/environment_map.py",
           "pdf = env.pdf_uv[i, j] / (2.0 * math.pi * math.pi * st)\n    return dx",
           "pdf = env.pdf_uv[i, j] / (2.0 * math.pi * math.pi)\n    return dx",
           (f"{ENVMAP}::test_sample_reports_the_lookups_radiance_and_pdf",
            f"{ENVRENDER}::test_constant_map_matches_the_constant_environment_in_the_path_tracer",
            f"{ENVRENDER}::test_furnace_under_a_constant_map"),
           "the NEE sample's pdf forgets sin(theta): NEE under a map is biased"),
    Mutant("env_row_offset_from_column_number", "runtime/transport/environment_map.py",
           "v = (i + ((u1 - env.row_cdf[i]) / du if du > 0.0 else 0.5)) / h",
           "v = (i + (u2 if du > 0.0 else 0.5)) / h",
           (f"{ENVMAP}::test_sampler_matches_its_own_pdf_chi_square",),
           "the position inside the sampled row taken from the column's random number (correlated)"),
    Mutant("env_rotation_not_inverted", "runtime/transport/environment_map.py",
           "x = r[0, 0] * dx + r[1, 0] * dy + r[2, 0] * dz\n    y = r[0, 1] * dx + r[1, 1] * dy + r[2, 1] * dz\n"
           "    z = r[0, 2] * dx + r[1, 2] * dy + r[2, 2] * dz",
           "x = r[0, 0] * dx + r[0, 1] * dy + r[0, 2] * dz\n    y = r[1, 0] * dx + r[1, 1] * dy + r[1, 2] * dz\n"
           "    z = r[2, 0] * dx + r[2, 1] * dy + r[2, 2] * dz",
           (f"{ENVMAP}::test_sampler_matches_its_own_pdf_chi_square",
            f"{ENVMAP}::test_yaw_90_equals_the_image_rolled_by_three_quarters",
            f"{ENVRENDER}::test_bright_patch_lights_like_a_directional_light[90.0]"),
           "the lookup rotates world directions by R instead of R^T: sampling and lookup disagree for a rotated map"),
    Mutant("env_mis_uses_the_constant_pdf", "runtime/renderers/path_tracer.py",
           "w = _mis_weights(pdf, pdf_light) if nee", "w = _mis_weights(pdf, 0 * pdf_light + 1 / (4 * np.pi)) if nee",
           (f"{ENVRENDER}::test_nee_with_mis_and_phase_sampling_agree_under_a_map",),
           "an escape under a map is MIS-weighted with the constant environment's pdf 1 / (4 pi), not the map's"),
    Mutant("env_photon_power_unscaled", "train/photons/tracing.py",
           "br, bg, bb = power[li, 0] * sr, power[li, 1] * sg, power[li, 2] * sb",
           "br, bg, bb = power[li, 0], power[li, 1], power[li, 2]",
           (f"{TRACING}::test_environment_map_photons_keep_the_colour_of_their_direction",),
           "map photons, importance-sampled by direction, all carry the same power (no L / (p int L) scale)"),
    Mutant("env_photon_travels_towards_the_light", "runtime/transport/emitters.py",
           "dx, dy, dz = -wx, -wy, -wz", "dx, dy, dz = wx, wy, wz",
           (f"{EMITTERS}::test_environment_map_photons_carry_the_maps_radiance_by_direction",
            f"{LIGHTS}[environment_map]"),
           "map photons travel towards the direction their light comes from instead of away from it"),
    Mutant("env_camera_rays_regenerated_wrongly", "runtime/wavefront/first_interaction.py",
           "return env.behind_camera_rays(scene.camera, items + start, seed)",
           "return env.behind_camera_rays(scene.camera, items + start, seed + 1)",
           (f"{ENVRENDER}::test_first_interaction_renderers_see_the_map_along_each_camera_ray[delta]",),
           "the first-interaction renderers look the map up along other camera rays than the ones that missed"),
    Mutant("marcher_skips_too_far", "runtime/transport/tracking.py", "    return max(0.0, min(ex, ey, ez))\n",
           "    return max(0.0, min(ex, ey, ez)) * 1.5\n",
           ("tests/runtime/renderers/test_ray_marcher.py::test_skipping_empty_space_changes_no_pixel",),
           "the ray marcher skips past the end of an empty region and misses the medium behind it"),
    Mutant("marcher_light_at_midpoint", "runtime/renderers/ray_marcher.py",
           "ts = t_prev + scattering_centroid(sigma, seg, e)", "ts = tm",
           ("tests/runtime/renderers/test_ray_marcher.py::test_a_coarse_step_reads_the_light_at_the_lit_wall",),
           "the ray marcher reads the light at a segment's midpoint, half a step inside a dense wall"),
    Mutant("marcher_long_segment_sampled_at_first_step", "runtime/renderers/ray_marcher.py",
           "                tm = 0.5 * (t_prev + t_next)\n"
           "                x, y, z = ox + tm * dx, oy + tm * dy, oz + tm * dz\n"
           "            seg = t_next - t_prev", "            seg = t_next - t_prev",
           ("tests/runtime/transport/test_step_grid.py::test_adaptive_steps_keep_the_image_of_a_fine_march",),
           "the ray marcher samples a segment of several steps at its first step's midpoint"),
    Mutant("step_grid_ignores_curvature", "runtime/transport/step_grid.py",
           "                if curv > 0.0:", "                if curv < 0.0:",
           ("tests/runtime/transport/test_step_grid.py::test_curvature_bounds_a_thin_medium",),
           "the adaptive steps ignore sigma_t's curvature and span a detailed medium in one sample"),
    Mutant("step_grid_neighbours_one_macrocell", "runtime/transport/step_grid.py",
           "    return _neighbourhood_min(own, max(1, int(math.ceil(max_units * step / edge))))",
           "    return _neighbourhood_min(own, 1)",
           ("tests/runtime/transport/test_step_grid.py::test_a_sharp_step_limits_every_macrocell_a_segment_could_reach_it_from",),
           "a long segment starts one macrocell before a sharp wall it then reaches and samples past"),
    Mutant("step_depth_three", "runtime/transport/step_grid.py", "STEP_DEPTH = 1.0", "STEP_DEPTH = 3.0",
           ("tests/runtime/renderers/test_ray_marcher.py::test_long_segments_stay_within_one_optical_depth_in_a_lit_slab",),
           "the ray marcher's segments hold three optical depths and read the light of a lit wall once for all three"),
    Mutant("block_extinction_pads_with_zeros", "runtime/transport/medium.py",
           "acc += _extinction_of(lut, categorical, density[ii, jj, min(k, nz - 1)])",
           "acc += _extinction_of(lut, categorical, density[ii, jj, min(k, nz - 1)]) if k < nz else 0.0",
           ("tests/runtime/transport/test_labels_medium.py::test_block_extinction_is_the_mean_of_the_voxels_sigma_t",),
           "the denoisers' coarse grid counts voxels past the far z end as empty instead of repeating the border"),
    Mutant("majorant_kept_instead_of_ranges", "runtime/transport/medium.py",
           "        majorant = majorant_grid(density, ext_lut, macrocell, ranges[macrocell])",
           "        majorant = ranges.setdefault(('majorant', macrocell), majorant_grid(density, ext_lut, macrocell))",
           ("tests/runtime/transport/test_transport.py::"
            "test_a_transfer_function_edit_reuses_the_volumes_scalar_ranges_and_gets_its_own_majorant",),
           "the volume keeps the first transfer function's majorant, and an edit's medium walks with the old one"),
    Mutant("depth_leaps_with_another_grids_table", "runtime/denoise/depth.py",
           "self.leap = medium.leap if leap and same_cells else leap_distances(self.grid, leap)",
           "self.leap = medium.leap if leap else leap_distances(self.grid, leap)",
           ("tests/runtime/denoise/test_wrls_reprojection.py::"
            "test_the_depth_walk_leaps_with_the_mediums_table_where_the_cells_are_its_macrocells[47-False]",),
           "the depth walk takes the medium's leap table although its cells are not the medium's macrocells"),
    Mutant("macrocell_fixed_at_two", "runtime/transport/medium.py",
           "    return max(DEFAULT_MACROCELL, math.ceil(max(shape) / MAX_MACROCELLS_SIDE))",
           "    return DEFAULT_MACROCELL",
           ("tests/runtime/transport/test_transport.py::test_the_macrocell_grows_with_large_volumes_only",),
           "a 512^3 volume keeps 2-voxel macrocells: a 256^3 majorant grid, slower walks, 134 MB tables per edit"),
    Mutant("majorant_range_starts_high", "runtime/transport/medium.py",
           "                lo = int(math.floor(float(smin[a, b, c]) * (lut_n - 1)))",
           "                lo = int(math.ceil(float(smin[a, b, c]) * (lut_n - 1)))",
           ("tests/runtime/transport/test_transport.py::"
            "test_majorant_grid_is_the_table_max_over_each_macrocells_scalar_range",),
           "a macrocell's majorant leaves out the table entry below its lowest scalar"),
    Mutant("tile_order_full_tiles_only", "runtime/wavefront/rays.py",
           "    cols = np.minimum(tile, width - col * tile)  # this tile's width", "    cols = np.full_like(col, tile)",
           ("tests/runtime/wavefront/test_pixel_order.py::test_tile_order_is_a_permutation_of_squares",
            "tests/runtime/renderers/test_ray_marcher.py::test_taking_rays_a_tile_at_a_time_changes_no_pixel"),
           "the tile order treats the right edge's narrower tiles as whole ones: pixels twice, others never"),
    Mutant("shadow_segment_sampled_at_first_step", "runtime/transport/marching.py",
           "        tb = min(ta + n * h, t1)\n        tm = 0.5 * (ta + tb)\n", "        tb = min(ta + n * h, t1)\n",
           ("tests/runtime/transport/test_step_grid.py::test_segmented_shadow_rays_sum_what_stepping_through_every_"
            "segment_sums",
            "tests/runtime/transport/test_step_grid.py::test_segmented_shadow_rays_agree_with_a_fine_march"),
           "a light-volume cell's shadow ray samples a long segment at its first base step's midpoint"),
    Mutant("light_volume_fills_one_corner", "runtime/transport/light_volume.py", "    for c in range(8):",
           "    for c in range(1):",
           ("tests/runtime/renderers/test_path_tracer.py::test_ray_marcher_matches_single_scattering",),
           "the light volume marches one corner of a stencil and reads the others unfilled"),
    Mutant("camera_segment_ignores_the_cells_it_passes", "runtime/transport/step_grid.py",
           "        if v != 0 and v < n:", "        if v != 0 and v < n and False:",
           ("tests/runtime/transport/test_step_grid.py::test_a_camera_segment_spans_what_every_macrocell_it_passes_allows",),
           "a camera segment spans what its start macrocell allows, across a wall ahead"),
    Mutant("light_edit_keeps_a_moved_lights_cells", "runtime/transport/light_volume.py",
           "if old_kind[j] == kind[k] and np.array_equal(old_vec[j], vec[k]):", "if old_kind[j] == kind[k]:",
           (f"{RAY_MARCHER}::test_a_light_edit_keeps_the_cells_of_the_lights_that_did_not_move",),
           "a moved light of the same kind inherits the cells marched towards its old position"),
    Mutant("light_volume_flags_the_stencils_brick", "runtime/transport/light_volume.py",
           "wanted[a >> _BRICK_SHIFT, b >> _BRICK_SHIFT, e >> _BRICK_SHIFT] = 1",
           "wanted[i >> _BRICK_SHIFT, j >> _BRICK_SHIFT, k >> _BRICK_SHIFT] = 1",
           (f"{RAY_MARCHER}::test_marked_cells_are_filled_brick_by_brick_and_no_others",),
           "a marked corner in the next brick is not flagged, and the fill never finds it"),
    Mutant("missed_ray_stops_marking", "runtime/renderers/preview_light.py",
           "tl = -1.0 if missed[i] else light_transmittance(", "tl = 1.0 if missed[i] else light_transmittance(",
           (f"{RAY_MARCHER}::test_light_volume_gives_the_same_image_cold_or_warm_and_with_any_threads",),
           "a ray that missed a light-volume cell marks nothing further, and its second march misses again"),
    # Coarser levels (runtime/scene/levels.py) and the viewer's first frame of each change.
    Mutant("level_box_stretched", "runtime/scene/levels.py",
           "spacing = tuple(float(s) * n / c for s, n, c in", "spacing = tuple(float(s) * 2.0 for s, n, c in",
           ("tests/runtime/scene/test_levels.py::test_a_level_averages_blocks_in_the_same_box",),
           "a level's voxels take twice the spacing whatever the padding: an odd side's level grows out of the box"),
    Mutant("level_light_edit_keeps_old_lights", "runtime/scene/scene.py",
           "levels[level] = replace(old, lights=self.lights, _cache={})", "levels[level] = old",
           ("tests/runtime/scene/test_levels.py::test_a_light_edit_keeps_a_levels_medium_and_renders_as_a_cold_level",),
           "after a light edit the coarser level still renders the lights before it"),
    Mutant("coarse_frame_accumulated", "runtime/viewer/session.py",
           "self._unrested = render and ((moved_only and not progressive(s.renderer)) or level > 0)",
           "self._unrested = render and moved_only and not progressive(s.renderer)",
           ("tests/runtime/viewer/test_viewer_preview.py::"
            "test_each_change_shows_the_interactive_level_first_and_rests_on_the_full_volume",),
           "the coarse first frame of a change is averaged into the resting view's full-level frames"),
    Mutant("changing_first_frame_dropped", "runtime/viewer/session.py",
           "settling = render and self._unrested and not fresh",
           "settling = render and self._unrested and not moved_only",
           ("tests/runtime/viewer/test_viewer_preview.py::"
            "test_a_changes_first_frame_is_shown_even_when_the_next_change_comes_while_it_renders",),
           "an edit's first frame after a coarse one is dropped when the next edit arrives: a slider drag shows "
           "nothing"),
    Mutant("cancelled_fill_forgets_its_bricks", "runtime/transport/light_volume.py",
           "lv.wanted[chunk[:, 0], chunk[:, 1], chunk[:, 2]] = 0", "lv.wanted[...] = 0",
           (f"{RAY_MARCHER}::test_a_cancelled_fill_keeps_its_cells_and_the_next_frame_completes_it",),
           "each fill chunk clears every brick's flag: a cancelled fill leaves marked cells no later fill finds"),
    Mutant("resting_preview_not_cancellable", "runtime/viewer/field_in_use.py",
           "progress=False, level=level, cancel=cancel,", "progress=False, level=level, cancel=None,",
           ("tests/runtime/viewer/test_viewer_preview.py::"
            "test_a_resting_preview_frame_gives_way_to_a_move_during_its_fill",),
           "the preview's resting frames ignore the session's cancel: a move waits for a whole full-level frame"),
    # Label volumes (runtime/scene/labels.py, the categorical medium).
    Mutant("labels_interpolated", "runtime/transport/medium.py", "    if m.categorical:  # vx <= nx - 1",
           "    if False:  # vx <= nx - 1",
           (f"{LABELS_MEDIUM}::test_no_false_colour_across_a_label_border",
            f"{LABELS_MEDIUM}::test_extinction_at_voxel_centres_is_the_labels",
            "tests/runtime/renderers/test_label_render.py::test_path_traced_labels_show_only_label_colours"),
           "label indices interpolated trilinearly before the table lookup: blends of two labels' colours"),
    Mutant("labels_majorant_nearest_only", "runtime/transport/medium.py",
           "    hi = -np.inf\n    for i in range(x0, x1):",
           "    hi = -np.inf\n    x0 = max(x0, int(math.ceil(a * nx / cx)))\n    for i in range(x0, x1):",
           (f"{LABELS_MEDIUM}::test_majorant_bounds_extinction_and_empty_space_stays_empty",),
           "the majorant (categorical or not) leaves out the voxels whose nearest-neighbour cell starts before the "
           "macrocell"),
    Mutant("labels_fingerprint_without_window", "runtime/scene/scene.py",
           "return self.volume.label_fingerprint() if isinstance", "return self.volume.fingerprint() if isinstance",
           ("tests/runtime/scene/test_labels.py::"
            "test_fingerprint_tells_label_volumes_with_the_same_normalized_grid_apart",),
           "label scenes fingerprinted by the normalized grid alone: {0, 1, 2} and {0, 2, 4} share photon maps"),
    # PVRT (issue 18): the transfer file, its refusals, and its radiance against the path tracer.
    Mutant("pvrt_seed_not_passed", "train/cli/pvrt_command.py", "bases=args.pca_bases, seed=args.seed",
           "bases=args.pca_bases, seed=0",
           (f"{PVRT_CLI}::test_same_seed_same_bytes_any_threads_other_seed_differs",),
           "pfn-train pvrt ignores --seed (every seed writes seed 0's transfer)"),
    Mutant("pvrt_zip_timestamps", "runtime/pvrt/transfer.py",
           'info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)',
           'info = zipfile.ZipInfo(f"{name}.npy", date_time=time.localtime()[:6])',
           (f"{PVRT_CLI}::test_same_seed_same_bytes_any_threads_other_seed_differs",),
           "the transfer file's zip entries carry the time of writing (as np.savez does): same seed, other bytes"),
    Mutant("pvrt_check_volume_only", "runtime/pvrt/transfer.py",
           "expected = {k: parts[k] for k in PVRT_SCENE_PARTS}",
           'expected = {k: parts[k] if k == "volume" else self.manifest["scene_parts"][k] for k in PVRT_SCENE_PARTS}',
           (f"{PVRT_CLI}::test_render_refuses_missing_foreign_or_unreadable_transfer",
            f"{PVRT_PT}::test_refuses_a_transfer_for_another_transfer_function_or_g"),
           "a transfer made for another transfer function of the same volume is accepted"),
    Mutant("pvrt_no_nee", "runtime/pvrt/lighting.py", "                nee_rgb.append(rgb)",
           "                nee_rgb.append(0.0 * rgb)", (f"{PVRT_PT}::test_pvrt_matches_path_tracer_under_its_light",),
           "a directional light's direct term is dropped (NEE light volume weighted by 0)"),
    Mutant("pvrt_no_mass_division", "runtime/pvrt/radiance.py", "scale = interp[v] / mass[v]",
           "scale = interp[v]",
           (f"{PVRT_PT}::test_pvrt_matches_path_tracer_under_its_light",),
           "the radiance volume is the photon energy, not divided by the cell's kernel-weighted extinction D_v"),
    Mutant("pvrt_mass_one_point", "runtime/pvrt/constants.py", "MASS_POINTS = 8", "MASS_POINTS = 1",
           (f"{PVRT_DIRECT}::test_transfer_denominators_integrate_the_extinction",),
           "the transfer's denominators D_v integrated with the kernel's few points per voxel (aliasing: +7 % on the "
           "vortex at 32^3)"),
    Mutant("pvrt_direct_dark", "runtime/pvrt/direct.py",
           "            t = math.exp(-tau[active[a]]) * ph[a]",
           "            t = math.exp(-tau[active[a]]) * ph[a] * 0.8",
           (f"{PVRT_DIRECT}::test_direct_term_of_a_constant_sky_is_the_closed_form_at_the_camera_samples",
            f"{PVRT_MARCH}::test_relighting_gives_render_pvrts_frames"),
           "the marched frames' basis direct term 20 % dark (the photon splat's bias before issue 18's fix); the "
           "closed-form test reads the kept samples' transmittances, the relit-equals-marched test this path"),
    Mutant("pvrt_kept_direct_dark", "runtime/pvrt/direct.py", "            out[s, q] = math.exp(-tau[q])",
           "            out[s, q] = 0.8 * math.exp(-tau[q])",
           (f"{PVRT_DIRECT}::test_direct_term_of_a_constant_sky_is_the_closed_form_at_the_camera_samples",),
           "the kept samples' transmittances towards the quadrature directions 20 % dark"),
    Mutant("pvrt_no_hg_bands", "runtime/pvrt/radiance.py", "                    y[j] *= band[j]",
           "                    y[j] *= 1.0", (f"{PVRT_PT}::test_pvrt_matches_path_tracer_under_its_light",),
           "the camera's HG phase (band factors g^l) is left out of the exitant radiance (isotropic instead)"),
    Mutant("pvrt_exitance_ignores_g", "runtime/pvrt/sh.py", "    a = abs(float(g))", "    a = 0.4",
           (f"{PVRT_PT}::test_the_exitance_order_follows_g",
            f"{PVRT_PT}::test_an_isotropic_transfer_keeps_band_0_only_and_its_values_are_the_full_ones"),
           "the transfer's default SH band limit is l_max 2 whatever g (an isotropic medium stores 9x what it reads)"),
    Mutant("pvrt_grid_ignores_budget", "runtime/pvrt/precompute.py",
           "        if cells_for(grid) * bytes_per_cell <= TRANSFER_BUDGET_BYTES:",
           "        if True:", (f"{PVRT_PT}::test_the_default_grid_is_the_finest_that_fits_the_memory_budget",),
           "the default transfer grid is DEFAULT_GRID whatever its memory (l_max 2 at DSF order 2: 2.6 GB)"),
    Mutant("pvrt_interpolation_by_mass", "runtime/pvrt/radiance.py",
           "(mass / (mass + d0)).astype(np.float32)", "mass.astype(np.float32)",
           (f"{PVRT_PT}::test_the_radiance_volume_weighs_cells_by_their_share_of_medium_saturating",),
           "the camera's interpolation weighs cells by D_v again (a dense medium's dark inside outweighs its skin)"),
    Mutant("pvrt_sun_power_halved", "runtime/pvrt/suns.py",
           "        suns.append((centre, irradiance))", "        suns.append((centre, 0.5 * irradiance))",
           (f"{PVRT_BASIS}::test_a_sun_the_basis_cannot_resolve_becomes_a_directional_light_and_the_maps_power_is_kept",
            f"{PVRT_BASIS}::test_a_maps_sun_is_lit_by_nee_from_its_turned_direction_and_projected_without_it"),
           "a map's sun, split off as a directional light, carries half its irradiance"),
    Mutant("pvrt_sun_not_turned", "runtime/pvrt/lighting.py", "                travel = -(r @ (to_world @ towards))",
           "                travel = -towards",
           (f"{PVRT_BASIS}::test_a_maps_sun_is_lit_by_nee_from_its_turned_direction_and_projected_without_it",),
           "a map's sun lights from its direction in the map's frame, ignoring the map's and the lighting's rotation"),
    Mutant("pvrt_reachable_not_widened", "runtime/pvrt/precompute.py",
           "                    lo[ax] = max(0, int(math.floor(u0 - hc)))",
           "                    lo[ax] = max(0, int(math.floor(u0)))",
           (f"{PVRT_PT}::test_the_transfer_keeps_rows_for_exactly_the_cells_photons_can_reach",),
           "the transfer's rows miss cells a photon's kernel reaches below an occupied macrocell (its splat lands in "
           "another cell's row)"),
    Mutant("cpca_least_principal_axes", "runtime/pvrt/cpca.py", "    return vectors[:, ::-1][:, :count].T",
           "    return vectors[:, :count].T",
           (f"{PVRT_BASIS}::test_cpca_recovers_clusters_of_low_rank_matrices",),
           "CPCA keeps the axes of least variance of a cluster with more rows than columns"),
    Mutant("pvrt_splat_radius_fixed", "runtime/pvrt/precompute.py",
           "    return min(hc, max(1.0, hc * math.sqrt(tau / max(sigma_cell, 1e-12))))", "    return hc",
           (f"{PVRT_PT}::test_the_splatting_radius_shrinks_in_dense_media_only",),
           "the splatting radius stays KERNEL_C in dense media (head's skull blurs its lit skin into its inside)"),
    Mutant("pvrt_photon_power_doubled", "runtime/pvrt/precompute.py", "        power = weight * scale",
           "        power = 2.0 * weight * scale", (f"{PVRT_PT}::test_pvrt_matches_path_tracer_under_its_light",),
           "basis-light photons carry twice their energy"),
    Mutant("pvrt_march_jumps_too_far", "runtime/transport/marching.py", "math.floor(empty_until / h - jitter + 0.5)",
           "math.floor(empty_until / h - jitter + 2.5)",
           (f"{PVRT_MARCH}::test_skipping_empty_space_changes_no_pixel",
            "tests/runtime/renderers/test_ray_marcher.py::test_skipping_empty_space_changes_no_pixel"),
           "a camera march (PVRT's, the ray marcher's) jumps two segments past the end of an empty run and misses "
           "the medium there (one segment is not seen: the first midpoint past a run had sigma_t = 0 on every ray "
           "of this scene)"),
    Mutant("pvrt_light_cells_short", "runtime/pvrt/radiance.py", "[0] + 1  # the stencil's upper corner",
           "[0]  # the stencil's upper corner",
           (f"{PVRT_MARCH}::test_light_volume_marches_every_cell_a_sample_in_the_medium_reads",
            f"{PVRT_MARCH}::test_skipping_empty_space_changes_no_pixel"),
           "the light volume leaves out the upper corner of the stencils of the occupied macrocells (shadows there "
           "read an unmarched 1)"),
    Mutant("pvrt_relight_keeps_old_shadows", "runtime/renderers/pvrt.py",
           "np.array_equal(previous.lighting.nee_directions,\n" + " " * 55 + "self.lighting.nee_directions)",
           "np.array_equal(previous.lighting.nee_rgb,\n" + " " * 55 + "self.lighting.nee_rgb)",
           (f"{PVRT_MARCH}::test_relighting_gives_render_pvrts_frames",),
           "a relit frame takes the last frame's light volumes when the directional lights' colours are unchanged, "
           "although they moved"),
    Mutant("pvrt_view_relights_stale_lights", "runtime/viewer/pvrt_view.py",
           "return kept.render(scene.lights, direct=self.options.direct).layers",
           "return kept.render(kept.scene.lights, direct=self.options.direct).layers",
           (f"{VPVRT}::test_light_change_is_render_pvrts_frame_relit_without_a_march",),
           "the viewer relights its kept samples with the lights they were marched under, not the page's edited "
           "ones (a light change shows the old light)"),
    Mutant("update_budget_ignores_outputs", "train/fit/update.py",
           "deadline = t0 + float(budget_s) - min(UPDATE_OUTPUT_RESERVE_S, 0.5 * float(budget_s))",
           "deadline = t0 + float(budget_s) - 0.0 * min(UPDATE_OUTPUT_RESERVE_S, 0.5 * float(budget_s))",
           ("tests/train/fit/test_update.py::test_training_stops_early_enough_for_the_outputs_to_fit_the_budget",),
           "an update trains until the whole budget is spent, and its log, plot and export come after it (a 15 s "
           "budget gave 15.4-16.4 s)"),
    Mutant("viewer_retrains_under_pvrt", "runtime/viewer/updater.py",
           "self._auto_waits = pvrt_shown\n        return not pvrt_shown",
           "self._auto_waits = pvrt_shown\n        return True",
           ("tests/runtime/viewer/test_viewer_retrain.py::test_under_pvrt_a_light_edit_waits_for_the_page_to_leave_pvrt",),
           "a light drag under PVRT starts a background retrain of the neural field, which takes a core from the "
           "relighting"),
    Mutant("update_budget_from_the_call", "train/cli/train.py",
           'started=_COMMAND_CLOCK["started"], on_bundle=bundle_written)', "started=None, on_bundle=bundle_written)",
           ("tests/train/fit/test_update.py::test_the_command_counts_its_budget_from_its_process_start",),
           "pfn-train update counts --budget from the call, not the process's start: the command's imports (2-3 s) "
           "come on top of the budget the user gave"),
    Mutant("retrain_waits_for_the_trainer_to_exit", "runtime/viewer/retrain.py",
           'if not self.cancelled and progress is not None and progress.status == "done" and self.bundle.exists():',
           "if False:",
           ("tests/runtime/viewer/test_viewer_retrain.py::"
            "test_a_job_is_done_once_its_bundle_is_written_not_when_its_trainer_has_exited",),
           "the viewer swaps a retrained field in only after the trainer's interpreter has exited (~1 s after the "
           "bundle was written)"),
    Mutant("update_keeps_the_earlier_field", "train/fit/fine_tune.py",
           'if not kept or first_trained or error < kept_validation["val_rel_l1"]:',
           'if not kept or error < kept_validation["val_rel_l1"]:',
           ("tests/train/fit/test_update.py::test_an_update_keeps_a_trained_field_not_the_earlier_one",),
           "an update keeps the earlier field whenever the noisy validation scores it lowest, so a chain of small "
           "edits is never followed (shell: 9 of 10, L_i 2.3 % behind)"),
    Mutant("update_done_after_the_plot", "train/cli/train.py",
           "started=_COMMAND_CLOCK[\"started\"], on_bundle=bundle_written)", "started=_COMMAND_CLOCK[\"started\"])",
           ("tests/train/fit/test_update.py::test_the_progress_file_says_done_before_the_loss_plot",),
           "pfn-train update marks its progress file done only after the loss plot: the viewer waits for the plot "
           "(1-3.6 s) before swapping the field in"),
    Mutant("rescale_ignores_where_lights_are", "runtime/scene/light_rescale.py",
           "return {k: v for k, v in light.items() if k not in FLUX_KEYS and k not in IGNORED_KEYS}",
           "return {k: v for k, v in light.items() if k == \"type\"}",
           ("tests/runtime/field/test_light_rescale.py::test_a_moved_light_is_still_refused",
            f"{VSESSION}::test_single_light_power_rescales_the_indirect_layer_exactly"),
           "a moved light passes for a power edit: the field's L_i is rescaled instead of marked stale or refused"),
    Mutant("rescale_one_light_of_several", "runtime/scene/light_rescale.py",
           "if ratios.max() - ratios.min() > RTOL * max(ratios.max(), 1e-300):", "if False:",
           ("tests/runtime/field/test_light_rescale.py::test_several_lights_rescale_only_together",
            f"{VSESSION}::test_lights_scaled_together_rescale_and_one_of_several_is_stale"),
           "one light's power among several rescales the whole L_i by that light's ratio (wrong wherever the "
           "other light dominates)"),
    Mutant("rescaled_bundle_not_rescaled", "runtime/field/field.py",
           "        scale = self.light_scale\n", "        scale = None\n",
           ("tests/runtime/field/test_light_rescale.py::test_a_bundle_answers_for_its_lights_rescaled",),
           "a bundle loaded for a brighter light renders the trained light's L_i (the issue's 40 % too dark)"),
    Mutant("rescaled_map_keeps_its_power", "runtime/photons/photon_map.py",
           "power = (self.power * factor).astype(np.float32)", "power = self.power",
           ("tests/runtime/field/test_light_rescale.py::test_a_photon_map_answers_for_its_lights_rescaled",),
           "a photon map taken for a brighter light keeps the traced light's powers"),
    Mutant("render_never_cancelled", "runtime/wavefront/first_interaction.py",
           "            if cancel is not None and cancel():", "            if False:",
           ("tests/runtime/renderers/test_neural_renderer.py::"
            "test_a_render_is_cancelled_between_batches_and_batches_do_not_change_the_image",),
           "a render never asks cancel(): a refinement overtaken by a camera move runs to its end first"),
    Mutant("refinements_not_cancellable", "runtime/viewer/session.py",
           "cancel = (lambda: self.generation != generation) if refining else None", "cancel = None",
           (f"{VSESSION}::test_stale_refinement_frames_are_dropped_but_first_frames_never",),
           "the viewer gives the renderer no cancel for refinements: a move waits for a whole resting frame"),
    # One light among several, the lights kept apart (issue 16).
    Mutant("photons_all_of_light_zero", "runtime/photons/knn_radiance.py",
           "col = 3 * np.int64(light[j]) if lights > 1 else 0", "col = 0",
           ("tests/runtime/field/test_per_light.py::test_the_parts_sum_to_the_estimate_and_each_is_its_lights",),
           "every photon counts for the first light: the per-light targets put the whole L_i on one light"),
    Mutant("per_light_factors_ignored", "runtime/field/outputs.py",
           "v = v * factors[light, c]", "v = v * factors[0, c]",
           ("tests/runtime/field/test_per_light.py::test_a_field_sums_its_lights_parts_with_their_factors",),
           "a field that keeps its lights apart ignores a light's edited power: L_i as trained"),
    Mutant("per_light_loss_on_own_part", "train/fit/loss.py",
           "return ((parts - targets) ** 2 / (total ** 2 + eps * eps)).sum(dim=1).mean()",
           "return ((parts - targets) ** 2 / (parts.detach() ** 2 + eps * eps)).sum(dim=1).mean()",
           ("tests/train/fit/test_per_light_fit.py::test_per_light_loss_weighs_lights_by_the_sum",),
           "each light's error is weighed by its own part: a dim light's noise is fitted as hard as the image's "
           "main light"),
    # An albedo edit reweights the earlier map (issue 16).
    Mutant("albedo_reweight_null_records_twice", "runtime/photons/albedo_reweight.py",
           "elif bounce[i] == bounce[i - 1]:", "elif bounce[i] == -1:",
           ("tests/runtime/photons/test_albedo_reweight.py::test_an_albedo_edit_reweights_like_a_fresh_trace",),
           "a null record's albedo factor multiplied again for the collision it precedes"),
    Mutant("albedo_reweight_never_resets", "runtime/photons/albedo_reweight.py",
           "        if bounce[i] <= 2:  # a new path", "        if bounce[i] <= 1:  # a new path",
           ("tests/runtime/photons/test_albedo_reweight.py::test_an_albedo_edit_reweights_like_a_fresh_trace",),
           "the albedo factors run on from one path into the next: records get other paths' products"),
    Mutant("update_never_reweights", "train/fit/update.py",
           "    pmap = reweighted_map(record, scene, photons, seed) if reweight else None",
           "    pmap = None",
           ("tests/train/fit/test_update.py::test_an_albedo_edit_reweights_runs_map_instead_of_retracing",),
           "an albedo edit retraces like any other: seconds of the budget and a map less correlated with RUN's"),
    # The direction features times g (issue 13).
    Mutant("runtime_ignores_direction_gain", "runtime/field/field.py",
           "self._frame_g = (g0, direction_gains(one, cfg.direction_gain),", "self._frame_g = (g0, None,",
           ("tests/runtime/field/test_bundle.py::test_direction_gain_makes_the_field_isotropic_at_g_zero",),
           "the runtime feeds the direction features unscaled to an MLP trained on scaled ones: another function"),
    Mutant("encoder_gain_ignored", "runtime/field/hashgrid.py",
           "        acc = builder.fmul(acc, builder.shuffle_vector(g, undef, splat))\n", "",
           ("tests/runtime/field/test_bundle.py::test_direction_gain_makes_the_field_isotropic_at_g_zero",),
           "the direction encoder drops the frame's gain it was given: the MLP sees unscaled direction features"),
    Mutant("frame_gain_applied_twice", "runtime/field/field.py",
           "finish_rows(buf, self._dir_col, self._phase_col, None, None if keep else phase, self._surface_col)",
           "finish_rows(buf, self._dir_col, self._phase_col, gains, None if keep else phase, self._surface_col)",
           ("tests/runtime/field/test_bundle.py::"
            "test_a_frames_gain_in_the_direction_encoder_equals_the_per_query_product",),
           "a frame's direction features are multiplied by its gain in the encoder and again over the rows"),
    Mutant("field_phase_rows_kept_for_another_g", "runtime/field/field.py",
           "keep = held is not None and held[0] == g0 and held[1] >= rows",
           "keep = held is not None and held[1] >= rows",
           ("tests/runtime/field/test_bundle.py::test_a_frames_phase_columns_are_kept_only_while_they_hold_its_g",),
           "a frame at another g reads the last frame's phase features from the reused buffer"),
    Mutant("field_phase_rows_kept_for_more_rows", "runtime/field/field.py",
           "keep = held is not None and held[0] == g0 and held[1] >= rows",
           "keep = held is not None and held[0] == g0",
           ("tests/runtime/field/test_bundle.py::test_a_frames_phase_columns_are_kept_only_while_they_hold_its_g",),
           "a longer chunk at the same g reads stale phase features past the rows written for it"),
    Mutant("field_phase_rows_kept_after_per_query_g", "runtime/field/field.py",
           "            if k is not None:\n                self._phase_rows[k] = None\n",
           "",
           ("tests/runtime/field/test_bundle.py::test_a_frames_phase_columns_are_kept_only_while_they_hold_its_g",),
           "after a query with per-query g the buffer is still taken to hold the frame g's row"),
    Mutant("field_inputs_one_phase_row", "runtime/field/inputs.py",
           "    row_step = 1 if phase.shape[0] == n and n > 1 else 0\n", "    row_step = 0\n",
           ("tests/runtime/field/test_inputs.py::test_finish_rows_equals_the_numpy_columns",),
           "per-query g: every row gets the first query's phase features"),
    Mutant("torch_ignores_direction_gain", "train/field/network.py",
           '        if self.cfg.direction_gain == "g":', "        if False:",
           ("tests/runtime/field/test_bundle.py::test_direction_gain_makes_the_field_isotropic_at_g_zero",),
           "the trained field is not isotropic at g = 0 (the cpu preset's field 3.5 % dark there on shell)"),
    Mutant("update_refuses_fields_without_gain", "train/fit/fine_tune.py",
           "cfg = replace(cfg, direction_gain=model.cfg.direction_gain, surface=surface)",
           "cfg = replace(cfg, surface=surface)",
           ("tests/train/fit/test_update.py::test_a_field_from_before_its_presets_direction_gain_keeps_its_own",),
           "every run trained before the cpu preset's direction gain is refused by pfn-train update and the viewer"),
    Mutant("surface_points_inwards", "models_spec/surface.py", "    v = -grad / (mag + c)\n",
           "    v = grad / (mag + c)\n",
           ("tests/models_spec/test_surface.py::"
            "test_the_grid_points_out_of_a_ball_at_its_surface_and_vanishes_inside_and_far_outside",),
           "the surface input's vector points into the medium: s reads entering rays as leaving ones"),
    Mutant("surface_columns_without_g", "models_spec/surface.py",
           "return np.stack([gg * s, gg * s * np.abs(s)], axis=1)", "return np.stack([s, gg * s * np.abs(s)], axis=1)",
           ("tests/models_spec/test_surface.py::test_the_columns_are_g_s_and_g_s_abs_s_of_the_trilinear_grid",),
           "the surface input's first column is not times g: the field is no longer isotropic at g = 0"),
    Mutant("surface_rows_axes_swapped", "runtime/field/inputs.py",
           "tz = min(max(np.float64(u[i, 2]) * sz - 0.5, 0.0), sz - 1.0)",
           "tz = min(max(np.float64(u[i, 0]) * sz - 0.5, 0.0), sz - 1.0)",
           ("tests/models_spec/test_surface.py::test_the_runtime_rows_equal_the_definition_bit_for_bit",
            "tests/runtime/field/test_bundle.py::test_parity_cpu_preset_in_a_non_unit_box"),
           "the runtime reads the surface grid at the wrong position: another function than the trained one"),
    Mutant("surface_cells_by_block_start", "models_spec/surface.py",
           "centres = (np.arange(n_voxels, dtype=np.float64) + 0.5) * (n_cells / n_voxels)",
           "centres = np.arange(n_voxels, dtype=np.float64) * (n_cells / n_voxels)",
           ("tests/models_spec/test_surface.py::test_a_coarse_volumes_cells_hold_the_mean_of_the_voxels_centred_in_them",),
           "a coarse volume's voxels are shared out to cells by their corner, not their centre: the grid shifts"),
    Mutant("update_keeps_the_runs_surfaces", "train/fit/fine_tune.py",
           "        model.set_surface(medium_surface_grid(scene.medium()))\n", "        pass\n",
           ("tests/train/fit/test_update.py::test_the_surface_input_follows_the_edited_scene",),
           "an update for a transfer-function edit keeps the old scene's surfaces in the surface input"),
    Mutant("export_without_surface", "train/export/bundle.py",
           "        out[SURFACE_ARRAY] = model.surface.detach().cpu().numpy().astype(SURFACE_DTYPE)\n",
           "        pass\n",
           ("tests/runtime/field/test_bundle.py::test_a_surface_bundles_grid_is_checked_like_its_tables",),
           "the bundle is written without the surface grid"),
    Mutant("resident_ignores_code", "runtime/resident/server.py", '        if request["code"] != self.code:\n',
           "        if False:\n",
           ("tests/runtime/cli/test_resident.py::test_another_code_fingerprint_is_not_run",),
           "a resident server renders with old code after the user edits or reinstalls the package"),
    Mutant("resident_ignores_environment", "runtime/resident/server.py", "        if theirs != ours:\n",
           "        if False:\n",
           ("tests/runtime/cli/test_resident.py::test_another_environment_renders_in_process",),
           "a resident server renders with another thread count or threading layer than the client asked for"),
    Mutant("depth_bounds_rect_short", "runtime/wavefront/depth_bounds.py", "a0 = max(math.floor(umin) - 1, 0)",
           "a0 = max(math.floor(umin) + 1, 0)",
           (f"{DEPTH}::test_every_ray_meets_the_medium_within_its_tiles_bounds",),
           "a macrocell's projected rectangle misses the pixels on its left edge: their rays skip medium"),
    Mutant("depth_bounds_behind_dropped", "runtime/wavefront/depth_bounds.py",
           "            all_near, all_far = min(all_near, lo), max(all_far, hi)\n",
           "            pass\n",
           (f"{DEPTH}::test_every_ray_meets_the_medium_within_its_tiles_bounds",
            f"{DEPTH}::test_bounds_change_no_sample_from_inside_the_volume",
            f"{DEPTH}::test_bounds_hold_for_an_eye_on_a_macrocell_plane"),
           "macrocells behind the eye's image plane (the eye inside the volume) are left out of every tile's bounds"),
    Mutant("depth_bounds_interior_eye_dropped", "runtime/wavefront/depth_bounds.py",
           "            if depth > _BEHIND:\n", "            if True:\n",
           (f"{DEPTH}::test_every_ray_meets_the_medium_within_its_tiles_bounds",),
           "interior macrocells are skipped even where they hold the eye: its rays start inside the medium late"),
    Mutant("depth_map_neighbour_tile", "runtime/denoise/depth.py",
           "tx = min(int(cx) // tile, ntx - 1)", "tx = min(int(cx) // tile + 1, ntx - 1)",
           ("tests/runtime/denoise/test_wrls_reprojection.py::"
            "test_depth_walks_within_tile_bounds_give_the_whole_walks_depths",),
           "a depth ray reads the depth bounds of the tile to its right: it skips medium or misses it"),
    Mutant("wrls_clamp_rows_fixed", "runtime/denoise/wrls_kernels.py",
           "_rows_extreme(hmin[i:i + 2 * clamp_r + 1]", "_rows_extreme(hmin[i:i + 3]",
           ("tests/runtime/denoise/test_wrls_reference.py::test_kernels_match_a_float64_reference",),
           "Psi's lower bound takes three filtered rows whatever the clamp radius"),
    Mutant("shadow_rest_collision_lets_light_through", "runtime/transport/tracking.py",
           "                            return kept, w_sum, 0.0, state\n",
           "                            return kept, w_sum, 0.5 * tr, state\n",
           ("tests/runtime/transport/test_tracking_numpy.py::test_ratio_tracking_matches_quadrature",),
           "a shadow ray's delta-tracked rest counts half the light at a real collision: NEE too bright"),
    Mutant("marcher_env_other_rays", "runtime/renderers/ray_marcher.py",
           "trans[None, :] * env.behind_camera_rays(cam, work, seed)",
           "trans[None, :] * env.behind_camera_rays(cam, work, seed + 1)",
           (f"{ENVRENDER}::test_ray_marcher_sees_the_map_along_each_camera_ray",),
           "the ray marcher looks the map up along other camera rays than the ones it marched"),
    Mutant("marcher_bounds_neighbour_tile", "runtime/renderers/ray_marcher.py",
           "        tx = (p % width) // tile\n", "        tx = min((p % width) // tile + 1, near.shape[1] - 1)\n",
           ("tests/runtime/renderers/test_ray_marcher.py::test_skipping_empty_space_changes_no_pixel",),
           "a marched ray starts at the near bound of the tile to its right: it skips medium or is not marched"),
    Mutant("depth_bounds_walk_starts_late", "runtime/wavefront/depth_bounds.py",
           "    return max(0.0, near[ty, tx] - entry), min(tmax, far[ty, tx] - entry)",
           "    return max(0.0, near[ty, tx] - entry + 0.02), min(tmax, far[ty, tx] - entry)",
           (f"{DEPTH}::test_bounds_change_no_sample_on_embedded_scenes",),
           "the first-interaction walk starts after its tile's near bound: rays skip the front of the medium"),
    Mutant("camera_rest_weight_one", "runtime/transport/tracking.py",
           "                        w_sum += tr  # the rest's collision",
           "                        w_sum += 1.0  # the rest's collision",
           (f"{CAMERA}::test_resampled_collision_matches_delta_tracking_on_one_ray[16.0-camera]",),
           "the camera walk's delta-tracked rest counts its collision with weight 1, not the transmittance so far"),
    Mutant("shadow_boost_ignored", "runtime/transport/tracking.py",
           "        if not rest:\n            maj *= boost\n",
           "",
           ("tests/runtime/transport/test_transport.py::"
            "test_boosted_ratio_tracking_keeps_the_mean_and_divides_the_variance[4.0]",),
           "shadow rays draw tentative collisions at the plain majorant whatever the boost: their noise stays"),
    Mutant("shadow_boost_in_the_rest", "runtime/transport/tracking.py",
           "                if tr < switch:\n                    rest = True\n",
           "                if tr < switch:\n                    rest = True\n                    tr *= 1.0 / boost\n",
           ("tests/runtime/transport/test_tracking_numpy.py::test_ratio_tracking_matches_quadrature[0.3-2.0]",),
           "the switch to the rest's flight rescales the estimate by the boost: shadows too dark"),
    Mutant("marched_pick_ignores_weights", "runtime/renderers/ray_marcher.py",
           "                    if u * w_sum < w:\n",
           "                    if u < 0.5 or w_sum == w:\n",
           ("tests/runtime/renderers/test_marched_indirect.py::"
            "test_the_picks_converge_to_the_neural_renderers_l_i_with_the_same_field",),
           "the marched L_i keeps each segment with probability 1/2 whatever its weight: later segments too often"),
    Mutant("marched_indirect_weight_one", "runtime/renderers/ray_marcher.py",
           "            pick[PICK_W, i] = w_sum\n", "            pick[PICK_W, i] = 1.0\n",
           ("tests/runtime/renderers/test_marched_indirect.py::"
            "test_a_constant_field_weights_each_ray_by_its_collision_probability",),
           "the marched L_i is weighted 1 instead of the ray's collision probability W: thin rays far too bright"),
    Mutant("marched_environment_unlit", "runtime/renderers/ray_marcher.py",
           "        film.splat(\"L_d\", pixel[sel], env, True, weight=weight)\n", "",
           ("tests/runtime/renderers/test_marched_indirect.py::"
            "test_an_environments_single_scattering_comes_from_nee_at_the_pick",),
           "the marched method leaves an environment's single scattering out, as the plain preview does"),
    Mutant("marched_camera_no_residual", "runtime/transport/residual_tracking.py",
           "        ratio *= 1.0 - (sigma - (sigma_c + slope * (t - t0))) / mu\n", "        ratio *= 1.0\n",
           (f"{CAMERA}::test_marched_walk_matches_delta_tracking_on_sharp_walls[16.0-coarse]",),
           "the marched camera's transmittance is the control's exp(-integral sigma_c) alone, without the residual "
           "ratio tracking's events: biased wherever sigma_t varies within a stratum (a thin wall in a long one)"),
    Mutant("marched_camera_flat_control_events", "runtime/transport/residual_tracking.py",
           "slope = (sigma_k - p_s) / (tk - p_t) if tk > p_t else 0.0", "slope = 0.0",
           (f"{CAMERA}::test_marched_walk_control_follows_a_linear_medium",
            "tests/runtime/transport/test_residual_tracking.py::test_residual_transmittance_is_unbiased"),
           "the residual events between two points correct a flat control while the exponential integrates the "
           "linear one: the marched camera's transmittance biased wherever sigma_t changes between points"),
    Mutant("marched_camera_rest_from_the_point", "runtime/wavefront/marched_camera.py",
           "tau, ratio, dc, s = constant_control_events(m, ox, oy, oz, dx, dy, dz, tk, b, boost * mu, sc,\n"
           "                                                                    tau, ratio, s)\n"
           "                        tau_c += dc\n                        rest = math.exp(-tau_c) * ratio\n"
           "                        t = b\n",
           "rest = tr\n                        t = tk\n",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_i-marched, dense]",),
           "the opaque rest's flight starts at the switching point, not at its stratum's end: the stretch between is "
           "counted twice (the stratum's candidate and the flight), dense media too bright"),
    Mutant("residual_shadow_without_its_last_tail", "runtime/transport/residual_tracking.py",
           "    if pend:  # the last point's tail\n", "    if False:  # the last point's tail\n",
           ("tests/runtime/transport/test_residual_tracking.py::test_residual_transmittance_is_unbiased",),
           "the residual shadow ray stops at its last point: the control's optical depth from there to the box or the "
           "light is left out, the marched picks' NEE too bright"),
    Mutant("staged_nee_drawn_light_unscaled", "runtime/transport/direct_light.py",
           "            ratio = total / c\n", "            ratio = 1.0\n",
           (f"{LSAMPLING}::test_staged_nee_with_residual_shadow_rays_has_the_one_stage_mean",),
           "the marched picks' NEE, one light per vertex, is not divided by the drawn light's probability: too dark "
           "wherever several lights reach a pick"),
    Mutant("staged_nee_first_light_only", "runtime/transport/residual_tracking.py",
           "        for j in range(i, lights.shape[1], n):\n", "        for j in range(i, i + 1):\n",
           (f"{LSAMPLING}::test_staged_nee_with_residual_shadow_rays_has_the_one_stage_mean",),
           "the marched picks' shadow rays to every light trace only the first light's: the others' light is lost"),
    Mutant("marched_camera_keeps_the_last", "runtime/wavefront/marched_camera.py",
           "            if v * w_abs < abs(w):\n", "            if v >= 0.0:\n",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_i-marched]",),
           "the marched camera's reservoir keeps the last candidate whatever the weights: the field is asked at the "
           "far end of the medium"),
    Mutant("marched_camera_one_draw_for_all_picks", "runtime/wavefront/marched_camera.py",
           "            v = u + q * step\n", "            v = u\n",
           (f"{CAMERA}::test_marched_walk_matches_delta_tracking_on_sharp_walls[16.0-default]",),
           "the marched camera's picks share one random number per candidate unshifted: every pick is the same "
           "point, the "
           "three field queries and shadow rays one sample bought three times"),
    Mutant("camera_choice_inverted", "runtime/wavefront/camera_choice.py",
           'choices[key] = "marched" if forced > cost_ratio(scene) * marched else "forced"',
           'choices[key] = "forced" if forced > cost_ratio(scene) * marched else "marched"',
           (f"{CHOICE}::test_the_choice_follows_the_probed_noise_ratio",
            f"{CHOICE}::test_auto_chooses_the_estimator_with_less_noise_per_unit_of_work"),
           "auto takes the estimator with more noise per unit of work"),
    Mutant("camera_choice_band_pixels_stretched", "runtime/wavefront/camera_choice.py",
           'half_w = half * aspect if cam.fov_axis == "y" else half', "half_w = half",
           (f"{CHOICE}::test_the_probe_band_is_the_full_cameras_middle_rows[y]",),
           "the probe's band has other pixels than the render (a wide image's band sees a narrower view): its noise "
           "is not the render's"),
    Mutant("camera_choice_cost_fixed", "runtime/wavefront/camera_choice.py",
           "return COST_RATIO * max(1.0, across / COST_RESOLUTION) ** COST_EXPONENT", "return COST_RATIO",
           (f"{CHOICE}::test_the_cost_ratio_grows_with_the_volumes_resolution",),
           "auto weighs the marched estimator's cost as on a 96^3 volume at any resolution (at 256^3 it costs ~1.8x "
           "more against forced)"),
    Mutant("camera_choice_key_without_pixel_size", "runtime/wavefront/camera_choice.py",
           "type(estimator).__name__, pixel_class(scene)\n", "type(estimator).__name__\n",
           (f"{CHOICE}::test_the_choice_follows_the_probed_noise_ratio",),
           "auto keeps the choice made at one pixel size for every other (a viewer's small dragging frames decide "
           "its full-size resting frames' estimator)"),
    Mutant("marched_camera_no_correction", "runtime/wavefront/marched_camera.py",
           "    return nee - cached.at_pick\n", "    return nee - nee\n",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_d-marched, scrambled cache]",),
           "the marched camera's L_d is the light volume's sum alone, without NEE's correction at the pick: the "
           "cache's error and the environment's single scattering reach the image"),
    Mutant("marched_camera_rest_weight_one", "runtime/wavefront/marched_camera.py",
           "a0, a1, a2, rest, w_abs,", "a0, a1, a2, 1.0, w_abs,",
           (f"{CAMERA}::test_camera_estimators_estimate_the_same_image[L_d-marched, dense]",),
           "the marched camera's opaque rest scores its collision with weight 1, not the transmittance estimate at "
           "the switch: dense media too bright"),
    Mutant("decode_all_fast_math", "runtime/field/outputs.py", '@njit(cache=True, fastmath={"afn", "nnan"})',
           "@njit(cache=True, fastmath=True)",
           ("tests/runtime/field/test_outputs.py::test_decode_lights_equals_numpy_bit_for_bit",),
           "the decode's sums contracted into fused multiply-adds: the field's output differs from numpy's in last "
           "bits"),
    Mutant("demo_warm_up_auto_only", "train/cli/demo.py", "    for camera in AUTO_CHOICES:\n",
           "    for camera in (\"auto\",):\n",
           ("tests/train/cli/test_demo.py::test_the_warm_up_compiles_every_estimator_that_auto_may_take",),
           "the demo warms up with auto alone, which renders its tiny view forced: a fresh clone's marched kernels "
           "compile inside the timed neural render, and the equal-time path tracer gets that time as samples"),
    Mutant("nee_items_made_by_a_factory", "runtime/transport/direct_light.py",
           "def direct_light_batch(",
           "def _items_of(nee):\n"
           "    @njit(cache=True)\n"
           "    def items(m, kind, vec, rgb, env, g, o, d, states, env_mis, boost, out, lo, hi):\n"
           "        for i in range(lo, hi):\n"
           "            out[0, i], out[1, i], out[2, i], states[i] = nee(m, kind, vec, rgb, env, g, o[0, i], o[1, i],"
           " o[2, i], d[0, i], d[1, i], d[2, i], states[i], env_mis, boost)\n"
           "    return items\n\n\n"
           "def _batch_of(items):\n"
           "    @njit(cache=True, parallel=True)\n"
           "    def batch(m, kind, vec, rgb, env, g, o, d, states, env_mis, boost):\n"
           "        n = o.shape[1]\n"
           "        out = np.empty((3, n))\n"
           "        for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):\n"
           "            items(m, kind, vec, rgb, env, g, o, d, states, env_mis, boost, out, task * TASK_ITEMS,"
           " min(n, (task + 1) * TASK_ITEMS))\n"
           "        return out\n"
           "    return batch\n\n\n"
           "_one_light_batch = _batch_of(_items_of(direct_light_one))\n\n\n"
           "def direct_light_batch(",
           ("tests/runtime/test_kernel_cache.py::test_every_cached_kernel_has_the_same_cache_key_in_a_new_process",
            "tests/runtime/test_kernel_cache.py::test_a_second_process_loads_every_kernel_the_first_compiled"),
           "NEE's one-light loop and its parallel batch made by factories closing over the kernels they call, as "
           "from 2026-11-27 to 11-30: their cache keys hold the dispatchers' per-process uuids, so every new process "
           "compiles them again (~20 s)"),
    Mutant("inlining_patch_left_out_of_phase", "runtime/transport/phase.py",
           "install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)\n", "",
           ("tests/runtime/test_numba_inlining.py::"
            "test_every_module_with_an_inlined_kernel_installs_the_patch_at_import",),
           "a module with inline kernels that does not install the inliner patch: a kernel inlining them alone "
           "compiles with numba's slow copies"),
    Mutant("inlining_patch_never_installed", "runtime/numba_inlining.py",
           "    _installed = False\n    if os.environ", "    _installed = True\n    return True\n    if os.environ",
           ("tests/runtime/test_numba_inlining.py::test_the_patch_applies_to_this_numba",),
           "install() reports the patch in place without patching numba: every cold compile as slow as before"),
    Mutant("marched_walk_counts_references", "runtime/wavefront/marched_camera.py",
           "    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)\n", "",
           ("tests/runtime/test_borrowed.py::test_every_task_kernel_of_a_parallel_loop_borrows_its_medium",),
           "the marched walk's task kernel without its borrowed medium: every macrocell step counts the medium's "
           "arrays up and down again (the walk 1.3x slower)"),
    Mutant("borrowed_keeps_the_meminfo", "runtime/borrowed.py",
           "        out.meminfo = cgutils.get_null_value(out.meminfo.type)\n",
           "        out.meminfo = source.meminfo\n        context.nrt.incref(builder, signature.args[0], args[0])\n",
           ("tests/runtime/test_borrowed.py::test_borrowing_takes_the_reference_counting_out_of_the_inlined_walk",),
           "a borrowed array that is a counted reference like any other (its owner's meminfo, incremented): every "
           "increment and decrement in the walks again"),
    Mutant("prefetch_moves_the_stratum_point", "runtime/wavefront/marched_camera.py",
           "                        qx, qy, qz = x + length * dx, y + length * dy, z + length * dz\n"
           "                        prefetch_scalar_stencil(m, qx, qy, qz)\n"
           "                        prefetch_light_stencil(lv, grid, qx, qy, qz)\n",
           "                        x, y, z = x + length * dx, y + length * dy, z + length * dz\n"
           "                        prefetch_scalar_stencil(m, x, y, z)\n"
           "                        prefetch_light_stencil(lv, grid, x, y, z)\n",
           ("tests/runtime/transport/test_prefetch.py::"
            "test_the_marches_give_the_same_images_with_and_without_prefetching",),
           "the marched walk's prefetch computes the next stratum's point into the current one's variables: with "
           "prefetching on, every stratum is read a stratum further on"),
    Mutant("prefetch_advances_the_preview_step", "runtime/renderers/ray_marcher.py",
           "                tn = t_next + 0.5 * h\n"
           "                qx, qy, qz = ox + tn * dx, oy + tn * dy, oz + tn * dz\n",
           "                t_next = t_next + 0.5 * h\n"
           "                qx, qy, qz = ox + t_next * dx, oy + t_next * dy, oz + t_next * dz\n",
           ("tests/runtime/transport/test_prefetch.py::"
            "test_the_marches_give_the_same_images_with_and_without_prefetching",),
           "the preview's prefetch moves the segment's end instead of computing a point of its own"),
    Mutant("preview_last_samples_unlit", "runtime/renderers/ray_marcher.py",
           "samples, ray_of,\n                   count, dirs, phases, lo)",
           "samples, ray_of,\n                   0, dirs, phases, lo)",
           (f"{RAY_MARCHER}::test_a_coarse_step_reads_the_light_at_the_lit_wall",
            f"{RAY_MARCHER}::test_the_light_of_buffered_samples_is_the_same_whatever_the_buffer"),
           "the preview's samples still in the buffer when a task's last ray ends get no light"),
    Mutant("preview_full_buffer_unlit", "runtime/renderers/ray_marcher.py",
           "                                   samples, ray_of, count, dirs, phases, lo)",
           "                                   samples, ray_of, 0, dirs, phases, lo)",
           (f"{RAY_MARCHER}::test_the_light_of_buffered_samples_is_the_same_whatever_the_buffer",),
           "a full buffer of the preview's samples is emptied without their light"),
    Mutant("margin_faces_only", "runtime/transport/light_volume.py",
           "                                    _mark_unfilled(v, wanted, p, q, r, light, NEIGHBOUR)\n",
           "                                    if abs(p - a) + abs(q - b) + abs(r - e) == 1:\n"
           "                                        _mark_unfilled(v, wanted, p, q, r, light, NEIGHBOUR)\n",
           (f"{RAY_MARCHER}::test_a_margin_fills_the_cells_beside_those_frames_filled_once_and_changes_no_image",),
           "the light volume's margin fills only the 6 face neighbours of the filled cells, not the 26"),
    Mutant("margin_cascades", "runtime/transport/light_volume.py",
           "        if _fill_brick(m, kind, vec, v, grid, h, units, bricks[b, 0], bricks[b, 1], bricks[b, 2]):\n",
           "        if _fill_brick(m, kind, vec, v, grid, h, units, bricks[b, 0], bricks[b, 1], bricks[b, 2]) "
           "or True:\n",
           (f"{RAY_MARCHER}::test_a_margin_fills_the_cells_beside_those_frames_filled_once_and_changes_no_image",),
           "the cells a margin fill marched seed the next margin: each idle moment grows the filled region a ring"),
    Mutant("margin_marks_never_filled", "runtime/transport/light_volume.py",
           "                    if state != WANTED and state != NEIGHBOUR:\n",
           "                    if state != WANTED:\n",
           (f"{RAY_MARCHER}::test_a_margin_fills_the_cells_beside_those_frames_filled_once_and_changes_no_image",
            f"{RAY_MARCHER}::test_a_cancelled_margin_is_completed_by_the_next_fill"),
           "the fill skips the cells a margin marked: they stay marked (and read as unfilled) for ever"),
    Mutant("viewer_idle_no_margin", "runtime/viewer/server.py",
           "                    fill_light_margins(self.session, self.stop_event)  # nothing to render: the next "
           "view's cells\n",
           "",
           ("tests/runtime/viewer/test_viewer_server.py::test_the_render_loop_fills_the_light_volumes_margin_once_the_"
            "view_rests",),
           "the viewer's render thread idles without filling the light volumes' margins"),
    Mutant("idle_work_ignores_render_turn", "runtime/viewer/idle_work.py",
           "    if not RENDER_LOCK.acquire(blocking=False):",
           "    if not RENDER_LOCK.acquire(blocking=False) and False:",
           ("tests/runtime/viewer/test_viewer_preview.py::test_idle_work_gives_way_to_every_pages_frames",),
           "the idle margin fills while another page's frame renders (both on the cores, on a shared light volume)"),
    Mutant("idle_work_skips_levels", "runtime/viewer/idle_work.py",
           '    scenes = [session.scene, *session.scene.shared_cache("levels").values()]',
           "    scenes = [session.scene]",
           ("tests/runtime/viewer/test_viewer_preview.py::test_idle_work_fills_the_margin_of_the_interactive_levels_"
            "light_volume_too",),
           "the idle margin leaves the interactive level's light volume (the first frame after each change) alone"),
    Mutant("depth_bounds_skip_the_interior", "runtime/wavefront/depth_bounds.py",
           "    n = cells.shape[0] if box_depth <= _BEHIND else n_boundary\n",
           "    n = n_boundary\n",
           ("tests/runtime/wavefront/test_depth_bounds.py::test_bounds_change_no_sample_from_inside_the_volume",
            "tests/runtime/wavefront/test_depth_bounds.py::test_every_ray_meets_the_medium_within_its_tiles_bounds"),
           "the depth bounds never rasterize the interior macrocells, not even when the eye is inside the medium: "
           "rays that start in it lose their walk"),
)


#: Folder inside a copy holding the photon_fields namespace (symlinks to the copy's fixed folders).
PACKAGE_ROOT = "_namespace"


def repo_files(root: Path) -> list[str]:
    """Tracked files and untracked, not ignored ones, as they are in the working tree."""
    out = subprocess.run(["git", "-C", str(root), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                         check=True, capture_output=True).stdout.decode()
    return sorted({f for f in out.split("\0") if f and (root / f).is_file()})


def check_mutant(root: Path, m: Mutant) -> str | None:
    """None if the mutant applies (original found exactly once), else the reason."""
    path = root / m.file
    if not path.is_file():
        return f"{m.file} does not exist"
    count = path.read_text().count(m.original)
    if count != 1:
        return f"the original text occurs {count} times in {m.file} (must be exactly once): {m.original!r}"
    if not m.tests:
        return "no tests named"
    return None


def make_copy(root: Path, files: list[str], dest: Path, mutant: Mutant | None) -> None:
    for f in files:
        target = dest / f
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / f, target)
    # The fixed folders are installed as photon_fields.runtime / .train / .models_spec (package-dir in
    # pyproject.toml): the same namespace over the copy's folders, first on PYTHONPATH (run_env).
    namespace = dest / PACKAGE_ROOT / "photon_fields"
    namespace.mkdir(parents=True)
    for folder in ("runtime", "train", "models_spec"):
        (namespace / folder).symlink_to(dest / folder, target_is_directory=True)
    if mutant is not None:
        path = dest / mutant.file
        text = path.read_text()
        assert text.count(mutant.original) == 1
        path.write_text(text.replace(mutant.original, mutant.replacement))


def run_env(copy: Path, cache: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_CACHE_DIR", "PYTHONPATH"))}
    env.update({"PYTHONPATH": os.pathsep.join([str(copy / PACKAGE_ROOT), str(copy)]), "NUMBA_CACHE_DIR": str(cache),
                "PYTHONDONTWRITEBYTECODE": "1"})
    return env


IMPORT_CHECK = """
import sys
sys.path.insert(0, 'tests')
import conftest
import photon_fields.models_spec, photon_fields.runtime.scene.scene, photon_fields.train.fit.loop
for mod in (conftest, photon_fields.models_spec, photon_fields.runtime.scene.scene, photon_fields.train.fit.loop):
    print(mod.__file__)
"""


def check_imports(python: str, copy: Path, env: dict[str, str]) -> None:
    """The copy's modules, not the editable install's (a mutant there would be tested against clean code)."""
    out = subprocess.run([python, "-c", IMPORT_CHECK], cwd=copy, env=env, capture_output=True, text=True, check=True)
    for line in out.stdout.split():
        if not Path(line).resolve().is_relative_to(copy.resolve()):
            raise SystemExit(f"error: {line} is imported from outside the copy {copy}: the check would be void")


def run_tests(python: str, copy: Path, tests: tuple[str, ...], timeout: float) -> tuple[str, list[str], float, str]:
    """(status, failed node ids, seconds, output tail) for ``tests`` in ``copy`` with a fresh numba cache."""
    with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
        env = run_env(copy, Path(cache))
        check_imports(python, copy, env)
        cmd = [python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfE", "--tb=line", *tests]
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, cwd=copy, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return "timeout", [], time.perf_counter() - t0, ""
        seconds = time.perf_counter() - t0
    output = proc.stdout + proc.stderr
    failed = sorted({m.group(2) for m in re.finditer(r"^(FAILED|ERROR) (\S+)", output, re.MULTILINE)})
    status = {0: "passed", 1: "failed", 2: "failed"}.get(proc.returncode, f"pytest exit {proc.returncode}")
    return status, failed, seconds, "\n".join(output.strip().splitlines()[-15:])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--only", nargs="+", metavar="NAME", help="run these mutants only")
    p.add_argument("--list", action="store_true", help="print the table and exit")
    p.add_argument("--check", action="store_true", help="only check that every mutant applies")
    p.add_argument("--no-baseline", action="store_true", help="skip the run on the unmodified copy")
    p.add_argument("--timeout", type=float, default=1800.0, help="seconds per pytest run")
    p.add_argument("--python", default=sys.executable, help="interpreter with the project's dependencies")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON report")
    args = p.parse_args(argv)

    mutants = list(MUTANTS)
    if args.only:
        unknown = sorted(set(args.only) - {m.name for m in MUTANTS})
        if unknown:
            p.error(f"unknown mutants {unknown}; known: {', '.join(m.name for m in MUTANTS)}")
        mutants = [m for m in MUTANTS if m.name in args.only]
    if args.list:
        for m in mutants:
            print(f"{m.name:34s} {m.file:30s} {m.bug}\n{'':34s} tests: {', '.join(m.tests)}")
        return 0
    problems = [(m.name, why) for m in mutants if (why := check_mutant(ROOT, m))]
    for name, why in problems:
        print(f"error: mutant {name}: {why}", file=sys.stderr)
    if problems:
        return 2
    if args.check:
        print(f"all {len(mutants)} mutants apply")
        return 0

    sys.path.insert(0, str(ROOT / "bench"))
    from common import machine_info, write_report

    info = machine_info()
    files = repo_files(ROOT)
    results: list[dict[str, Any]] = []
    baseline: dict[str, Any] | None = None
    with tempfile.TemporaryDirectory(prefix="pfn-mutants-") as tmp:
        if not args.no_baseline:
            tests = tuple(dict.fromkeys(t for m in mutants for t in m.tests))
            copy = Path(tmp) / "baseline"
            make_copy(ROOT, files, copy, None)
            print(f"baseline: {len(tests)} tests on an unmodified copy ...", flush=True)
            status, failed, seconds, tail = run_tests(args.python, copy, tests, args.timeout)
            baseline = {"status": status, "failed": failed, "seconds": round(seconds, 1)}
            print(f"baseline: {status} in {seconds:.0f} s", flush=True)
            shutil.rmtree(copy)
            if status != "passed":
                print(f"error: the named tests do not pass without mutants:\n{tail}", file=sys.stderr)
                return 2
        for m in mutants:
            copy = Path(tmp) / m.name
            make_copy(ROOT, files, copy, m)
            print(f"{m.name}: {len(m.tests)} tests ...", end=" ", flush=True)
            status, failed, seconds, tail = run_tests(args.python, copy, m.tests, args.timeout)
            verdict = {"failed": "killed", "passed": "survived", "timeout": "killed"}.get(status, "error")
            print(f"{verdict} ({seconds:.0f} s){': ' + ', '.join(failed) if failed else ''}", flush=True)
            if verdict == "error":
                print(tail, file=sys.stderr)
            results.append({**asdict(m), "status": verdict, "pytest": status, "killed_by": failed,
                            "seconds": round(seconds, 1)})
            shutil.rmtree(copy)

    print(f"\n{'mutant':34s} {'status':9s} killed by")
    for r in results:
        names = [t.split("::", 1)[1] for t in r["killed_by"]]
        print(f"{r['name']:34s} {r['status']:9s} {', '.join(names)}")
    bad = [r["name"] for r in results if r["status"] != "killed"]
    write_report(args.out, "mutants", info,
                 {"python": args.python, "timeout_s": args.timeout, "files_copied": len(files)},
                 baseline=baseline, mutants=results, survived_or_error=bad)
    if bad:
        print(f"NOT KILLED: {', '.join(bad)}", file=sys.stderr)
        return 1
    print(f"all {len(results)} mutants killed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
