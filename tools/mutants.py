"""Plant known mistakes (mutants) in the source, one at a time, and see which test catches each.

A developer tool (not run by ``make test``): issue 20 asks for tests with teeth, shown by
planting the mistakes a reviewer found (and a few more on the new code) and running the tests
that should catch them.  Each mutant is data in :data:`MUTANTS`: the file, the exact text it
replaces (which must occur exactly once, so a mutant that no longer applies is reported, not
silently skipped) and the targeted test files.  For each one the tool

1. checks the working tree's file is unmodified (``git diff --quiet``; it never plants on top of
   an edit),
2. writes the mutated file,
3. runs ``python -m pytest -x -q -p no:randomly -rf <tests>`` with ``OPENBLAS_NUM_THREADS=1``
   and a time limit,
4. restores the file's original bytes (in a ``finally``: also on Ctrl-C or a time-out) and
   checks ``git diff --quiet`` again,

and records CAUGHT (the first failing test, as pytest names it), SURVIVED (the tests passed),
NO-MATCH (the text to replace is not found exactly once) or TIMEOUT.  A mutant is caught only
by a failure: an error while collecting counts as caught too (it is named), a skip does not.

Usage (from the repository root)::

    .venv/bin/python tools/mutants.py                 # every mutant, then the markdown table
    .venv/bin/python tools/mutants.py --only tie_rule # one (repeatable; prefix match with --prefix)
    .venv/bin/python tools/mutants.py --baseline      # the targeted tests pass unmutated first
    .venv/bin/python tools/mutants.py --list          # the table of mutants, nothing run
    .venv/bin/python tools/mutants.py --only layer_cycle --show   # with the failing assertion
    .venv/bin/python tools/mutants.py --timeout 300 --python .venv/bin/python

Exit status 0 when every mutant run was caught, 1 otherwise.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutant:
    """One planted mistake: replace ``before`` (exactly once in ``path``) by ``after``; an empty
    ``before`` appends ``after`` to the file."""

    name: str
    path: str  # relative to the repository root
    before: str
    after: str
    tests: tuple[str, ...]  # test files (or node ids) to run
    what: str  # one line: the mistake it stands for


STAGE = ("tests/frame/test_stage_units.py",)
#: the process engine (`dvcore.parallel`): its own tests on plain items first (fast), then the frame workers
ENGINE = ("tests/dvcore/test_parallel.py", "tests/frame/test_forked_frames.py")
VIEWER = ("tests/app/test_rerun_screenshot.py",)
INTERVALS = ("tests/analysis/test_intervals.py",)

MUTANTS: tuple[Mutant, ...] = (
    # --- the previous stop's mutants (issue 20), re-planted where the code now lives ----------
    Mutant("tie_rule", "dropvision/analysis/pinchoff.py",
           "hit = frac.index[frac.to_numpy() >= 0.5]", "hit = frac.index[frac.to_numpy() > 0.5]",
           STAGE, "pinch-off delay: a tie (half detached) no longer counts"),
    Mutant("waist_both_halves", "dropvision/frame/volume.py",
           "half = edges.chord_px[at] / (2.0 * math.sqrt(2.0))", "half = edges.chord_px[at] / 2.0",
           STAGE, "split_at_row: the waist row's whole slice counted in both halves"),
    Mutant("attached_x1005", "dropvision/frame/bodies.py",
           "return AttachedLiquid(volume_nl=bv.volume_px3 * geo.nl_per_px3,",
           "return AttachedLiquid(volume_nl=1.005 * bv.volume_px3 * geo.nl_per_px3,",
           STAGE, "attached volume x1.005"),
    Mutant("blur_sign", "dropvision/frame/volume.py",
           "vol += c_vol * cos_t", "vol -= c_vol * cos_t",
           STAGE, "blur correction subtracted instead of added"),
    Mutant("tilt_cos_dropped", "dropvision/frame/volume.py",
           "return np.pi * 0.25 * c * c * np.cos(tilt_rad)", "return np.pi * 0.25 * c * c",
           STAGE, "slice area without cos(tilt)"),
    Mutant("off_path_disabled", "dropvision/frame/bodies.py",
           "if off > 0.5 * max(main.diameter_um, 20.0):", "if False:",
           STAGE, "off-path rule never fires"),
    Mutant("threshold_plus_001", "dropvision/frame/edges.py",
           "return 0.5 * (1.0 + interior_level)", "return 0.5 * (1.0 + interior_level) + 0.01",
           STAGE + ("tests/frame/test_edges.py",), "edge threshold +0.01 (the one rule of the edge level)"),
    Mutant("mask_threshold_plus_001", "dropvision/frame/segmentation.py",
           "np.multiply(t, threshold, out=t)",
           "np.multiply(t, threshold + 0.01, out=t)",
           STAGE + ("tests/frame/test_measure_frame.py", "tests/frame/test_segmentation.py"),
           "dark mask's grey-level threshold +0.01 (survived STAGE + test_measure_frame.py: "
           "tests/frame/test_segmentation.py added)"),
    Mutant("isolated_tie", "dropvision/analysis/pinchoff.py",
           "maj = frac.to_numpy() >= 0.5", "maj = frac.to_numpy() > 0.5",
           STAGE, "isolated_detached: a tie is not a detached majority"),
    Mutant("random_u_factor", "dropvision/frame/volume.py",
           "math.sqrt(0.5 * volume.chord2_px2)", "math.sqrt(volume.chord2_px2)",
           STAGE, "random edge-noise volume uncertainty sqrt(2) too large"),
    Mutant("tip_plane_fraction", "dropvision/frame/volume.py",
           "frac = i0 + 0.5 - top_px  # in (0, 1]", "frac = i0 + 1.0 - top_px",
           STAGE, "row fraction below the tip plane off by half a row"),
    Mutant("end_tails_sign", "dropvision/analysis/pinchoff.py",
           "dark = ndtr((e_top - rows) / sigma_top_px)", "dark = ndtr((rows - e_top) / sigma_top_px)",
           STAGE, "upper end's tail in the wrong direction"),
    Mutant("frame_scatter_sqrt15", "dropvision/analysis/sequence_summary.py",
           "z.append(np.sum(w * m, axis=1) / np.sqrt(np.sum(w * w * s * s, axis=1)))",
           "z.append(np.sum(w * m, axis=1) / s[:, 1])",
           STAGE, "frame scatter: third differences not over their own expected spread (was: second "
           "differences without their sqrt(3/2))"),
    Mutant("grown_r0_n0", "dropvision/analysis/sequence_summary.py",
           "+ rand ** 2 + r0 ** 2 / n0 + se ** 2 + wider ** 2)", "+ rand ** 2 + r0 ** 2 + se ** 2 + wider ** 2)",
           STAGE, "grown-volume uncertainty: meniscus random part not divided by n0"),
    Mutant("esf_slope_cosine", "dropvision/calibrate/blur.py",
           "us.append(sign * (x[keep] - xe) / np.hypot(1.0, s))", "us.append(sign * (x[keep] - xe))",
           STAGE, "edge spread measured along the row, not the outline's normal"),
    Mutant("plane_cut_sqrt12", "dropvision/frame/volume.py",
           "span * abs(math.tan(tilt_rad)) / math.sqrt(12.0)", "span * abs(math.tan(tilt_rad)) / math.sqrt(3.0)",
           STAGE, "plane-cut tilt term sqrt(3) instead of sqrt(12)"),
    Mutant("waist_lobe_off_by_one", "dropvision/frame/volume.py",
           "j0 < min_lobe_rows or n - 1 - j1 < min_lobe_rows", "j0 <= min_lobe_rows or n - 1 - j1 < min_lobe_rows",
           STAGE, "waist: the upper lobe needs one row more than min_lobe_rows"),
    Mutant("half_width_axis_test", "dropvision/calibrate/calibration_pass.py",
           "holds_axis = bool(np.any(np.abs(cols - cal.axis_col) < 2.0)) or bool((lab[:r, axis] == k).any())",
           "holds_axis = True",
           STAGE, "attached half-width counts bodies that do not hold the axis"),
    Mutant("common_u_cos", "dropvision/frame/volume.py",
           "edge = math.pi * volume.area_px2 * edge_sigma_px * math.cos(tilt_rad)",
           "edge = math.pi * volume.area_px2 * edge_sigma_px",
           STAGE, "common-edge volume uncertainty without cos(tilt)"),
    Mutant("viewer_error_is_skip", "tools/rerun_screenshot.py",
           "if isinstance(exc, TimeoutError) or _TIMED_OUT.search(str(exc)):", "if True:",
           VIEWER, "viewer probe: any exception (broken wrapper, API change) reads as a skip"),
    Mutant("viewer_png_unchecked", "tools/rerun_screenshot.py",
           "if not isinstance(png, bytes) or not png.startswith(b\"\\x89PNG\"):", "if not isinstance(png, bytes):",
           VIEWER, "viewer probe: a screenshot that is no PNG passes"),
    Mutant("viewer_exit_status", "tools/rerun_screenshot.py",
           "    if rc != 0:\n        raise ViewerBroken", "    if rc is None:\n        raise ViewerBroken",
           VIEWER, "viewer probe: a non-zero exit status passes"),
    # --- listed in the issue ------------------------------------------------------------------
    Mutant("confidence_x06", "identify/hybrid.py",
           "s_conf = float(np.sqrt(s_mc**2 + s_model**2 + s_meas**2))",
           "s_conf = 0.6 * float(np.sqrt(s_mc**2 + s_model**2 + s_meas**2))",
           INTERVALS + ("tests/identify/test_identify_hybrid.py",), "confidence intervals 0.6x as wide"),
    Mutant("one_output_x15", "identify/hybrid.py",
           "s_conf = float(np.sqrt(s_mc**2 + s_model**2 + s_meas**2))",
           "s_conf = (1.5 if k == 'jetting_velocity_m_s' else 1.0) * float(np.sqrt(s_mc**2 + s_model**2 + s_meas**2))",
           INTERVALS + ("tests/identify/test_identify_hybrid.py",), "one output's (velocity) interval 1.5x too wide"),
    # --- new ones on the merged code ----------------------------------------------------------
    Mutant("crossing_direction", "dropvision/frame/edges.py",
           "f = np.clip((threshold - t_dark) / (t_bright - t_dark), 0.0, 1.0)",
           "f = np.clip((t_bright - threshold) / (t_bright - t_dark), 0.0, 1.0)",
           ("tests/frame/test_edges.py",) + STAGE, "crossing_fraction measured from the wrong sample"),
    Mutant("edge_threshold_level", "dropvision/frame/edges.py",
           "return 0.5 * (1.0 + interior_level)", "return 0.5 * (1.0 + 0.5 * interior_level)",
           ("tests/frame/test_edges.py",) + STAGE, "edge level not half-way to the interior"),
    Mutant("frames_dtype_unchecked", "dropvision/analysis/sequence_summary.py",
           "    schema.check_table(frames, schema.FRAMES, source)", "    pass",
           ("tests/analysis/test_frames_table.py", "tests/calibrate/test_unmeasurable_blur.py"),
           "frames table written without its dtype and value check"),
    Mutant("row_nearest_column", "dropvision/analysis/nozzle_row.py",
           "    tracks = _link(lines, _tracks(lines))", "    tracks = _tracks(lines)",
           ("tests/analysis/test_nozzle_row.py",), "a printhead row's drops joined into nozzles by column, not by trajectory"),
    Mutant("layer_upward_import", "dvcore/schema.py",
           "", "\n\ndef _planted_upward():\n    import dropvision.frame.volume  # noqa: F401\n",
           ("tests/project/test_layers.py",), "an upward import (foundation -> image pipeline) in the real tree"),
    Mutant("layer_cycle", "dropvision/frame/edges.py",
           "", "\n\ndef _planted_cycle():\n    from dropvision.frame.volume import integrate  # noqa: F401\n",
           ("tests/project/test_layers.py",), "an import cycle (edges -> volume -> edges) in the real tree, inside a function"),
    Mutant("json_depth_limit", "dvcore/jsonio.py",
           "if depth > MAX_JSON_DEPTH:", "if depth > 100 * MAX_JSON_DEPTH:",
           ("tests/io/test_hostile_inputs.py",), "hardened JSON accepts any nesting depth"),
    Mutant("polynomial_bias_sign", "identify/discrepancy.py",
           "b = np.asarray(flexible.predict(u1_um_per_ms, u2_um) - chosen.predict(u1_um_per_ms, u2_um), float)",
           "b = np.asarray(chosen.predict(u1_um_per_ms, u2_um) - flexible.predict(u1_um_per_ms, u2_um), float)",
           ("tests/identify/test_discrepancy.py",) + INTERVALS, "polynomial bias with the wrong sign"),
    Mutant("polynomial_bias_max", "identify/hybrid.py",
           "if bias_sq.get(k, 0.0) > s_model**2:", "if False:",
           INTERVALS, "the chosen polynomial's bias never replaces a smaller model discrepancy"),
    Mutant("atomic_foreign_overwrite", "dvcore/atomic.py",
           "    if not overwrite:\n        raise _refusal(final, foreign)\n    return \"merge\"",
           "    return \"merge\"",
           ("tests/dvcore/test_output_safety.py", "tests/dvcore/test_atomic_executors.py"),
           "an output folder holding files we did not write is replaced without --overwrite"),
    Mutant("flicker_gain_inverted", "dropvision/frame/edges.py",
           "scale = 1.0 / gain", "scale = gain",
           ("tests/frame/test_edges.py",) + STAGE + ("tests/frame/test_measure_frame.py", "tests/frame/test_subpixel_edges.py"),
           "sub-pixel edges: the strobe-flicker gain applied the wrong way (survived: tests/frame/test_subpixel_edges.py added)"),
    Mutant("right_side_never_touches", "dropvision/frame/edges.py",
           "touches = bool((starts == 0).any() or (stops == w).any())", "touches = bool((starts == 0).any())",
           ("tests/frame/test_edges.py",) + STAGE + ("tests/frame/test_measure_frame.py", "tests/frame/test_subpixel_edges.py"),
           "a run reaching the region's right side is not flagged (survived: tests/frame/test_subpixel_edges.py added)"),
    Mutant("row_min_ignored", "dropvision/frame/edges.py",
           "y0 = max(y0, row_min)", "y0 = y0",
           ("tests/frame/test_edges.py",) + STAGE + ("tests/frame/test_measure_frame.py", "tests/frame/test_subpixel_edges.py"),
           "body_edges keeps rows above row_min (survived: tests/frame/test_subpixel_edges.py added)"),
    Mutant("flat_pair_edge", "dropvision/frame/edges.py",
           "return float(f) if np.isfinite(f) else 0.5", "return float(f) if np.isfinite(f) else 0.0",
           ("tests/frame/test_edges.py",), "a flat pair on the level: edge at the dark sample, not half-way"),
    Mutant("frames_order_unchecked", "dropvision/analysis/sequence_summary.py",
           "if list(frames.columns) != FRAME_COLUMNS:", "if False:",
           ("tests/analysis/test_frames_table.py",), "frames table columns out of the declared order pass"),
    Mutant("json_int_digits", "dvcore/jsonio.py",
           "if digits > MAX_JSON_INT_DIGITS:", "if digits > 100 * MAX_JSON_INT_DIGITS:",
           ("tests/io/test_hostile_inputs.py",), "hardened JSON accepts a 10 000-digit integer"),
    Mutant("output_inside_input", "dvcore/atomic.py",
           "        if in_r in out_r.parents:\n", "        if False:\n",
           ("tests/dvcore/test_output_safety.py", "tests/dvcore/test_atomic_executors.py"),
           "an output folder inside the input folder is allowed"),
    Mutant("prediction_t_quantile", "identify/hybrid.py",
           "return float(special.ndtri(p)) if not np.isfinite(nu) or nu > 1e7 else float(special.stdtrit(nu, p))",
           "return float(special.ndtri(p))",
           INTERVALS + ("tests/identify/test_identify_hybrid.py", "tests/identify/test_interval_quantiles.py"),
           "intervals with the normal quantile instead of Student's t (survived: tests/identify/test_interval_quantiles.py added)"),
    Mutant("fork_shares_open_files", "dvcore/parallel.py",
           "    if after_fork is not None:\n        after_fork()", "    if False:\n        after_fork()",
           ENGINE, "forked workers read a multi-page file through the parent's open handle (shared offset, lock)"),
    Mutant("forked_workers_outlive_parent", "dvcore/parallel.py",
           "    die_with_parent(parent_pid)\n    signal.signal(signal.SIGINT, signal.SIG_IGN)",
           "    signal.signal(signal.SIGINT, signal.SIG_IGN)",
           ENGINE, "forked workers go on measuring after a kill -9 of the measuring process"),
    Mutant("fork_with_native_threads", "dvcore/parallel.py",
           "            and os_thread_count() == 1)", "            and True)",
           ENGINE, "workers forked from a process whose native pools (OpenCV, OpenBLAS) have run (issue 29 hang)"),
    Mutant("worker_wait_unbounded", "dvcore/process.py",
           "        elif now - since > stall_after_s:", "        elif False:",
           ENGINE, "the parent waits for ever on a forked worker that is blocked on a lock (no watchdog)"),
    Mutant("opencv_pool_started_before_fork", "dvcore/parallel.py",
           "    cv2.setNumThreads(0)\n    try:", "    try:",
           ENGINE, "the calibration before the fork starts OpenCV's pool, so the command line never forks (or forks unsafely)"),
    Mutant("dead_worker_items_lost", "dvcore/parallel.py",
           "        yield from _updating(_map_here(fn, rest, workers, threads), bar)\n", "        pass\n",
           ENGINE, "the items a dead or stalled worker had not returned are dropped instead of computed here"),
    Mutant("worker_warnings_dropped", "dvcore/parallel.py",
           "            relay(caught)\n", "            pass\n",
           ENGINE, "the warnings raised in a forked worker never reach the caller"),
    Mutant("bar_before_fork", "dvcore/parallel.py",
           "    done, bar, finished, bar_made = 0, None, False, False\n",
           "    done, bar, finished, bar_made = 0, (progress(len(items)) if progress else None), False, progress is not None\n",
           ENGINE, "the progress bar (a monitor thread) started before the workers are forked"),
    Mutant("campaign_wait_unbounded", "dropvision/app/campaign.py",
           "    if not isinstance(executor, ProcessPoolExecutor):", "    if True:",
           ("tests/dvcore/test_atomic_executors.py",),
           "a campaign waits for ever on a local worker blocked on a lock"),
    Mutant("campaign_pool_forks_threaded_parent", "dropvision/app/executors.py",
           'get_context("fork" if os_thread_count() == 1 else "forkserver")', 'get_context("fork")',
           ("tests/dvcore/test_atomic_executors.py",),
           "campaign workers forked from a process running other threads (a lock held at the fork)"),
    Mutant("flexible_scatter_ignored", "identify/hybrid_fit.py",
           "if flex is not None and flex[0] < drop_var:", "if False:",
           ("tests/analysis/test_intervals.py",),
           "drop scatter from the chosen order's residuals even where the flexible reference fits better"),
    Mutant("satterthwaite_dof_ignored", "identify/hybrid.py",
           "nu = float(dof) * (total / estimated_var) ** 2 if estimated_var > 0 else np.inf",
           "nu = float(dof)",
           ("tests/identify/test_interval_quantiles.py",),
           "the scatter's dof used even where a stated (known) measurement term dominates the variance"),
    Mutant("relative_measurement_term", "identify/hybrid.py",
           "return abs(mean) * v if relative else v", "return v",
           INTERVALS + ("tests/identify/test_identify_hybrid.py",),
           "a relative measurement uncertainty used as absolute"),
    Mutant("bias_variance_sign", "identify/discrepancy.py",
           "np.clip(leverage(flexible) - leverage(chosen), 0.0, None)",
           "np.clip(leverage(chosen) - leverage(flexible), 0.0, None)",
           ("tests/identify/test_discrepancy.py",), "polynomial_bias variance from the leverages the wrong way"),
    Mutant("cv_misfit_uncorrected", "identify/discrepancy.py",
           "(e**2 - float(scatter_variance) - v) / (1.0 + h) ** 2", "(e**2 - float(scatter_variance) - v)",
           ("tests/identify/test_discrepancy.py",), "cross-validation misfit not carried back to the full fit (no (1 + h_f)²)"),
    Mutant("manifest_stale_entry", "dropvision/app/campaign.py",
           "if known is None or known[0] != entry:", "if known is None:",
           ("tests/app/test_campaign.py",), "manifest writer keeps a sequence's first text after it changed"),
    Mutant("tabular_conformal_alpha", "identify/tabular.py",
           "    k_lo = math.floor((n + 1) * alpha / 2)\n    k_hi = math.ceil((n + 1) * (1 - alpha / 2))",
           "    k_lo = math.floor((n + 1) * alpha)\n    k_hi = math.ceil((n + 1) * (1 - alpha))",
           ("tests/identify/test_tabular.py",), "one-drop interval of a table model at 1 - 2 alpha (each tail alpha, not alpha/2)"),
    Mutant("tabular_region_low_unchecked", "identify/tabular.py",
           "for i in np.flatnonzero(X[:, j] < self.low[j]):", "for i in np.flatnonzero(X[:, j] < -np.inf):",
           ("tests/identify/test_tabular.py",), "an input below its training range is not flagged"),
    # --- the sequence-level seams of issue 34 (findings applied in one place, the main-drop track) ---
    Mutant("withheld_not_blanked", "dropvision/analysis/sequence_summary.py",
           "            summary[key] = float(\"nan\")", "            pass",
           ("tests/analysis/test_plausibility.py",), "a withheld summary value (pixel size lie, delay lie) still given"),
    Mutant("finding_flag_dropped", "dropvision/analysis/sequence_summary.py",
           "                    s.flags[k].append(f.flag)", "                    pass",
           ("tests/analysis/test_plausibility.py",), "a check's quality code never reaches its frames"),
    Mutant("tail_rule_trusts_all", "dropvision/analysis/tracking.py",
           "TAIL_IGNORED_FLAGS = q.UNTRUSTED_INTENSITY_FLAGS + (q.NEIGHBOURS,)", "TAIL_IGNORED_FLAGS = ()",
           ("tests/analysis/test_tracking.py",), "a tail in an untrusted frame holds the earlier drops out of flight"),
    Mutant("line_se_dof", "dropvision/analysis/tracking.py",
           "np.sqrt(np.sum(res**2) / (n - 2) / sxx)", "np.sqrt(np.sum(res**2) / n / sxx)",
           ("tests/analysis/test_tracking.py",), "jetting velocity standard error with n instead of n - 2 degrees of freedom"),
    # --- issue 34: the seams of decisions that no longer read a message -------------------------
    Mutant("edge_slope_without_sqrt_2pi", "dropvision/frame/edges.py",
           "return float(transmission_error * _SQRT_2PI * sig / depth)",
           "return float(transmission_error * sig / depth)",
           ("tests/analysis/test_clipped_background.py::test_backlight_under_the_clip_is_extrapolated_from_what_is_seen",),
           "the one edge slope (edges.edge_shift_px) loses its sqrt(2 pi)"),
    Mutant("same_view_flag_dropped", "dropvision/analysis/shot_rig.py",
           'f"{MAX_SHIFT_PX:g} px)", same_view=True)', 'f"{MAX_SHIFT_PX:g} px)")',
           ("tests/analysis/test_shots_shared.py::test_fingerprints_tell_a_moved_camera_and_another_light",),
           "a shifted shot is no longer known as the same view (the flag, not the words, decides)"),
    Mutant("touching_body_rule", "dropvision/frame/bodies.py",
           "    if body.touching:\n        return DetachedClass.TOUCHING", "    if False:\n        return DetachedClass.TOUCHING",
           ("tests/app/test_rerun.py::test_class_image_rejected_and_touching_bodies",),
           "the one body-class rule (bodies.detached_class) forgets a body split off the main drop"),
    # --- issue 29, the tip plane's cut and its uncertainty -------------------------------------
    Mutant("plane_row_wall_rule_off", "dropvision/frame/volume.py",
           "        liquid &= rows != math.floor(top_px + 0.5)\n", "        pass\n",
           ("tests/analysis/test_measure_accuracy.py::test_attached_volume_with_the_tip_plane_close_above_a_row_centre",),
           "the row holding the tip plane read as liquid although its chord is the walls'"),
    Mutant("plane_cut_reads_walls", "dropvision/frame/volume.py",
           "(r > 0) & (dy >= np.asarray(reach_px, float) + 0.5)", "(r > 0)",
           STAGE, "near a tilted tip plane the low side's edges read although the walls reach below the tip row"),
    Mutant("plane_end_line_dropped", "dropvision/frame/volume.py",
           "    ak[up] = np.pi * (r2_at[0] + (r2_at[0] - r2_at[1]) / (s2 - s1) * (s1 - sk[up]))",
           "    ak[up] = np.pi * r2_at[0]",
           STAGE, "above the first edges the slice held at the first row's, not on the line through two"),
    Mutant("grown_plane_position_dropped", "dropvision/analysis/sequence_summary.py",
           "+ (position - p0) ** 2 + rand ** 2", "+ rand ** 2",
           STAGE, "a grown volume drops the plane's position part where its liquid is wider at the plane"),
    Mutant("tip_crossings_ignored", "dropvision/frame/bodies.py",
           "return math.sqrt(math.pi / 2.0 / crossings) if crossings >= 4 else TIP_MEDIAN_FACTOR",
           "return TIP_MEDIAN_FACTOR",
           STAGE, "the tip plane's random part from the 4-crossing bound whatever the crossings"),
    Mutant("wall_blur_rows_near_ends", "dropvision/calibrate/blur.py",
           "    if keep.all():\n        return sigma\n", "    if True:\n        return sigma\n",
           ("tests/frame/test_measure_frame.py",),
           "the walls' blur fitted on every wall row, a holder's face and the tip within a few sigmas"),
    Mutant("asymmetry_runs_ignored", "dropvision/frame/volume.py",
           "    keep = idx[np.bincount(run)[run] >= ASYMMETRY_MIN_ROWS]\n", "    keep = idx[:0]\n",
           ("tests/frame/test_measure_frame.py",),
           "a drop's sides departing from mirror images (a shadow over one edge) add nothing to its uncertainty"),
    Mutant("background_noise_as_misfit", "dropvision/calibrate/background.py",
           "    return float(math.sqrt(max(spread * spread - noise * noise, 0.0)))\n", "    return spread\n",
           ("tests/calibrate/test_calibration_fast.py",),
           "the background's misfit read with the blocks' own noise in it (every body's edges moved by noise)"),
    Mutant("noise_of_neighbours", "dvcore/robust.py", "NOISE_LAG_PX = 2\n", "NOISE_LAG_PX = 1\n",
           ("tests/calibrate/test_calibration_fast.py", "tests/analysis/test_measure_accuracy.py"),
           "the frames' noise read on neighbours (a colour camera's or a JPEG coder's 2x2 cells hide part of it)"),
    Mutant("noise_mad_of_counts", "dvcore/robust.py", "        spread = quantized_sigma(a.astype(np.int64) - b.astype(np.int64))\n",
           "        spread = robust_sigma(a.astype(np.int64) - b.astype(np.int64))\n",
           ("tests/dvcore/test_robust.py", "tests/calibrate/test_calibration_fast.py"),
           "raw counts' noise read by a median absolute deviation of integers (sticks at 1.05 counts)"),
    Mutant("halo_band_unnamed", "dropvision/frame/bodies.py",
           "                          halo_band_nl=_definition_px3(bv, ctx) * geo.nl_per_px3 if in_halo else 0.0)",
           "                          halo_band_nl=0.0)",
           STAGE, "a rest meniscus's band read against the nozzle's halo not named (every grown volume keeps it)"),
    Mutant("halo_band_kept_in_grown", "dropvision/analysis/sequence_summary.py",
           "    common_u_nl = np.sqrt(np.maximum(np.asarray(common_u_nl, float) ** 2 - band ** 2, 0.0))\n", "",
           STAGE, "the rest meniscus's halo band kept in the grown volumes' common part"),
    Mutant("drop_scatter_over_repeats", "dropvision/analysis/sequence_summary.py",
           "    step = np.diff(d) != 0\n", "    step = np.ones(d.size - 1, bool)\n",
           STAGE, "the drops' scatter read between repeats at one delay (the same place: no sampling error)"),
    Mutant("drop_scatter_ignored", "dropvision/analysis/sequence_summary.py",
           "    drop_u = widened_drop_uncertainty(drop_u,", "    drop_u = (lambda u, *_: u)(drop_u,",
           ("tests/analysis/test_measure_accuracy.py::test_in_flight_scatter_widens_the_drops_uncertainty",),
           "the in-flight drops' own scatter ignored: their random part the edges' noise alone"),
)


def _git_clean(path: str) -> bool:
    return subprocess.run(["git", "diff", "--quiet", "--", path], cwd=ROOT).returncode == 0


def _first_failure(output: str) -> str:
    """The first failing test pytest names (``-rf`` summary), or its collection error."""
    m = re.search(r"^(?:FAILED|ERROR) (\S+)", output, re.M)
    if m:
        return m.group(1)
    return "(pytest failed: " + (output.strip().splitlines() or ["no output"])[-1][:120] + ")"


def run_mutant(m: Mutant, python: str, timeout_s: float, show: bool = False) -> tuple[str, str, float]:
    """Plant ``m``, run its tests, restore the file. Returns (outcome, detail, seconds); ``show``
    prints the end of pytest's output (the failure's assertion)."""
    target = ROOT / m.path
    if not _git_clean(m.path):
        raise SystemExit(f"{m.path}: has uncommitted changes; commit or stash them before planting mutants")
    original = target.read_bytes()
    text = original.decode("utf-8")
    n = text.count(m.before) if m.before else 1
    if n != 1:
        return "NO-MATCH", f"the text to replace occurs {n} times in {m.path}", 0.0
    t0 = time.monotonic()
    try:
        mutated = text.replace(m.before, m.after, 1) if m.before else text + m.after
        target.write_bytes(mutated.encode("utf-8"))
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONDONTWRITEBYTECODE="1")
        try:
            proc = subprocess.run([python, "-m", "pytest", "-x", "-q", "-p", "no:randomly", "-p", "no:cacheprovider",
                                   "-rf", *m.tests], cwd=ROOT, env=env, capture_output=True, text=True,
                                  timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return "TIMEOUT", f"no result within {timeout_s:g} s", time.monotonic() - t0
    finally:
        target.write_bytes(original)
    if not _git_clean(m.path):
        raise SystemExit(f"{m.path}: not restored after mutant {m.name}; run git checkout -- {m.path}")
    dt = time.monotonic() - t0
    if show:
        print("\n".join((proc.stdout + proc.stderr).strip().splitlines()[-25:]), flush=True)
    if proc.returncode == 0:
        return "SURVIVED", "all targeted tests passed", dt
    if proc.returncode == 5:
        return "SURVIVED", "no tests collected", dt
    return "CAUGHT", _first_failure(proc.stdout + proc.stderr), dt


def _line(m: Mutant) -> int:
    """Line of ``before`` in the file (for an append, the line after the last)."""
    text = (ROOT / m.path).read_text("utf-8")
    i = text.find(m.before) if m.before else len(text)
    return text.count("\n", 0, i) + 1 if i >= 0 else 0


def _cell(s: str) -> str:
    if not s:
        return "(end of file)"
    return "`" + s.strip().replace("\n", " ⏎ ").replace("|", "\\|") + "`"


def table(rows: list[tuple[Mutant, str, str, float]] | None = None) -> str:
    """The markdown table of the mutants (with outcomes when ``rows`` is given)."""
    head = "| mutant | what | file:line | before -> after | tests run |"
    if rows is not None:
        head += " outcome | caught by | s |"
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    items = rows if rows is not None else [(m, "", "", 0.0) for m in MUTANTS]
    for m, outcome, detail, dt in items:
        cells = [m.name, m.what, f"{m.path}:{_line(m)}", f"{_cell(m.before)} -> {_cell(m.after)}",
                 " ".join(m.tests)]
        if rows is not None:
            cells += [outcome, detail, f"{dt:.0f}"]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", action="append", default=[], metavar="NAME", help="run this mutant (repeatable)")
    p.add_argument("--prefix", action="store_true", help="--only names are prefixes")
    p.add_argument("--list", action="store_true", help="print the table of mutants and run nothing")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds per mutant (default 600)")
    p.add_argument("--baseline", action="store_true",
                   help="first run the chosen mutants' test files unmutated; stop unless they pass")
    p.add_argument("--show", action="store_true", help="print the end of each pytest run's output")
    p.add_argument("--python", default=sys.executable, help="interpreter that runs pytest")
    a = p.parse_args(argv)
    names = {m.name for m in MUTANTS}
    if len(names) != len(MUTANTS):
        raise SystemExit("tools/mutants.py: two mutants share a name")
    chosen = list(MUTANTS)
    if a.only:
        unknown = [o for o in a.only if not any((m.startswith(o) if a.prefix else m == o) for m in names)]
        if unknown:
            raise SystemExit(f"unknown mutant(s): {', '.join(unknown)}; known: {', '.join(sorted(names))}")
        chosen = [m for m in MUTANTS if any((m.name.startswith(o) if a.prefix else m.name == o) for o in a.only)]
    if a.list:
        print(table())
        return 0
    if a.baseline:
        files = list(dict.fromkeys(t for m in chosen for t in m.tests))
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        t0 = time.monotonic()
        proc = subprocess.run([a.python, "-m", "pytest", "-q", "-p", "no:randomly", "-p", "no:cacheprovider", *files],
                              cwd=ROOT, env=env, capture_output=True, text=True)
        last = (proc.stdout.strip().splitlines() or ["no output"])[-1]
        print(f"baseline (no mutant) of {len(files)} test files: {last} ({time.monotonic() - t0:.0f} s)", flush=True)
        if proc.returncode != 0:
            print(proc.stdout[-3000:] + proc.stderr[-2000:])
            return 1
    rows = []
    for m in chosen:
        outcome, detail, dt = run_mutant(m, a.python, a.timeout, a.show)
        print(f"{m.name:28s} {outcome:9s} {detail} ({dt:.0f} s)", flush=True)
        rows.append((m, outcome, detail, dt))
    print()
    print(table(rows))
    return 0 if all(r[1] == "CAUGHT" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
