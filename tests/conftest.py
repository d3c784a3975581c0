"""Shared fixtures. Tests run on CPU in float32 unless they ask for ``x64``.

The slow tier: ``pytest -m "not slow"`` leaves out the notebooks and the files and tests named in
:data:`SLOW_FILES` and :data:`SLOW_TESTS` (the README runner, command-line runs in fresh processes,
NUTS posteriors, coverage studies): under 5 minutes on 2 cores, for everyday work. ``pytest`` runs all.
"""

import gc
import os
import pathlib

import jax
import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
# Chosen from `pytest --durations=0` of the whole suite on 2 cores (2026-12-04): a file is slow when a
# fixture of it takes 4 s or more to build, a test when it takes 2 s or more (all its parameters). The tests of
# 4 s or more in `pytest -m "not slow" --durations=60` were added on 2026-12-06 (the quick tier had grown to 7.8 min).
#: Test files whose every test is slow (paths relative to the repository).
SLOW_FILES = frozenset({
    "tests/bias/test_adapt.py",
    "tests/bias/test_bias_grid.py",
    "tests/bias/test_looking_estimators.py",
    "tests/calibration/test_cone_fit.py",
    "tests/calibration/test_posterior.py",
    "tests/calibration/test_simulated.py",
    "tests/cli/test_attend.py",
    "tests/cli/test_demo.py",
    "tests/cli/test_joint_cli.py",
    "tests/concurrence/test_covariance_coverage.py",
    "tests/concurrence/test_modes.py",
    "tests/concurrence/test_recording.py",
    "tests/concurrence/test_scenes.py",
    "tests/facial/test_chain.py",
    "tests/facial/test_image_features.py",
    "tests/facial/test_spatial.py",
    "tests/gp/test_exact.py",
    "tests/headpose/test_regression.py",
    "tests/joint/test_infer.py",
    "tests/joint/test_rivals.py",
    "tests/papers/test_siegfried2017.py",
    "tests/simulate/test_conversation.py",
    "tests/simulate/test_dyadic.py",
    "tests/simulate/test_scenes.py",
    "tests/test_devices.py",
    "tests/test_precision.py",
    "tests/test_readme.py",
    "tests/vision/test_attend.py",
    "tests/vision/test_tracker.py",
})
#: Single slow tests (pytest node ids without parameters) in files that are otherwise quick.
SLOW_TESTS = frozenset({
    "tests/cli/test_bias.py::test_bias_csv_bayes",
    "tests/cli/test_bias.py::test_bias_openface_bayes_with_targets_csv",
    "tests/cli/test_bias.py::test_bias_openface_constant_target_lmeds_and_segments_csv",
    "tests/cli/test_bias.py::test_bias_progress_bar_on_tty",
    "tests/cli/test_calibrate.py::test_calibrate_a_partner_close_by_runs_with_the_override",
    "tests/cli/test_calibrate.py::test_calibrate_failure_modes",
    "tests/cli/test_calibrate.py::test_calibrate_posterior_that_did_not_mix_exits_1",
    "tests/cli/test_calibrate.py::test_calibrate_two_wearers_of_one_joint_reconstruction",
    "tests/cli/test_calibrate.py::test_calibrate_warns_of_implausible_speeds",
    "tests/cli/test_calibrate.py::test_calibrate_with_posterior",
    "tests/cli/test_calibrate.py::test_concurrences_with_calibration",
    "tests/cli/test_calibrate.py::test_readme_joint_colmap_chain",
    "tests/cli/test_concurrences_demo.py::test_concurrences_bandwidth_column_and_quiet",
    "tests/cli/test_concurrences_demo.py::test_concurrences_full_covariance_tracks_members_mutual_gaze_and_figure",
    "tests/cli/test_concurrences_demo.py::test_concurrences_known_scene",
    "tests/cli/test_concurrences_demo.py::test_demo_writes_table_and_figure",
    "tests/cli/test_concurrences_demo.py::test_entry_point_subprocess_and_min_rays",
    "tests/cli/test_interrupt.py::test_ctrl_c_during_nuts_exits_130_and_leaves_no_file",
    "tests/cli/test_one_person_cli.py::test_one_wearer_over_frames_with_members_and_figure",
    "tests/concurrence/test_meanshift_pallas.py::test_fused_kernel_equals_xla_path_in_float64",
    "tests/concurrence/test_meanshift_pallas.py::test_fused_kernel_float32_plain_steps_agree_and_climb",
    "tests/concurrence/test_meanshift_pallas.py::test_seed_behind_every_ray_stays_put_and_is_not_converged",
    "tests/concurrence/test_metrics.py::test_hungarian_matches_brute_force",
    "tests/concurrence/test_refinement_result.py::test_a_start_that_is_not_finite_falls_back_with_a_code",
    "tests/concurrence/test_refinement_result.py::test_over_frames_codes_keep_the_frame_shape_and_padding_is_successful",
    "tests/concurrence/test_refinement_result.py::test_refinement_out_of_steps_is_a_code_per_concurrence",
    "tests/concurrence/test_runtime_guard.py::test_audit_flags_a_call_that_jaxlib_splits",
    "tests/concurrence/test_runtime_guard.py::test_batching_does_not_change_the_concurrences",
    "tests/concurrence/test_runtime_guard.py::test_long_recording_never_hangs",
    "tests/concurrence/test_runtime_guard.py::test_long_recording_programs_cannot_split_lapack_calls",
    "tests/concurrence/test_runtime_guard.py::test_posterior_programs_cannot_split_lapack_calls",
    "tests/facial/test_orientation.py::test_esc_threshold_matches_the_best_fixed_threshold_of_a_sweep",
    "tests/facial/test_orientation.py::test_facial_gaze_rays_feed_the_concurrence_finder",
    "tests/facial/test_orientation.py::test_shape_sd_makes_intervals_cover_the_simulated_faces",
    "tests/faults/test_bandwidth_floor.py::test_the_narrowest_accepted_bandwidth_keeps_the_other_rays_concurrence",
    "tests/faults/test_cache.py::test_a_cache_on_a_full_disk_gives_one_warning_line",
    "tests/faults/test_cache.py::test_a_truncated_entry_is_replaced_and_warns_no_more",
    "tests/faults/test_covariances.py::test_a_degenerate_mode_has_a_positive_definite_covariance",
    "tests/faults/test_covariances.py::test_a_degenerate_mode_has_a_positive_definite_covariance_in_a_recording",
    "tests/faults/test_far_from_origin.py::test_cli_gives_the_same_concurrences_5000_km_away",
    "tests/faults/test_far_from_origin.py::test_recording_and_stream_give_the_same_concurrences_5000_km_away",
    "tests/faults/test_figure_full_disk.py::test_a_full_disk_gives_one_line_for_every_figure_format",
    "tests/faults/test_frame_ids.py::test_concurrences_cli_keeps_64_bit_frames_apart",
    "tests/faults/test_injection.py::test_members_csv_of_hostile_names_is_safe",
    "tests/faults/test_input_limits.py::test_dev_zero_is_refused",
    "tests/faults/test_input_limits.py::test_fifo_without_writer_is_refused_without_blocking",
    "tests/faults/test_input_limits.py::test_file_over_the_size_limit_is_refused_before_reading",
    "tests/faults/test_input_limits.py::test_huge_single_line_is_refused",
    "tests/faults/test_input_limits.py::test_nul_bytes_are_refused",
    "tests/faults/test_signals.py::test_a_signal_in_the_first_seconds_ends_the_command_cleanly",
    "tests/faults/test_signals.py::test_a_signal_while_writing_keeps_every_old_output_and_no_temporary_file",
    "tests/faults/test_signals.py::test_sigkill_while_writing_leaves_no_mixed_set_and_the_next_run_removes_the_litter",
    "tests/gp/test_kernels.py::test_kernel_matrices_are_symmetric_and_psd",
    "tests/gp/test_kernels.py::test_kernel_matrices_match_sklearn",
    "tests/gp/test_kernels.py::test_kernels_work_under_jit_and_grad",
    "tests/gp/test_kernels.py::test_vectorised_matrix_equals_vmap_of_evaluate",
    "tests/headpose/test_nn.py::test_early_stopping_returns_best_validation_weights",
    "tests/headpose/test_nn.py::test_fit_equals_hand_written_pipeline",
    "tests/headpose/test_nn.py::test_initial_weights_uniform_in_half_interval_and_reproducible",
    "tests/headpose/test_nn.py::test_learns_smooth_function_like_sklearn",
    "tests/headpose/test_nn.py::test_online_epoch_matches_per_sample_python_loop",
    "tests/headpose/test_target.py::test_disk_hits_box_matches_sampling",
    "tests/headpose/test_target.py::test_pipeline_on_simulated_sessions",
    "tests/io/test_fuzz_readers.py::test_reader_parses_or_names_the_file",
    "tests/io/test_gaze360_l2cs.py::test_gaze360_90_percent_cone_holds_90_percent_of_true_directions",
    "tests/io/test_models.py::test_gp_round_trip_predicts_the_same_in_float64",
    "tests/io/test_models.py::test_kernel_json_round_trip_and_registry",
    "tests/io/test_tables.py::test_calibrated_rays_are_the_cones_rays",
    "tests/io/test_video.py::test_render_tabletop_video_draws_the_head_at_the_session_pose",
    "tests/joint/test_head_only.py::test_a_gaussian_process_map_is_kept_where_heads_saturate",
    "tests/joint/test_head_only.py::test_a_head_trackers_per_frame_sd_widens_the_head_only_likelihood",
    "tests/joint/test_head_only.py::test_a_tracker_reading_pitch_worse_leaves_the_tilt_couplings",
    "tests/joint/test_head_only.py::test_each_frames_term_is_the_prefix_likelihood_it_adds",
    "tests/joint/test_head_only.py::test_frame_scores_are_finite_for_someone_alone",
    "tests/joint/test_head_only.py::test_head_only_gradients_match_finite_differences",
    "tests/joint/test_head_only.py::test_head_only_likelihood_matches_brute_force",
    "tests/joint/test_head_only.py::test_one_video_of_the_group_gives_the_couplings_and_who_looks_at_whom",
    "tests/joint/test_head_only.py::test_the_first_descent_keeps_the_profiles_couplings",
    "tests/joint/test_model.py::test_a_masked_slot_is_the_model_without_it",
    "tests/joint/test_model.py::test_absent_people_are_no_candidates_and_add_nothing",
    "tests/joint/test_model.py::test_bad_input_names_what_and_where",
    "tests/joint/test_model.py::test_blocks_restart_the_chain",
    "tests/joint/test_model.py::test_gradients_match_finite_differences",
    "tests/joint/test_model.py::test_held_spot_matches_brute_force_enumeration",
    "tests/joint/test_model.py::test_held_spot_stays_bounded_as_the_cone_narrows",
    "tests/joint/test_model.py::test_marginal_matches_brute_force_enumeration",
    "tests/joint/test_model.py::test_masked_slots_leave_the_values_and_the_inverse_hessian",
    "tests/joint/test_model.py::test_the_likelihood_finds_the_share_a_fixation_holds",
    "tests/joint/test_model.py::test_the_written_out_adjoint_matches_autodiff_of_the_scan",
    "tests/joint/test_spot.py::test_the_spot_is_kept_where_fixations_hold_one_and_dropped_where_not",
    "tests/joint/test_spot.py::test_the_spots_bayes_factor_against_adaptive_quadrature",
    "tests/simulate/test_calibration.py::test_deterministic_for_a_key",
    "tests/simulate/test_calibration.py::test_simulate_wearers_batch",
    "tests/test_doors.py::test_no_import_past_a_door",
    "tests/test_examples.py::test_bias_example_from_openface",
    "tests/test_examples.py::test_calibrate_example_and_its_colmap_twin",
    "tests/test_examples.py::test_concurrences_example",
    "tests/test_examples.py::test_convert_example_camera_tools_then_concurrences",
    "tests/test_geometry.py::test_head_pose_rotation_signs_and_round_trip",
    "tests/test_layout.py::test_import_jaxgaze_loads_no_opencv_and_no_simulator",
    "tests/test_layout.py::test_subpackages_that_need_opencv_load_on_first_use",
    "tests/test_looking_at_each_other.py::test_agrees_with_the_joint_posterior_where_biases_are_zero",
    "tests/test_looking_at_each_other.py::test_frames_and_masks_are_vectorised",
    "tests/test_looking_at_each_other.py::test_probabilities_are_calibrated_and_beat_the_angle_rule",
    "tests/test_nuts.py::test_fixed_mass_matrix_samples_a_badly_scaled_gaussian",
    "tests/test_nuts.py::test_laplace_inverse_mass_floors_curvature_and_refuses_nonfinite",
    "tests/test_nuts.py::test_laplace_inverse_mass_of_a_gaussian_is_its_covariance",
    "tests/test_plotting.py::test_recording_a_concurrence_has_its_track_colour_in_every_panel",
    "tests/test_plotting.py::test_scene_story_one_colour_scale_and_one_colorbar",
    "tests/test_poses.py::test_similarity_alignment_recovers_known_transform",
    "tests/test_runtime.py::test_a_second_process_compiles_nothing",
    "tests/test_runtime.py::test_import_turns_the_cache_on_and_off_switches_it_off",
    "tests/vision/test_faces.py::test_lfw_subset_detection_and_false_positive_rates",
})


#: The files that take most of the suite's time, heaviest first (seconds of their slowest tests in
#: ``pytest --durations=80`` on 2 cores, 2026-12-05: 496, 265, 122, 106, 103, 99, 96, 86, 80, 75, 63, 62, 57 …).
#: They are handed out first, so that no worker starts one of them when the other is nearly done: pytest-xdist's
#: ``--dist loadfile`` hands out files in collection order (``--no-loadscope-reorder`` in pyproject.toml; its
#: default orders them by their number of tests, which put the one-test notebooks and the few long fits last).
HEAVY_FILES = (
    "tests/test_readme.py", "tests/joint/test_rivals.py", "tests/joint/test_infer.py",
    "tests/concurrence/test_runtime_guard.py", "tests/test_devices.py", "tests/calibration/test_simulated.py",
    "tests/joint/test_head_only.py", "tests/cli/test_joint_cli.py", "tests/concurrence/test_modes.py",
    "tests/headpose/test_regression.py", "notebooks/09_head_pose_only.ipynb", "tests/bias/test_bias_grid.py",
    "tests/concurrence/test_recording.py", "tests/papers/test_siegfried2017.py",
    "tests/concurrence/test_covariance_coverage.py", "tests/test_precision.py", "tests/vision/test_attend.py",
    "tests/concurrence/test_scenes.py", "tests/faults/test_signals.py", "tests/cli/test_calibrate.py",
    "tests/test_examples.py", "tests/facial/test_image_features.py", "notebooks/07_joint_inference.ipynb",
    "tests/faults/test_covariances.py", "tests/cli/test_concurrences_demo.py", "notebooks/03_speaker_prior_bias.ipynb",
)


def pytest_collection_modifyitems(config, items):
    """Mark the slow tier (the notebooks, :data:`SLOW_FILES` and :data:`SLOW_TESTS`) and put the
    :data:`HEAVY_FILES` first, heaviest first (the order within a file kept)."""
    rank = {name: k for k, name in enumerate(HEAVY_FILES)}
    order = {}
    for index, item in enumerate(items):
        path = pathlib.Path(str(item.path)).resolve()
        relative = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
        base = item.nodeid.split("[")[0]
        if relative.startswith("notebooks/") or relative in SLOW_FILES or base in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)
        order[item.nodeid] = (rank.get(relative, len(HEAVY_FILES)), index)
    items.sort(key=lambda item: order[item.nodeid])

# No persistent compilation cache inside the test processes (``import jaxgaze`` would turn it on): a
# worker compiles what it runs, as it did before issue 34, and never loads programs another worker
# is writing. The commands the tests start as subprocesses keep it (the environment is untouched),
# and tests/test_runtime.py and tests/faults/test_cache.py check the cache in fresh processes.
jax.config.update("jax_enable_compilation_cache", False)


@pytest.fixture
def x64():
    """Run the test body with ``jax_enable_x64`` on, restoring it afterwards."""
    with jax.enable_x64(True):
        yield


def _pin_worker_to_one_core() -> None:
    """Give each pytest-xdist worker a core of its own when there are as many workers as cores.

    XLA:CPU hands the work of one program to a pool of threads per process and waits for them. Two
    workers on two cores run four such threads, and a thread that waits on another process's
    time slice stalls its program: the Yücel regression fixture took 430 s in the whole suite against
    39 s alone, and 174 s against 64 s pinned with one other XLA process busy (2026-12-04,
    tests/headpose/test_regression.py + tests/calibration/test_simulated.py: 257 s → 165 s on 2
    cores). The processes a test starts inherit the core. Runs without workers keep every core.
    """
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if worker.startswith("gw") and cores and workers >= len(cores) > 1:
        os.sched_setaffinity(0, {cores[int(worker[2:]) % len(cores)]})


_pin_worker_to_one_core()


#: Memory maps a test process may hold before its compiled programs are dropped (Linux allows 65,530 a process,
#: ``vm.max_map_count``). Every XLA:CPU executable maps its own code pages: tests/joint/test_rivals.py alone
#: reaches 16,000, and a worker that had run other joint files before it died inside LLVM ("Cannot allocate
#: memory") in CI on 2026-12-04. ``jax.clear_caches()`` with a collection gives them back (13,416 → 1,632).
MAX_MAPS_BEFORE_CLEARING = 30_000


def pytest_runtest_teardown(item, nextitem):
    """Drop compiled programs after a test when the process nears the kernel's limit on memory maps."""
    maps = pathlib.Path("/proc/self/maps")
    if maps.exists() and sum(1 for _ in maps.open()) > MAX_MAPS_BEFORE_CLEARING:
        jax.clear_caches()
        gc.collect()
