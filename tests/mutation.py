"""Mutation testing (`make mutation`, outside CI): mutmut over one module at a time, each mutant run
against the tests that reach the mutated function (mutmut's own map), fastest first, in a copy of the
tree under out/mutation/ (the work tree is never touched). Prints the score per module and lists the survivors.

    python tests/mutation.py testing codecs        # modules by name (see TARGETS); none: all of them
    python tests/mutation.py --dry codecs          # its tests against the plain kernels, unmutated
    python tests/mutation.py --inproc framing      # one worker, CPU-time limits: verdicts the load cannot change
    python tests/mutation.py --inproc --sample 200 codecs --only '*.evt3.*'   # a random 200 of those

Numba: mutmut 3 skips every decorated function (its trampoline, applied under the function's own
decorators, would be what numba compiles). So the copy of each mutated file has its kernels' `@njit`
lines removed (`plain_kernels`): there they run as plain Python and mutmut mutates them like any
function; everything not being mutated stays compiled. A function's `functools.cache` goes too: a
kernel factory's nested kernel is then mutated with it, and no cache warmed by mutmut's clean run (in
the process each mutant is forked from) answers for mutated code (`event_packet._layout`'s did for
`_string`: its mutants "survived" every test). Kernels calling a numba `@intrinsic` (no plain-Python
form) stay compiled unless it has a plain twin (`PLAIN_TWINS`), and so do those a compiled kernel calls
(`kept_compiled`: compiled code cannot call a plain function). The work tree is never changed: normal
runs are the same code.
Numba's cache goes to a fresh folder per run, so no compiled code outlives a run.
"""

from __future__ import annotations

import ast
import fnmatch
import json
import os
import random
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "mutation"

# module -> (files to mutate, as paths in the copy, where sources/ lives at evstream/sources/; tests)
CODECS = "evstream/codecs/"
DENOISE = "evstream/denoise/"
FRAMING = "evstream/framing/"
TARGETS = {
    "testing": (["evstream/testing.py"], ["tests/test_invariant_kit.py"]),
    "sources_base": (["evstream/sources/_base.py"],
                     ["tests/test_sources_base.py", "tests/test_sources_formats.py",
                      "tests/test_sources_bad_input.py", "tests/test_sources_kernels.py", "tests/test_seek.py"]),
    # represent.py is a target of its own (framing_represent)
    "framing": ([FRAMING + f for f in ("arrays.py", "base.py", "fixed.py", "options.py", "overlap.py",
                                       "render.py", "stats.py")],
                ["tests/test_framing.py", "tests/test_invariant_kit.py", "tests/test_framing_render_cli.py",
                 "tests/test_represent_outputs.py", "tests/test_framing_options.py",
                 "tests/test_framing_render.py", "tests/test_represent.py"]),
    # framing's two window framers alone (a copy of their own, so `framing`'s verdicts stay)
    "framing_windows": ([FRAMING + "fixed.py", FRAMING + "overlap.py"],
                        ["tests/test_framing.py", "tests/test_invariant_kit.py", "tests/test_represent_outputs.py",
                         "tests/test_represent.py", "tests/test_framing_options.py",
                         "tests/test_framing_render_cli.py"]),
    # the representations (voxel grid, time surface, histogram, count, timestamp) over any window
    "framing_represent": ([FRAMING + "represent.py"],
                          ["tests/test_represent.py", "tests/test_represent_outputs.py",
                           "tests/test_represent_cli.py", "tests/test_framing.py"]),  # its bad parameters
    # the chunks cut so that a framer hands on its frames in batches of bounded memory (a copy of its own, so
    # `framing`'s verdicts and samples stay); its tests cut chunks for each kind of framer, through a Pipeline too,
    # and run `frames` as a user types it
    "framing_bound": ([FRAMING + "bound.py"], ["tests/test_frames_user.py", "tests/test_pipeline_bound.py"]),
    "codecs": ([CODECS + f for f in ("attachment.py", "event_packet.py", "evt2.py", "evt3.py")],
               ["tests/test_codecs_evt2.py", "tests/test_codecs_evt3.py", "tests/test_event_packet.py",
                "tests/test_zenoh_attachment.py", "tests/test_seek.py", "tests/test_mcap_archive.py",
                "tests/test_sources_kernels.py"]),
    # the packet payloads: checked by the packet codec's tests (mono and EVT3 packets against references)
    # and the MCAP archive's
    "codecs_payloads": ([CODECS + "mono.py", CODECS + "packets.py"],
                        ["tests/test_event_packet.py", "tests/test_mcap_archive.py", "tests/test_zenoh_attachment.py",
                         "tests/test_codecs_evt3.py"]),
    # the paper's cascade (the default denoiser) and the baselines; learned/ has its own tests
    # (every kernel plain: the intrinsics they call replaced by their plain twins, PLAIN_TWINS; `prefetch` stays
    # compiled, the learned features' compiled kernel calling it, and it is one call of an intrinsic)
    "denoise_cascade": ([DENOISE + f for f in ("base.py", "cascade.py", "common.py", "density.py",
                                               "prefetch.py", "rowsum.py", "timeseries.py")],
                        ["tests/test_paper_cascade.py", "tests/test_rowsum.py"]),
    # the cascade's three stages alone (a copy of their own: session 10's verdicts)
    "denoise_cascade_stages": ([DENOISE + f for f in ("cascade.py", "density.py", "timeseries.py")],
                               ["tests/test_paper_cascade.py"]),
    "denoise_baselines": ([DENOISE + f for f in ("baf.py", "dwf.py", "hotpixel.py", "khodamoradi.py",
                                                 "oracle.py", "refractory.py", "stcf.py", "ynoise.py")],
                          ["tests/test_baselines.py", "tests/test_metrics.py", "tests/test_pipeline.py",
                           "tests/test_paper_cascade.py", "tests/test_baf_stage.py"]),
    # the learned denoiser (the shipped model's stage): its features' kernel as plain Python, the vector
    # neighbour pass (an intrinsic) by its plain twin `reference_nb8`; less the one test that trains in a child
    # process (`evstream train` piped: the plain kernel there takes minutes, out of reach of the CPU limit)
    "denoise_learned": ([DENOISE + "learned/" + f for f in ("features.py", "model.py", "neighbours.py", "stage.py",
                                                            "train.py")],
                        ["tests/test_learned.py", "--deselect",
                         "tests/test_learned.py::test_train_says_where_it_is_when_its_output_is_piped"]),
    # the two per-pixel baselines alone (the others stay compiled: their tests share test_baselines.py)
    "denoise_per_pixel": ([DENOISE + "hotpixel.py", DENOISE + "refractory.py"],
                          ["tests/test_baselines.py", "tests/test_paper_cascade.py"]),
}
# Test files that import a target's functions but are left out of its selection (`selection_gaps`), and why
LEFT_OUT = {
    "tests/test_zenoh_live.py": "live Zenoh: a router and publishers in other processes, waits bounded in wall "
                                "time; what it imports (codecs, FixedWindow) is checked by those modules' own tests",
    "tests/test_cli_user_errors.py": "its codec imports build one packet for a live Zenoh session (above)",
}
# Targets whose module every test file uses as a tool: their selection is their own tests alone
TOOLS = {"testing": "the invariant kit: most test files draw streams with it; its checks are checked in "
                    "test_invariant_kit.py"}
ALIASES = {"denoise": ["denoise_cascade", "denoise_baselines"]}  # and `codecs_payloads` for codecs
IGNORE = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.pyc")
# Functions whose code runs only at import or while numba compiles, never while a mutant is switched on (the
# worker imports once and compiles in its clean run): their mutants are neither run nor scored, with the reason
NOT_RUN = {
    "evstream.denoise.rowsum.x__vector_add": "the factory of the vector add intrinsics (`_add_4` .. `_add_32`): run at "
                                             "import; its `add` types and `codegen` lowers when numba compiles",
    "evstream.denoise.rowsum.x__vector_full": "the factory of the vector test intrinsics (`_full_4` .. `_full_32`), "
                                              "as `_vector_add`",
}

# Mutants no input can tell from the code (docs/testing.md says why for each): counted apart, not as
# survivors. mutmut names a mutant by function and number, so a name here holds while that function's
# source is unchanged.
_B = "evstream.sources._base."
_EQUIVALENT_BY_REASON: dict[str, list[str]] = {
    # evstream/testing.py
    "np.random.default_rng returns a Generator it is given unaltered": ["evstream.testing.x__rng__mutmut_1"],
    "random_stream: a constant of the stress stream changed, and the stream still has every stress the "
    "kit relies on and test_random_stream_has_the_stress_it_promises pins (bursts, 60/30/10 % labels, a "
    "blob crossing the sensor, hot pixels, all four borders, int64 t)": [
        f"evstream.testing.x_random_stream__mutmut_{n}" for n in (
            1, 2, 23, 28, 31, 53, 61, 65, 69, 71, 72, 76, 78, 79, 80, 82, 83, 94, 101, 103, 105, 114, 121, 122,
            123, 125, 133, 135, 138, 140, 151, 153, 156, 158, 163, 167, 170, 175, 179, 181, 182, 184)],
    "random_bounds with n = 0: every cut is 0 whatever the array's length, dtype or draw, and the set "
    "keeps one": [f"evstream.testing.x_random_bounds__mutmut_{n}" for n in (15, 29, 31, 32, 33)],
    "rng.integers(n - 1) is rng.integers(0, n - 1)": ["evstream.testing.x_random_bounds__mutmut_41"],
    "random_bounds: cuts drawn from 1..n or 0..n-2 instead of 0..n: still valid bounds with every kind of "
    "split (test_random_bounds_draw_every_kind_of_split passes); `<= 0.3` for `< 0.3` on a float draw": [
        f"evstream.testing.x_random_bounds__mutmut_{n}" for n in (23, 24, 58)],
    "one more, empty, chunk after the one-event chunks: a stage's output for it is empty":
        ["evstream.testing.x_one_event_chunks__mutmut_8"],
    "concat takes the geometry from the chunks when given none": [
        f"evstream.testing.x_classify_all__mutmut_{n}" for n in (6, 8)],
    "another default seed, number of splits or cuts, or chunk length: the checks hold for any": [
        "evstream.testing.x_assert_causal__mutmut_1", "evstream.testing.x_assert_chunk_invariant__mutmut_1",
        "evstream.testing.x_assert_chunk_invariant__mutmut_2", "evstream.testing.x_assert_framer_causal__mutmut_1",
        "evstream.testing.x_assert_framer_causal__mutmut_2", "evstream.testing.x_assert_cameras_independent__mutmut_1",
        "evstream.testing.x_assert_bounded_state__mutmut_3"],
    "the memory bound's threshold moved by one byte (`>=` for `>`, 4097 for 4096)": [
        "evstream.testing.x_assert_bounded_state__mutmut_36", "evstream.testing.x_assert_bounded_state__mutmut_39"],
    "t_end=None: a slice's watermark is then its last event's time, the value given": [
        "evstream.testing.x_assert_framer_causal__mutmut_20"],
    "the wording of the second future's failure message": [
        "evstream.testing.x_assert_framer_causal__mutmut_26", "evstream.testing.x_assert_framer_causal__mutmut_27"],
    "an empty camera's result built the same (other) way on both sides of the comparison": [
        f"evstream.testing.x_assert_cameras_independent__mutmut_{n}" for n in (22, 24, 25)],
    # evstream/denoise (baselines)
    "STCF's padded map: shifting or mirroring every pixel's cell the same way (x - r, r - x, y - r; an "
    "index below 0 wraps into never-written padding) and visiting the symmetric offsets as -o keep every "
    "pixel's neighbourhood the same": [
        f"evstream.denoise.stcf.x_stcf_scored_kernel__mutmut_{n}" for n in (4, 5, 7, 13)],
    "STCF top-k: inserting a timestamp equal to the k-th newest, or shifting past equal ones, leaves the "
    "same k newest values": [f"evstream.denoise.stcf.x_stcf_scored_kernel__mutmut_{n}" for n in (16, 30)],
    "STCF's unscored kernel: the same padded-map shifts and mirrors as the scored one's (x - r, r - x, "
    "y - r, centre - o); counting on past k supporters (n > k to stop) before deciding n >= k": [
        f"evstream.denoise.stcf.x_stcf_kernel__mutmut_{n}" for n in (4, 5, 7, 15, 24)],
    "Khodamoradi: visiting the column and row cells x+1-d / y+1-d for d in -1..1 visits the same three "
    "cells each, and d = 0 is still the event's own column / row": [
        f"evstream.denoise.khodamoradi.x_khodamoradi_kernel__mutmut_{n}" for n in (18, 45)],
    "Khodamoradi's cells: NEVER_US without a dtype is int64; rows and polarities as float64 (np.zeros' "
    "default: every value exact, compared equal to the event's) or one cell longer: the same decisions": [
        f"evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁ_allocate__mutmut_{n}"
        for n in (4, 7, 9, 11, 13, 15, 17, 19, 21, 25, 28, 30, 32, 34, 36, 38, 40, 42)],
    "STCF's and BAF's maps: a wider padding (3r for 2r, or one more row / column: never read past r), "
    "NEVER_US or the polarities without a dtype (int64; float64 compared equal to the event's), offsets "
    "mirrored in x (dy·W - dx over a symmetric box is the same set)": [
        *(f"evstream.denoise.stcf.xǁSpatioTemporalCorrelationFilterǁ_allocate__mutmut_{n}"
          for n in (5, 9, 12, 16, 19, 21, 37)),
        *(f"evstream.denoise.baf.xǁBackgroundActivityFilterǁ_allocate__mutmut_{n}" for n in (4, 7, 9, 11))],
    "STCF's top-k scratch as float64: NEVER_US (-2^62) and every time below 2^53 us are exact, so the same "
    "comparisons and the same score": [
        f"evstream.denoise.stcf.xǁSpatioTemporalCorrelationFilterǁ__post_init____mutmut_{n}" for n in (72, 74)],
    "DWF: the rings as float64 (every position exact) or with a third, unused row (and fill/head of 3)": [
        *(f"evstream.denoise.dwf.xǁDoubleWindowFilterǁ__post_init____mutmut_{n}"
          for n in (51, 53, 54, 57, 59, 60, 66, 72))],
    "YNoise's maps: padded by 3r instead of 2r at the far side (never read: a neighbourhood reaches r), "
    "NEVER_US (the last times, the ring) without a dtype is int64, the last polarity as float64 "
    "(compared equal to the event's)": [
        f"evstream.denoise.ynoise.xǁYNoiseFilterǁ_allocate__mutmut_{n}" for n in (5, 8, 12, 15, 18, 20, 24, 27)],
    "want_score None for False, or the score computed and dropped: the same classes": [
        "evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁ_run__mutmut_9",
        "evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁclassify__mutmut_2",
        "evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁclassify__mutmut_5",
        "evstream.denoise.ynoise.xǁYNoiseFilterǁ_run__mutmut_9",
        "evstream.denoise.dwf.xǁDoubleWindowFilterǁ_run__mutmut_9",
        "evstream.denoise.dwf.xǁDoubleWindowFilterǁclassify__mutmut_2",
        "evstream.denoise.dwf.xǁDoubleWindowFilterǁclassify__mutmut_5",
        "evstream.denoise.ynoise.xǁYNoiseFilterǁclassify__mutmut_2",
        "evstream.denoise.ynoise.xǁYNoiseFilterǁclassify__mutmut_5",
        "evstream.denoise.hotpixel.xǁHotPixelLearnerǁclassify__mutmut_2",
        "evstream.denoise.hotpixel.xǁHotPixelLearnerǁclassify__mutmut_5",
        "evstream.denoise.hotpixel.xǁHotPixelLearnerǁ_run__mutmut_9",
        "evstream.denoise.refractory.xǁRefractoryFilterǁclassify__mutmut_2",
        "evstream.denoise.refractory.xǁRefractoryFilterǁclassify__mutmut_5",
        "evstream.denoise.refractory.xǁRefractoryFilterǁ_run__mutmut_9"],
    "np.empty(n, None) and np.empty(n) are float64, the dtype given": [
        "evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁ_run__mutmut_11",
        "evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁ_run__mutmut_13",
        "evstream.denoise.ynoise.xǁYNoiseFilterǁ_run__mutmut_11",
        "evstream.denoise.dwf.xǁDoubleWindowFilterǁ_run__mutmut_11",
        "evstream.denoise.dwf.xǁDoubleWindowFilterǁ_run__mutmut_13",
        "evstream.denoise.ynoise.xǁYNoiseFilterǁ_run__mutmut_13",
        "evstream.denoise.hotpixel.xǁHotPixelLearnerǁ_run__mutmut_11",
        "evstream.denoise.hotpixel.xǁHotPixelLearnerǁ_run__mutmut_13",
        "evstream.denoise.refractory.xǁRefractoryFilterǁ_run__mutmut_11",
        "evstream.denoise.refractory.xǁRefractoryFilterǁ_run__mutmut_13",
        "evstream.denoise.stcf.xǁSpatioTemporalCorrelationFilterǁclassify_scored__mutmut_9",
        "evstream.denoise.stcf.xǁSpatioTemporalCorrelationFilterǁclassify_scored__mutmut_11",
        "evstream.denoise.baf.xǁBackgroundActivityFilterǁclassify_scored__mutmut_9",
        "evstream.denoise.baf.xǁBackgroundActivityFilterǁclassify_scored__mutmut_11"],
    "the state set in __post_init__ is replaced by _allocate before its first use": [
        "evstream.denoise.hotpixel.xǁHotPixelLearnerǁ__post_init____mutmut_42",
        "evstream.denoise.refractory.xǁRefractoryFilterǁ__post_init____mutmut_15",
        "evstream.denoise.khodamoradi.xǁKhodamoradiFilterǁ__post_init____mutmut_43",
        "evstream.denoise.ynoise.xǁYNoiseFilterǁ__post_init____mutmut_90",
        "evstream.denoise.stcf.xǁSpatioTemporalCorrelationFilterǁ__post_init____mutmut_69",
        "evstream.denoise.baf.xǁBackgroundActivityFilterǁ__post_init____mutmut_16"],
    "to_events: astype(None) is float64, the dtype given; copy=True/None for copy=False changes no value; "
    "np.issubdtype(None, np.floating) holds, and an integer column always equals its floor": [
        f"evstream.sources._base.x_to_events__mutmut_{n}" for n in (20, 38, 40, 41, 58)],
    "to_events: a bool polarity through (p > 0) gives the same 0/1": ["evstream.sources._base.x_to_events__mutmut_90"],
    # sources/_base.py (session 8)
    "unwrap: a first value with last = 0 (or the start value +1 / -2 for -1) can never be a wrap: a drop "
    "from 0 or 1 is never more than half the clock": [
        _B + "x_unwrap_kernel__mutmut_21",
        _B + "x_unwrap_kernel__mutmut_22",
        _B + "xǁUnwrapperǁ__init____mutmut_8",
        _B + "xǁUnwrapperǁ__init____mutmut_9"],
    "np.array of Python ints without a dtype is int64, the dtype given": [
        _B + "xǁUnwrapperǁ__init____mutmut_4",
        _B + "xǁUnwrapperǁ__init____mutmut_6"],
    "max(2, block_bytes // 16): block_bytes is at least 1024, so the step is at least 64 either way":
        [_B + "xǁFileSourceǁ_column_blocks__mutmut_6"],
    "a watermark equal to the chunk's last time is the default watermark": [_B + "xǁFileSourceǁ_emit__mutmut_37"],
    "t_at past the queue: the IndexError's argument (never shown; only its type is relied on)":
        [_B + "xǁ_Queueǁt_at__mutmut_5"],
    "_next_bin with t_next == bin_start returns bin_start on either branch": [_B + "x__next_bin__mutmut_5"],
    "codec names are case-insensitive ('LATIN-1' is 'latin-1')": [
        _B + "x_read_header_lines__mutmut_25",
        _B + "x_read_header_lines__mutmut_35"],
    "iter_records: return for break after the last read: nothing follows the loop but closing the file":
        [_B + "x_iter_records__mutmut_38"],
    "_Queue.take: k = None for k = 0 ends the loop the same": [_B + "xǁ_Queueǁtake__mutmut_30"],
    "time_cut never returns 0 (index >= 1 in the first block, which is never empty), so cut <= 0 / < 1 is "
    "cut < 0; and -2 for -1 is below 0 too": [
        _B + "xǁFileSourceǁ__iter____mutmut_51",
        _B + "xǁFileSourceǁ__iter____mutmut_52",
        _B + "xǁ_Queueǁtime_cut__mutmut_28"],
    "guess_columns: rising = fractional when there are 0 or 2+ fractional columns has len != 1 like []; "
    "range(5) adds a 5th index after the two kept; a placeholder other than '' or a 5th '' is overwritten "
    "or joins to nothing": [f"{_B}x_guess_columns__mutmut_{n}" for n in (37, 63, 67, 68)],
    "__iter__'s last chunks: the loop cut until at most chunk_events (or, by time, at most MAX_CHUNK_EVENTS "
    "and no bin boundary) remain, so the rest is one step, k == queue.n, and its watermark is None anyway": [
        _B + "xǁFileSourceǁ__iter____mutmut_85",
        _B + "xǁFileSourceǁ__iter____mutmut_86",
        _B + "xǁFileSourceǁ__iter____mutmut_88",
        _B + "xǁFileSourceǁ__iter____mutmut_93"],
    "_check_coords: where = None for '' is as falsy": [_B + "xǁFileSourceǁ_check_coords__mutmut_17"],
    "warn's stacklevel (3 -> 4 or default): mutmut's trampoline adds a frame, so no test can see it under "
    "mutmut; outside it, test_dropped_events_are_counted_and_warned_about_where_the_stream_is_read fails on "
    "both (checked by hand)": [_B + "xǁFileSourceǁwarn__mutmut_6",
        _B + "xǁFileSourceǁwarn__mutmut_7"],
    # evstream/codecs: mono.py and packets.py (session 9)
    "copy=None / True / left out for copy=False in astype: a copy or not, the same values (encode's are "
    "session 12's 70, 72, 75 now)": [
        *(f"evstream.codecs.mono.x_decode__mutmut_{n}" for n in (12, 14, 25))],
    "mono.decode: memoryview.cast('b') for 'B': np.frombuffer reads the same bytes whatever the view's "
    "format": ["evstream.codecs.mono.x_decode__mutmut_6"],
    "evt3_sensor_clock: the encoder's started flag 2 for 1 (it tests state[0] != 0); -2 for -1 as the "
    "clock's time-low or row: any negative is none (both are 0 or more)": [
        f"evstream.codecs.packets.x_evt3_sensor_clock__mutmut_{n}" for n in (26, 28, 30)],
    # evstream/codecs: EVT2, EVT3, the packet CDR, the attachment (session 9)
    "EVT3 decoder before the first TIME_HIGH: the clock's wraps are 0 until a TIME_HIGH is seen (only "
    "the has-high branch counts them), so (loops >> 24) / (loops << 25) is 0 too; and the time a TIME_LOW "
    "computes there is recomputed by the TIME_HIGH that ends the branch before any event takes it": [
        f"evstream.codecs.evt3.x__decode_kernel__mutmut_{n}" for n in (36, 37, 88, 89, 90, 91, 92, 93, 94)],
    "EVT3 decoder: a TIME_HIGH equal to the last one (payload <= high) drops by 0, never a wrap (its "
    "has_high = 2, 32, is now killed: test_seek compares the state it stores)": [
        "evstream.codecs.evt3.x__decode_kernel__mutmut_204"],
    "EVT2 skip kernel: has_high = 2 for 1 (only ever tested for truth, in both EVT2 kernels)": [
        "evstream.codecs.evt2.x__skip_kernel__mutmut_40"],
    "Evt2Encoder: np.array([-1]) is int64 without the dtype; -2 for -1 as 'no TIME_HIGH written yet' "
    "(cur >= 0 decides, and either starts from 0)": [
        f"evstream.codecs.evt2.xǁEvt2Encoderǁ__init____mutmut_{n}" for n in (3, 5, 7)],
    "Evt2Encoder.encode: a word buffer of float64 (np.empty's default; every word < 2^32 is exact) or "
    "larger than needed, and a copy or not in the final astype: the same bytes": [
        f"evstream.codecs.evt2.xǁEvt2Encoderǁencode__mutmut_{n}" for n in (51, 53, 57, 59, 65, 86, 88, 91)],
    "decode_attachment: n >= 16 for n > 16: 16 bytes is evstream's layout, taken by the branch before": [
        "evstream.codecs.attachment.x_decode_attachment__mutmut_11"],
    "EventPacket CDR: 'UTF-8' is 'utf-8'; memoryview.cast('b') for 'B' (len, slicing to bytes, struct and "
    "indexing a byte against 0 or 1 are the same); aligning from pos + 4 for pos - 4 (8 apart: the same "
    "padding for sizes 1, 4 and 8); aligning a 1-byte field, or not aligning when size > 2 (no field is 2 "
    "bytes), changes nothing": [
        f"evstream.codecs.event_packet.{m}" for m in (
            "x__string__mutmut_4", "xǁ_Readerǁstring__mutmut_36", "x_decode_packet__mutmut_5",
            "x_encode_packet__mutmut_18", "xǁ_Readerǁalign__mutmut_7", "xǁ_Readerǁscalar__mutmut_1",
            "xǁ_Readerǁscalar__mutmut_2")],
    "the last-event map as float64: NEVER_US (-2^62) and every time difference below 2^53 µs (285 years) "
    "are exact, so the same comparisons": [
        "evstream.denoise.refractory.xǁRefractoryFilterǁ_allocate__mutmut_4",
        "evstream.denoise.refractory.xǁRefractoryFilterǁ_allocate__mutmut_7"],
    # session 10 (the in-process executor)
    "the cascade's progress as float64: it holds an event index (< 2^53, exact) and a 0/1 flag, so the same "
    "comparisons and the same calls (seen by hand: the cascade tests pass compiled too; the ahead-of-time "
    "table misses and numba compiles a float64 variant, a cost, not a result)": [
        "evstream.denoise.cascade.xǁPaperCascadeǁ_both__mutmut_9"],
    "bind(kernel, 7, ...) for 6: the bound call gets exactly 6 arguments, so args[:7] + fixed + args[7:] is "
    "args[:6] + fixed, the same call": [
        "evstream.denoise.cascade.xǁPaperCascadeǁ_both__mutmut_44"],
    "dc_kernel's new-bin branch taken for an event of the current bin (bin_end = bin_start - bin_us before the "
    "first event; ti <= bin_start for <): it stores in_bin and reads it back, its expiry range is empty "
    "(nb == b), and it sets bin_start and bin_end to what they were, so nothing changes": [
        "evstream.denoise.timeseries.x_dc_kernel__mutmut_20", "evstream.denoise.timeseries.x_dc_kernel__mutmut_98"],
    "dc_kernel's prefetch at another address: a prefetch is a hint to the cache that no value depends on (as "
    "plain Python it does nothing; compiled, a float address may not type, which the tests would see)": [
        "evstream.denoise.timeseries.x_dc_kernel__mutmut_90"],
    "TimeSeriesFilter's uint16 row-sum check with 2r + 2 for 2r + 1: after the radius (<= MAX_RADIUS_PX = 32) "
    "and n_bins (<= 255) checks, (2r + 2) n_bins <= 66 * 255 = 16830, far below 65535: neither form raises "
    "(seen: radius_px 33 is refused by the radius check first)": [
        "evstream.denoise.timeseries.xǁTimeSeriesFilterǁ__post_init____mutmut_60"],
    "TimeSeriesFilter's grown `live` buffer as float64: it holds event indices (< BLOCK_EVENTS, exact in "
    "float64), and every read of one goes through ix() (np.uintp) before it indexes, so the same events "
    "(by reading; the DC kernel tests pass with it written by hand, compiled, but that they grow the buffer "
    "was not checked)": [
        "evstream.denoise.timeseries.xǁTimeSeriesFilterǁ_ready__mutmut_24"],
    "save_representation: another spelling of the temporary name ('XX.partXX', '.PART'): the file is renamed "
    "to its own name once whole, and no reader looks for the temporary one": [
        f"evstream.framing.arrays.x_save_representation__mutmut_{n}" for n in (6, 7)],
    "_table's anchors without a dtype (ints): np.interp returns float64 whatever the anchors' dtype, so the "
    "same table": ["evstream.framing.render.x__table__mutmut_3"],
    # framing's window framers (session 11)
    "FixedCount's last time None for 0 between frames: fn_run and fn_scan set it with a frame's first event, "
    "and it is read (a full frame's end, finish) only while the frame holds events (by hand, compiled: the "
    "FN tests pass too)": ["evstream.framing.fixed.xǁFixedCountǁ_reset__mutmut_5"],
    "an empty frame's count 1 for 0 with no counts: _frame makes the empty frame (n_events 0) whenever the "
    "counts are None, whatever n": ["evstream.framing.fixed.xǁFixedWindowǁ_advance__mutmut_22"],
    "SlidingFramer._reset's frame end, counts and buffers (None, '', float64 for int64): _reset leaves no frame "
    "open (start None), and push calls _first, which sets all of them, before any is read": [
        f"evstream.framing.overlap.xǁSlidingFramerǁ_reset__mutmut_{n}" for n in (2, 4, 9, 11, 15)],
    "the flat indices' buffer grown longer than the times' (size + live): push makes room by the times' "
    "length, so the extra is never written (session 12: push's mutant 16 named here was of its code before "
    "a7955fa, and is now another one, killed)": ["evstream.framing.overlap.xǁSlidingFramerǁ_make_room__mutmut_34"],
    "SlidingFramer._skip_empty is never called: OA and adaptive each override it (no test reaches it)": [
        f"evstream.framing.overlap.xǁSlidingFramerǁ_skip_empty__mutmut_{n}" for n in range(1, 10)],
    "adaptive's jump past empty frames not taken when the frame ends exactly on the watermark w: the frame "
    "stays current, holds no event (none comes before w), and the next advance to w or later steps it onto "
    "the same grid (its overlap has settled)": ["evstream.framing.overlap.xǁAdaptiveOverlapǁ_skip_empty__mutmut_14"],
    "voxel grids zeroed lazily: zeroing one bin further ahead ((lo + 3)·hw for (lo + 2)·hw) zeroes a bin no "
    "event has reached yet (events come in time order, so bins only move up), before any write to it": [
        "evstream.framing.represent.x_voxel_count_kernel__mutmut_42",
        "evstream.framing.represent.x__zero_for__mutmut_10"],
    "np.searchsorted's side is 'left' by default":
        ["evstream.framing.represent.xǁ_EventBufferǁindex_of_time__mutmut_10"],
    "the representations' event buffer's times as float64 (np.zeros' default, at first or once grown): every "
    "time below 2^53 µs is exact, and each use (searchsorted, t − t_start scaled to a bin, a timestamp's "
    "fraction of its window) computes the same values": [
        "evstream.framing.represent.xǁ_EventBufferǁ__init____mutmut_3",
        "evstream.framing.represent.xǁ_EventBufferǁappend__mutmut_33"],
    "NOT equivalent, but no test can tell: the flat index as uint32 for a sensor of 2^31 pixels or more (2 / hw "
    "or 3**32 for 2 * hw < 2**32) wraps there, and such a sensor's count image is 8 GiB; every sensor a test "
    "can hold gets uint32 either way": [
        f"evstream.framing.overlap.xǁSlidingFramerǁ_first__mutmut_{n}" for n in (8, 12)],
    "EVT2 encoder: `cur > 0` for `cur >= 0` (session 6): frm is only used as frm >> 28, and cur = 0 gives "
    "0 on either side; `cur >= 1` likewise": [
        f"evstream.codecs.evt2.x__encode_kernel__mutmut_{n}" for n in (13, 14)],
    # session 11 (codecs, whole): each by reading the code
    "EVT2 decoder: has_high = 2 for 1 (only ever tested for truth, in both EVT2 kernels)": [
        "evstream.codecs.evt2.x__decode_kernel__mutmut_64"],
    "EventPacket CDR layout: the padding after is_bigendian depends on the offset mod 4, and the offset before "
    "that field group is a multiple of 4 (pad1 aligned it, + 8 keeps it): leaving it out, or -20 for +20 (40 "
    "apart), gives the same padding": [f"evstream.codecs.event_packet.x__layout__mutmut_{n}" for n in (34, 38)],
    "Evt3Encoder: a first scratch of float64 or of 1 word: every call with events needs 4n + ramp >= 11 "
    "words, so the first scratch is always replaced (session 13: its 'no row yet' -2, 11, is killed by the "
    "state compared with the reference, and reallocating at 5n + ramp, encode 67, by the buffer test)": [
        *(f"evstream.codecs.evt3.xǁEvt3Encoderǁ__init____mutmut_{n}" for n in (20, 21))],
    "EVT3 encoder kernel: cur_low = None for -1 after a TIME_HIGH (both differ from every time low 0..4095, "
    "so the TIME_LOW word follows and replaces it); t[i+2] == ti for t[i+1] == ti in the vector test: times "
    "are checked non-decreasing first, so t[i+2] == t[i] holds only with t[i+1] == t[i]": [
        f"evstream.codecs.evt3.x__encode_kernel__mutmut_{n}" for n in (58, 113)],
    "EVT3 packets kernel: the encoder's started flag 2 for 1 (tested != 0); `h >> 12` for `h << 12` as the "
    "check's previous time: both are <= t0 (the kernel returned already when h > t0 >> 12, and h >= 0), "
    "and only the first event is compared with it; n <= 0 / n < 1 for n < 0: a packet writes at least a "
    "TIME_LOW and an event word (n >= 2), a packet without events having returned before": [
        f"evstream.codecs.evt3.x__encode_packets_kernel__mutmut_{n}" for n in (78, 104, 106, 107)],
    "EVT3 skip kernel: (loops << 25) for (loops << 24) in the test of the period carried over from the "
    "block before only makes it hold more often (never less); stop = 0 then has `_follow` read the block "
    "word by word, which finds the same first word at or after start_us": [
        "evstream.codecs.evt3.x__skip_kernel__mutmut_10"],
    "the hot-pixel learner's counts as float64 (np.zeros' default): every count is exact, so the same "
    "comparisons and scores": [
        f"evstream.denoise.hotpixel.xǁHotPixelLearnerǁ_allocate__mutmut_{n}" for n in (3, 5, 8, 10)],
    "the state set in __post_init__ ('' for None) is replaced by _allocate before its first use; "
    "np.array([NEVER_US]) without a dtype is int64": [
        *(f"evstream.denoise.hotpixel.xǁHotPixelLearnerǁ__post_init____mutmut_{n}" for n in (44, 47, 49)),
        "evstream.denoise.refractory.xǁRefractoryFilterǁ__post_init____mutmut_16"],
    "framer flags: argparse's default is None without `default=None`; getattr(args, 'all_events', None) "
    "is as falsy as False for arguments without the flag": [
        "evstream.framing.options.x_add_framer_flags__mutmut_44", "evstream.framing.options.x_framer_spec__mutmut_26"],
    "render: a sequential map's total is never negative (ON + OFF counts, or |array|), so clipping it "
    "from None is clipping from 0; a time surface or last-timestamp image is within 0..1, so clipping "
    "it at 2 is at 1; write_png's sync=False only spares an fsync (the same bytes)": [
        "evstream.framing.render.x_coloured__mutmut_33", "evstream.framing.render.x_render_representation__mutmut_20",
        "evstream.framing.render.x_write_png__mutmut_4"],
    # session 12: denoise_cascade
    "TimeSeriesFilter._bind: `far` (which kernel variant runs: the prefetching one or not) decided otherwise "
    "(2 / nbytes > FAR_BYTES): both variants give the same classes and scores (test_prefetching_kernels_match_"
    "brute_force), so only the speed differs": ["evstream.denoise.timeseries.xǁTimeSeriesFilterǁ_bind__mutmut_5"],
    "the bound call looked up under None (never a key) and so bound again: setdefault returns the call already "
    "bound for this variant, the same call (a cost, not a result)": [
        "evstream.denoise.timeseries.xǁTimeSeriesFilterǁ_judge__mutmut_9"],
    "TimeSeriesFilter's grown `live` buffer as float64 (np.empty(n, None)): as _ready 24 (session 10), event "
    "indices exact in float64, each read through ix() before it indexes": [
        "evstream.denoise.timeseries.xǁTimeSeriesFilterǁ_ready__mutmut_22"],
    "TimeSeriesFilter._init's first `live` buffer (0 events) as float64: _ready replaces it with an int64 one "
    "before any chunk of one event or more is judged, and a chunk of none gathers nothing into it": [
        "evstream.denoise.timeseries.xǁTimeSeriesFilterǁ_init__mutmut_62"],
    "a stage's first FIFO capacity from another estimate (n_pixels // 5 for // 4): fifo_capacity gives at least "
    "4,096 and the FIFO doubles whenever full (test_dc_activation_fifo_grows_past_its_initial_capacity): the same "
    "classes": ["evstream.denoise.timeseries.xǁTimeSeriesFilterǁ_init__mutmut_5"],
    "TimeSeriesFilter's uint16 row-sum check as (2r + 1) / n_bins > 65535: like __post_init__ 60 (session 10), "
    "after the radius (<= 32) and n_bins (<= 255) checks no form of it raises ((2r + 1) n_bins <= 16575)": [
        "evstream.denoise.timeseries.xǁTimeSeriesFilterǁ__post_init____mutmut_56"],
    "a prefetch at another address (density's FIFO entry 32 behind the head for 32 ahead, the index still masked "
    "into the ring; DC's cell q - r for q + r): a hint to the cache no value depends on, as dc_kernel 90 (session "
    "10); `prefetch` stays compiled and never faults": [
        "evstream.denoise.density.x_density_kernel__mutmut_102", "evstream.denoise.timeseries.x_dc_kernel__mutmut_66"],
    "dc_kernel's outer loop as while j <= k (session 6): at j == k, stop = min(k, j + cap - size) == j and the "
    "loop breaks at once, returning j >= k as before": ["evstream.denoise.timeseries.x_dc_kernel__mutmut_43"],

    # session 13: denoise_cascade (the other 89 of session 12's random 200)
    "DensityFilter._run's score array as np.zeros(n, ): float64 is np.zeros' default dtype, the same array": [
        "evstream.denoise.density.xǁDensityFilterǁ_run__mutmut_23"],
    "DensityFilter._run after a grow stores the call it binds under None (never looked up): _grow's _bind has just "
    "emptied _calls, so setdefault returns that new call for this variant all the same; the next chunk binds "
    "again (a cost, not a result, as TimeSeriesFilter._judge 9)": [
        "evstream.denoise.density.xǁDensityFilterǁ_run__mutmut_43"],
    "DensityFilter._init's first FIFO capacity from n_pixels / 16 for // 16: fifo_capacity takes int(entries), and "
    "int(n / 16) == n // 16 for any sensor (exact below 2**53)": [
        "evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_5"],
    "DensityFilter._init's map of two planes without match_polarity: the second plane is never read or written "
    "(every event's plane is 0, its position and fifo_y the same); only `far` (4 x nbytes > FAR_BYTES) holds from "
    "half the sensor size, the prefetching variant, whose classes and scores are the same "
    "(test_prefetching_kernels_match_brute_force, test_density_kernel_widening_its_map_matches_brute_force[far])": [
        "evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_19"],
    "DensityFilter._init's coordinate dtype: int32 for uint16 from 2r rows sooner (rows = 2(h + 3r + 1)), or int64 "
    "map positions for int32 whatever the map's length: a wider integer holds the same columns, rows and positions "
    "(the head-group test and its twin compare modulo the dtype's width, which no coordinate then nears)": [
        f"evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_{n}" for n in (36, 39, 47, 69)],
    "DensityFilter._init's 16-bit coordinates two rows further (rows = 2(h + 2r - 1)): the ON plane's rows (at most "
    "2h + 2r) still fit, and the modular head-group test, the margin's reason, runs only without match_polarity, "
    "where rows are below h (test_density_polarity_planes_on_the_tallest_sensors)": [
        "evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_33"],
    "DensityFilter._init's fifo_state of 3 (an unused third slot: the kernel and grow_fifo read [head, size]); "
    "per_pol as float64 (counts exact below 2**53; g then enters only float arithmetic, the threshold and the "
    "mean count, as it does as an int)": [
        f"evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_{n}" for n in (93, 99)],
    "DensityFilter: `far` decided otherwise (5 x nbytes for 4 x): as TimeSeriesFilter._bind 5, the prefetching "
    "variant gives the same classes and scores": ["evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_24"],
    "DensityFilter: the kernel variant that tests each event's code whatever all_live says (all_live None: not "
    "computed, or computed when the caller gave it, or None passed to density_kernel): all_live only lets the "
    "kernel skip that test when no code is set, so the same classes (a cost, not a result)": [
        *(f"evstream.denoise.density.xǁDensityFilterǁ_run__mutmut_{n}" for n in (2, 3)),
        "evstream.denoise.density.xǁDensityFilterǁ_kernel__mutmut_2"],
    "density kernel: a prefetch at another address (the box of the event 16 ahead on the ON plane whatever its "
    "polarity, its column subtracted, its rows upward): as 102 (session 12), a hint no value depends on": [
        f"evstream.denoise.density.x_density_kernel__mutmut_{n}" for n in (73, 74, 82, 93)],
    "density kernel: the head group of exactly G entries tested by the loop (size > G for >=): the loop is the "
    "match_polarity / far path, the same out and near as the vector test (both against brute force)": [
        "evstream.denoise.density.x_density_kernel__mutmut_212"],
    "density kernel: the group expiry waiting for more than G entries (size > G for >=): a head group of exactly "
    "G entries all out of the window stays one event longer, and the head-group test (size >= G) takes every one "
    "of them off the count and off g meanwhile: the same counts (its cells may widen the map sooner: the same "
    "values)": ["evstream.denoise.density.x_density_kernel__mutmut_138"],
    "density kernel's relative score when the mean count is 0: inf only if total > 1 for > 0; but a mean count of "
    "0 means g = 0 events in the window, and total counts some of them (total <= g), so total = 0 and both give "
    "0.0 (the inf branch is never taken)": ["evstream.denoise.density.x_density_kernel__mutmut_352"],
    "reference_head_group's mask one bit wider (2 << bits for 1 << bits): on every input the density kernel gives "
    "it the same: a coordinate below 2**bits - 32 less x0 >= -r is below 2**bits (no mask needed), and a negative "
    "difference d >= 33 + r - 2**bits masks to 2**bits + d or 2**(bits + 1) + d, both past box = 2r: outside "
    "either way; the compiled test of the intrinsic against its twin, on wrapped coordinates too, fails on it": [
        "evstream.denoise.density.x_reference_head_group__mutmut_10"],
    "NOT equivalent compiled, only as plain Python: DensityFilter._init's fifo_y as float64 (np.zeros(group, )): "
    "compiled, the head-group intrinsic refuses coordinates of two dtypes (a TypingError in every test that "
    "reaches the kernel); plain, its twin takes them, and rows are exact in float64 (np.uint32 of a negative "
    "float wraps as of an int): the same values. Left for the twin to refuse what the intrinsic's typing refuses": [
        "evstream.denoise.density.xǁDensityFilterǁ_init__mutmut_86"],
    "density kernel: fifo_y's ON-plane offset h + 2r + 2 for + 1: written and read back with the same offset, the "
    "planes' rows still more than 2r apart (never near), and 2h + 2r + 1 within the dtype's rows": [
        "evstream.denoise.density.x_density_kernel__mutmut_33"],
    "row_full: L = 4, 8 or 16 tested by the next wider vector (L < 4 for L <= 4, and so on), whose lanes from n = L "
    "on are masked off: the same answer (and every stage's L = 2r + 1 is odd)": [
        f"evstream.denoise.rowsum.x_row_full__mutmut_{n}" for n in (4, 14, 24)],
    "row_full: L equal to the vector's cells taken by the loop (L < width for <=): its one pass tests a full vector "
    "of n = L lanes, the same test": ["evstream.denoise.rowsum.x_row_full__mutmut_3"],
    "row_full over several vectors stepping one cell (range(0, L)) for a vector's width: each test covers cells "
    "pos + k .. pos + min(L, k + width) - 1, all of the L cells, and those from k = 0, width, 2 width .. cover "
    "them all: the same any() (row_add's like mutant, 47, adds twice and is killed)": [
        "evstream.denoise.rowsum.x_row_full__mutmut_49"],

    # session 12: denoise_baselines, denoise_learned
    "learned features' state: the word and bitmap maps padded by 3r columns for 2r (wp = width + 3r: the extra "
    "columns right of the sensor are zero, 'never fired', as the 2r padding is, and every index goes through the "
    "same wp), or a first FIFO of 2 << 12 pairs for 1 << 12 (a power of two too; the kernel grows a full one "
    "anyway): the same features": [
        f"evstream.denoise.learned.features.x_new_state__mutmut_{n}" for n in (5, 8)],
    "learned feature kernel: an MLP's batch arrays allocated for a logistic model too (m_max = BATCH whatever "
    "n_hidden; never read there); the word rows prefetched from row -2 or at another address (row + k*wp - 1, "
    "row - k*wp + 1): a prefetch is a hint that never faults and no value depends on": [
        f"evstream.denoise.learned.features.x_feature_kernel__mutmut_{n}" for n in (38, 150, 156, 157)],

    # session 13: denoise_learned
    "learned feature kernel: the word rows prefetched at row + k / wp + 1 (a float address, cast to an index by "
    "numba): a prefetch is a hint that never faults and no value depends on": [
        "evstream.denoise.learned.features.x_feature_kernel__mutmut_158"],
    "learned training samples: the unthinned signal also drawn through the thinning generator at fraction 1.0 "
    "(`random() < 1.0` keeps every event: the same signal); the thinned copies then use later draws of the same "
    "seeded generator, another random thinning of the same fraction, as seeded (nothing promises which draws)": [
        "evstream.denoise.learned.train.x_samples__mutmut_31"],
    "fit_logistic's linear predictor not clipped at +30: above 30 the logistic is 1 within 1e-13 and exp(-z) "
    "underflows to 0 without a warning (the lower clip, kept, is the one that guards an overflow)": [
        "evstream.denoise.learned.train.x_fit_logistic__mutmut_24"],
    "fit_mlp's output bias as two equal entries (np.zeros(2)): each update broadcasts the same value to both, and "
    "only b2[0] is read and returned": ["evstream.denoise.learned.train.x_fit_mlp__mutmut_32"],
    "sha256 of a model's recording read in blocks of 2 MiB for 1 MiB: the same digest": [
        "evstream.denoise.learned.train.x_sha256__mutmut_16"],
    "Model.threshold's 1e-9 tolerance at its own edge (`<` for `<=`): only a keep exactly equal to the grid's end "
    "-/+ 1e-9 as a float is refused instead of taken; the tolerance absorbs rounding, its last ulp is no contract": [
        f"evstream.denoise.learned.model.xǁModelǁthreshold__mutmut_{n}" for n in (23, 24)],

    # session 12: codecs, codecs_payloads
    "mono.encode: copy=None / True / left out for copy=False in the final astype('<u8'): a copy or not, the "
    "same bytes (session 9's encode 58, 60, 63, renumbered by the x, y, p checks added since)": [
        f"evstream.codecs.mono.x_encode__mutmut_{n}" for n in (70, 72, 75)],
    "PacketEncoder's first encode_many scratch of float64 (np.empty's default) or of 1 word: encode_many needs "
    "room for 4 words an event + 1 + a ramp of at least 7 words, so it replaces the first scratch (uint16) "
    "before any use": [f"evstream.codecs.packets.xǁPacketEncoderǁ__init____mutmut_{n}" for n in (15, 17, 18)],
    "PacketEncoder.encode_many: bounds and t without their dtype (ascontiguousarray(.., None)): every caller "
    "gives integers (the MCAP sink int64 bounds and times, tests lists of ints: int64 without the dtype), and "
    "an integer array of another dtype carries the same indices and times through the same arithmetic": [
        f"evstream.codecs.packets.xǁPacketEncoderǁencode_many__mutmut_{n}" for n in (3, 5, 35, 37)],
    "PacketEncoder.encode_many: ramp floored at 1 for 0 (it is at least 7: 5 (wraps + 1) + 2 with wraps >= 0 "
    "and the clock never past the packet); reallocating the scratch when it is exactly the room (the same "
    "size again); -2 for -1 as 'no clock yet' (the kernel tests high < 0); what it slices and where the "
    "packets start when the kernel wrote none (done = 0: no packet is made from them, the slice clamps); "
    "ends[: done + 1] (zip stops at the done bounds); encoding='evt3' left out (EventPacket's default)": [
        f"evstream.codecs.packets.xǁPacketEncoderǁencode_many__mutmut_{n}"
        for n in (102, 130, 162, 166, 169, 174, 176, 199)],
    "Evt3Decoder.decode: out arrays of len(rest) + 65 for + 64 events: one more slot of room, and the kernel "
    "stops by the room it has (the same events, in as many or fewer calls)": [
        "evstream.codecs.evt3.xǁEvt3Decoderǁdecode__mutmut_15"],
    "EVT3 skip kernel: the test of the period carried over from the block before made to hold more often, "
    "never less (`has_high or`, high << 13, + 4096 for + 0xFFF; session 11's 10 is loops << 25): stop = 0 "
    "then has `_follow` read the block word by word from the state as it stands (before a TIME_HIGH, its "
    "TIME_LOWs stop nothing), which finds the same first word at or after start_us and counts the same "
    "wraps; in its TIME_HIGH pass, stopping at an earlier TIME_HIGH (loops << 25, payload << 13, + 4096) "
    "likewise: `_restore` and `_follow` then go word by word from there": [
        f"evstream.codecs.evt3.x__skip_kernel__mutmut_{n}" for n in (6, 12, 13, 42, 44, 45)],
    "EVT3 skip kernel and _follow: payload <= high for < in the wrap test: a TIME_HIGH equal to the last one "
    "drops by 0, never the 4080 a wrap needs (as the decoder's 204)": [
        "evstream.codecs.evt3.x__skip_kernel__mutmut_31", "evstream.codecs.evt3.x__follow__mutmut_30"],
    "_restore: need_low / need_y / need_base = None for False once found: as falsy": [
        f"evstream.codecs.evt3.x__restore__mutmut_{n}" for n in (29, 36, 57)],
    "EVT3 encoder kernel: the TIME_HIGH steps from cur_high even when not started ('or True'): state[1] (the "
    "time-high) is 0 whenever state[0] (started) is 0: a new Evt3Encoder's state, and every restart "
    "(evt3_sensor_clock, the packets kernel) sets started; cur_low = -2 for -1 after a TIME_HIGH: as -1 "
    "(and session 11's None), no time low 0..4095, so the TIME_LOW word follows": [
        f"evstream.codecs.evt3.x__encode_kernel__mutmut_{n}" for n in (54, 60)],
    "EVT3 encoder kernel: the started flag it leaves, 1 whatever (or True, else 1) or 2 for 1: it is called with "
    "one event or more (Evt3Encoder returns before it for none, the packets kernel for an empty packet), so "
    "started is true at its end, and the flag is only tested != 0": [
        f"evstream.codecs.evt3.x__encode_kernel__mutmut_{n}" for n in (247, 248, 249)],
    "EVT3 packets kernel: a state of 5 slots (the encoder kernel reads 4); `h > t0 << 12` for `t0 >> 12` (the "
    "clock past the first event hardly ever refused here): the encoder kernel it calls refuses the same "
    "packet, its check's last time being h << 12 > t0, and the kernel returns j as before": [
        f"evstream.codecs.evt3.x__encode_packets_kernel__mutmut_{n}" for n in (11, 32)],
    "EVT3 packets kernel: -2 for -1 as the opening clock's 'no time low' and 'no row' (compared with time lows "
    "and rows, 0 or more; as evt3_sensor_clock's 28, 30); Evt3Encoder's state without its dtype: a list of "
    "Python ints is int64": [
        *(f"evstream.codecs.evt3.x__encode_packets_kernel__mutmut_{n}" for n in (84, 88)),
        *(f"evstream.codecs.evt3.xǁEvt3Encoderǁ__init____mutmut_{n}" for n in (3, 5))],
    "EVT2 encoder: the start value np.int64(1) for 0 before any TIME_HIGH (session 6's, renumbered): frm is "
    "only read as frm >> 28, 0 for both, and replaced by ((frm >> 28) + 1) << 28 at each wrap": [
        "evstream.codecs.evt2.x__encode_kernel__mutmut_16"],
    "EventPacket CDR layout: pad1 - 8 for pad1 + 8 moves the offset by 16, a multiple of 8, so pad2 and pad3 "
    "(the offset mod 8 and mod 4) are the same": ["evstream.codecs.event_packet.x__layout__mutmut_26"],

    # session 12: framing, framing_windows, framing_represent, testing, sources_base
    "VoxelGrid._add and _add_flat: their table branch is never taken (every caller, `add`, `take` and "
    "`add_flat`, first asks `_count_add` / `_count_take` / `_count_add_flat`, which take the window in one "
    "kernel whenever `_table` of the same span gives a table), so a mutant there, or `table = None`, changes "
    "nothing": [
        *(f"evstream.framing.represent.xǁVoxelGridǁ_add__mutmut_{n}" for n in (1, *range(32, 56))),
        *(f"evstream.framing.represent.xǁVoxelGridǁ_add_flat__mutmut_{n}" for n in (1, *range(22, 36)))],
    "the time surface's counted positions over fn windows (`where`) computed again for each frame: the same "
    "array; at finish (no chunk, n = 0) use_cls True for False: cls and use_cls are read only where n > 0": [
        f"evstream.framing.represent.xǁTimeSurfaceǁ_surfaces__mutmut_{n}" for n in (10, 27)],
    "state_nbytes of an object without a __dict__: None for {} holds no array either (0 bytes)":
        ["evstream.testing.x_state_nbytes__mutmut_49"],
    "voxel kernels' lazy zeroing asked one bin sooner ((lo + 2)·hw >= ready): `ready` is a whole number of "
    "bins (m·hw), and in the one case added, lo + 2 = m, _zero_bins(out, m·hw, m·hw) zeroes nothing and "
    "returns m·hw": ["evstream.framing.represent.x_voxel_kernel__mutmut_27",
                     "evstream.framing.represent.x_voxel_count_kernel__mutmut_31"],
    "the representations' event buffer grown to another size that holds the events (2·(live + k) alone, "
    "3·len, 3·(live + k)): the same events kept": [
        f"evstream.framing.represent.xǁ_EventBufferǁappend__mutmut_{n}" for n in (24, 25, 27)],
    "a window's array seen flat by reshape(-2): NumPy infers the size for any negative one, as for -1; a "
    "grid's `ready` None once done(): a done grid is handed on in its Representation, never written again": [
        "evstream.framing.represent.xǁ_Gridǁ__init____mutmut_4", "evstream.framing.represent.xǁ_Gridǁdone__mutmut_3"],
    "the representations' event buffer's flat indices as int64 where uint32 holds them (the same values), "
    "or uint32 for 2·hw = 2^32 too (its largest index, 2^32 − 1, still fits)": [
        f"evstream.framing.represent.xǁRepresentationFramerǁ_geometry__mutmut_{n}" for n in (7, 11, 12)],
    "RepresentationFramer._represent: a, b None for 0 where the representation needs no events (histogram, count: "
    "their _compute reads neither)": ["evstream.framing.represent.xǁRepresentationFramerǁ_represent__mutmut_27"],
    "RepresentationFramer._forget's `start is None` never holds once there is a buffer: it is made at the first "
    "chunk with events, which also gives the windowing framer its start": [
        "evstream.framing.represent.xǁRepresentationFramerǁ_forget__mutmut_20"],
    "VoxelGrid._table giving no table where it gave one (never, `window != 'fn'`; at a span of exactly "
    "VOXEL_TABLE_MAX_US; at 2 bins) or the same (fn windows, which never ask: 'XXfnXX', 'FN'): those windows go "
    "through the arithmetic kernels, whose grids the table kernels' are to the bit "
    "(test_voxel_table_kernels_are_the_arithmetic_kernels_to_the_bit); only slower":
        [f"evstream.framing.represent.xǁVoxelGridǁ_table__mutmut_{n}" for n in (3, 4, 5, 6, 7)],
    "VoxelGrid._table's weights: w_lo 3·span long (voxel_table fills len(lo_at) // 2 µs, the rest never read); "
    "w_hi as float64 (each weight a float32 product stored exactly, and a float32 grid element plus a float64 "
    "holding a float32 rounds once, to the float32 sum)": [
        f"evstream.framing.represent.xǁVoxelGridǁ_table__mutmut_{n}" for n in (23, 27)],
    "SlidingFramer._make_room grows the buffer sooner (3·(live + more), or >=) or to another size that still "
    "takes `more` (3·len, 3·(live + more), or 2·(live + more) alone); or to 2·len where that is too small, "
    "and push, the kernel again lacking room, calls it again until it fits: the same events kept, the same "
    "frames": [f"evstream.framing.overlap.xǁSlidingFramerǁ_make_room__mutmut_{n}" for n in (8, 10, 16, 17, 18, 19, 20)],
    "the overlap buffer's times as float64 once grown (np.zeros' default): every time below 2^53 µs is exact, "
    "and each use (a binary search for the next frame's start, a time surface's newest time, a voxel bin) "
    "computes the same values": [f"evstream.framing.overlap.xǁSlidingFramerǁ_make_room__mutmut_{n}" for n in (24, 26)],
    "SlidingFramer._close: searchsorted's side is 'left' by default; an empty frame handed the counts as well "
    "(_frame makes the empty frame whenever n is 0, whatever it is given); the follower handed no buffered "
    "event (j == tail) for the next window: an empty array, zero when emitted, dropped by _forget when passed": [
        f"evstream.framing.overlap.xǁSlidingFramerǁ_close__mutmut_{n}" for n in (15, 28, 43)],

    # session 13: codecs
    "Evt3Encoder's first scratch of float64 by dtype None (as session 11's 20, np.empty's default): a call "
    "with events asks for 4 words an event plus the ramp (never below 0), so `encode` replaces it (uint16) "
    "before any use; a call with none returns before it": [
        "evstream.codecs.evt3.xǁEvt3Encoderǁ__init____mutmut_18"],
    "Evt3Encoder.encode: the ramp floored at 1 for 0: in a call the kernel writes, t_last >= last_t, so wraps "
    ">= 0 and the ramp is 5 + 2 or more; it is below 1 only in a call going back in time, which the kernel "
    "refuses before writing a word (the scratch then one word longer, never read)": [
        "evstream.codecs.evt3.xǁEvt3Encoderǁencode__mutmut_50"],
    "Evt3Encoder.encode: `k <= 0` or `k < 1` for `k < 0`: the kernel is called with one event or more (none "
    "returns before it) and writes at least that event's word when it accepts them, so k is never 0": [
        f"evstream.codecs.evt3.xǁEvt3Encoderǁencode__mutmut_{n}" for n in (93, 94)],
    "Evt3Encoder.encode: t without its dtype (ascontiguousarray(t, None)): as plain Python, how this copy runs "
    "the kernel, times of any integer dtype give the same words (uint64 - int64 is float64 in NumPy, exact "
    "below 2^53 µs). Not equivalent in the program: compiled, uint64 times do not type (float64 >> 12), which "
    "test_encoder_takes_any_integer_dtype_and_names_the_last_call_s_time catches (seen failing with it written "
    "by hand, compiled); named here only because the plain copy cannot show it": [
        f"evstream.codecs.evt3.xǁEvt3Encoderǁencode__mutmut_{n}" for n in (3, 5)],

    # session 13: framing_represent, framing_bound
    "TimeSurface._surfaces: searchsorted's side is 'left' by default": [
        "evstream.framing.represent.xǁTimeSurfaceǁ_surfaces__mutmut_52"],
    "TimeSurface._surfaces counting a window's events into its counts when none of them counts (n_events >= 0): "
    "its events [i, j) are then all noise, which the kernel skips before it counts, so nothing is written. So as "
    "plain Python (the copy); compiled, numba refuses at typing a kernel that writes the shared read-only zeros "
    "of an empty frame (48140dd), and test_time_surface_over_fixed_time_windows_of_noise_alone fails on it": [
        "evstream.framing.represent.xǁTimeSurfaceǁ_surfaces__mutmut_58"],
    "TimeSurface._surfaces: a frame's counts seen flat by reshape(-2) (NumPy infers the size for any negative "
    "one); the open window's events applied when none is left (i <= n: _apply(n, n) applies nothing, and its "
    "rebase check reads t[n - 1], which the last _apply already rebased to)": [
        f"evstream.framing.represent.xǁTimeSurfaceǁ_surfaces__mutmut_{n}" for n in (76, 95)],
    "frames_at_once: max(2, frame_bytes) for max(1, ...): every framer's frame is at least 4 bytes (FramerBase: "
    "two uint16 count planes of one pixel or more; a representation adds its channels); the max only keeps a "
    "0 from dividing": ["evstream.framing.bound.x_frames_at_once__mutmut_11"],
    "Cutter starting with one empty piece counted: a stream's first piece starts at its first event, so holds "
    "it, and sets the count to 0; before it, the one check of the count passes only when max_empty_frames is "
    "0 (gap_pieces 1), and then jumps to the first event, where the watermark already is: nothing handed on": [
        "evstream.framing.bound.xǁCutterǁ__init____mutmut_26"],
    "Cutter._first reading max_empty_frames from the framer itself, not its inner framer: a representation "
    "passes its window parameters on as given (WINDOW_PARAMS; None: the window's default, 1,000 = "
    "DEFAULT_MAX_EMPTY), and a windowing framer has no inner one": [
        f"evstream.framing.bound.xǁCutterǁ_first__mutmut_{n}" for n in (25, 31, 32)],
    "Cutter._first: pause_us falls back to 1 (or 2) only when step_us is None, and then max_us is None, "
    "gap_pieces 0 and pause_us unused; gap_pieces as 1 for 0 where max_us is None: read only where it is not; "
    "one more empty piece before the jump over a pause (+ 2): the framer has stopped emitting empty frames "
    "by the last one already, so that piece closes no frame (the same frames, the same bound)": [
        f"evstream.framing.bound.xǁCutterǁ_first__mutmut_{n}" for n in (42, 50, 51)],
    "Cutter.pieces: end_of_chunk as t_end alone for a chunk with events differs only where t_end is below the "
    "last event; its last piece is then the chunk's events with t_end = the last event, not the chunk itself, "
    "and every framer's watermark is the larger of t_end and the last event (framing.base): the same frames": [
        "evstream.framing.bound.xǁCutterǁpieces__mutmut_16"],
    "Cutter.pieces, the jump over a pause once the framer has stopped emitting empty frames (gap_pieces past "
    "max_empty_frames): one more empty piece first (`>`); the count of empty pieces left at 1 after it (the "
    "next piece with events resets it; pieces before that are the same pause); an empty piece at the watermark "
    "itself (`nxt >= mark`) or the chunk again after the jump (`given` False or None): a watermark no higher "
    "than the framer's closes nothing; the jump piece without its watermark (None: the lowest): it closes no "
    "frame either way, and the next piece's watermark carries the framer on. The same frames, the same bound": [
        f"evstream.framing.bound.xǁCutterǁpieces__mutmut_{n}" for n in (32, 39, 40, 42, 43, 45, 49)],
    "Cutter.pieces: searchsorted's side is 'left' by default": ["evstream.framing.bound.xǁCutterǁpieces__mutmut_71"],

    # session 13: framing (a random 200 of the seven files; the lead)
    "png_bytes at zlib level 7 by default for 6: another compression of the same pixels (a reader decodes the "
    "same image; only the size moves, which test_png_header_level_and_message checks between levels 0 and 9)": [
        "evstream.framing.render.x_png_bytes__mutmut_1"],
    "FixedWindow._reset: end 1 for 0 while start is None: push sets both at the first event before any read "
    "(an empty first chunk returns before them; finish reads them only with events counted)": [
        "evstream.framing.fixed.xǁFixedWindowǁ_reset__mutmut_3"],
    "SlidingFramer._reset: the empty buffer of flat pixel indices as float64 (dtype None): _first replaces both "
    "buffers at the first event, before any read": ["evstream.framing.overlap.xǁSlidingFramerǁ_reset__mutmut_13"],
    "SlidingFramer._first: uint32 flat indices while 2 * pixels < 2^33 (for 2^32): they differ only for a sensor "
    "of over 2^31 pixels, whose two uint16 count planes alone would be 8 GiB: no stream a test or a user can "
    "frame reaches it": ["evstream.framing.overlap.xǁSlidingFramerǁ_first__mutmut_13"],
}
EQUIVALENT: dict[str, str] = {m: why for why, names in _EQUIVALENT_BY_REASON.items() for m in names}

# The copy's root conftest: while mutmut runs a mutant, the tests that reach it run fastest first
# (durations from mutmut's own clean run), so with `-x` a killed mutant costs its quickest failing
# test, not the slowest test of the module; a survivor still meets every test that reaches it.
ORDER_CONFTEST = """\
import json
import os
from pathlib import Path


def pytest_collection_modifyitems(session, config, items):
    if "__mutmut_" not in os.environ.get("MUTANT_UNDER_TEST", ""):
        return
    stats = Path("mutmut-stats.json")
    if stats.is_file():
        duration = json.loads(stats.read_text()).get("duration_by_test", {})
        items.sort(key=lambda item: duration.get(item.nodeid, 0.0))
"""


def _is_njit(dec: ast.expr) -> bool:
    f = dec.func if isinstance(dec, ast.Call) else dec
    return (isinstance(f, ast.Name) and f.id == "njit") or (isinstance(f, ast.Attribute) and f.attr == "njit")


def _is_cache(dec: ast.expr) -> bool:
    f = dec.func if isinstance(dec, ast.Call) else dec
    return isinstance(f, ast.Attribute) and f.attr in ("cache", "lru_cache")


def _called(call: ast.Call) -> str | None:
    f = call.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None


def _is_intrinsic(f: ast.FunctionDef) -> bool:
    return any(isinstance(d.func if isinstance(d, ast.Call) else d, ast.Name)
               and (d.func if isinstance(d, ast.Call) else d).id == "intrinsic" for d in f.decorator_list)


def kept_compiled(sources: dict[str, str], mutated: set[str]) -> set[str]:
    """The kernels of the files `mutated` (of `sources`, path -> source) that stay compiled, by name: those
    calling an `@intrinsic` (it has no Python form), and those a compiled kernel calls, since compiled code
    cannot call a plain-Python function: a kernel of a file not mutated (represent's `voxel_take` calls
    overlap's `frame_part`), or one kept itself (density's kernel, kept for `_head_group`, calls rowsum's
    `column_sum`). Names are matched without their module: a clash keeps more compiled, never less."""
    trees = {path: ast.parse(src) for path, src in sources.items()}
    functions = [(path, f) for path, tree in trees.items() for f in ast.walk(tree) if isinstance(f, ast.FunctionDef)]
    intrinsics = {f.name for _, f in functions if _is_intrinsic(f)} - set(PLAIN_TWINS)
    kernels = {(path, f.name): {_called(c) for c in ast.walk(f) if isinstance(c, ast.Call)}
               for path, f in functions if any(_is_njit(d) for d in f.decorator_list)}
    compiled = {k for k, calls in kernels.items() if k[0] not in mutated or calls & intrinsics}
    while more := {k for k in kernels if k not in compiled and k[1] in set().union(*(kernels[c] for c in compiled))}:
        compiled |= more
    return {name for path, name in compiled if path in mutated}


# numba intrinsics with a plain-Python twin (the definition their tests compare them with), as the lines
# that bind the twin to the intrinsic's name: a kernel calling one is not kept compiled for it but runs as
# plain Python calling the twin, so that it is mutated like any kernel (the learned features' kernel). The
# twin takes Python ints (a NumPy int64 shift count would overflow its 64-bit bitmaps).
PLAIN_TWINS = {"nb8_support": "from .neighbours import reference_nb8 as _nb8_twin\n"
                              "nb8_support = lambda word, bins, *scalars: _nb8_twin(word, bins, *map(int, scalars))\n",
               # the row-summed maps' vector add and test (rowsum.py), and density's head-group test: so the
               # cascade's kernels, `row_add`, `row_full` and `column_sum` run (and are mutated) as plain Python
               "_lanes_of": "_lanes_of = lambda a: VECTOR_BYTES // a.itemsize\n",
               **{f"_add_{c}": f"_add_{c} = lambda a, pos, delta, n: reference_add(a, pos, delta, n, {c})\n"
                  for c in (4, 8, 16, 32)},
               **{f"_full_{c}": f"_full_{c} = lambda a, pos, n, limit: reference_full(a, pos, n, limit, {c})\n"
                  for c in (4, 8, 16, 32)},
               "_head_group": "_head_group = reference_head_group\n"}


# Compiled helpers of modules a target does not mutate, which its plain kernels would call through numba's
# dispatcher (~1 us a call: a quarter of the learned features' plain kernel's time, session 12), bound instead
# in the target's mutated files to their plain form: `ix`'s own Python body (`np.uintp(i)`: a negative index
# fails as it does through the dispatcher), and `prefetch` as nothing (a hint: it changes no result). Only
# where no kernel of the file stays compiled to call it (numba would find a Python function), and per target,
# so that the other targets' copies (and their verdicts) stay as they are.
PLAIN_HELPERS = {"denoise_learned": {"ix": "ix = ix.py_func\n", "prefetch": "prefetch = lambda a, i: None\n"}}


def plain_kernels(source: str, keep: set[str] = frozenset(), helpers: dict[str, str] | None = None) -> str:
    """`source` with its numba kernels as plain Python: `@njit` lines removed (kept on functions calling
    an `@intrinsic`: numba-only, and on those named in `keep`), and every `functools.cache` / `lru_cache`
    (see the module's doc); a plain kernel calling an intrinsic of PLAIN_TWINS calls its twin, and one
    calling a compiled helper of `helpers` (name -> the line binding its plain form: PLAIN_HELPERS) calls
    its plain form, unless a kernel still compiled calls it too."""
    tree = ast.parse(source)
    intrinsics = {f.name for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and _is_intrinsic(f)}
    intrinsics -= set(PLAIN_TWINS)
    helpers = helpers or {}
    drop: set[int] = set()
    twins: set[str] = set()
    plain_calls: set[str] = set()
    compiled_calls: set[str] = set()
    for f in ast.walk(tree):
        if not isinstance(f, ast.FunctionDef):
            continue
        calls = {_called(c) for c in ast.walk(f) if isinstance(c, ast.Call)}
        for dec in f.decorator_list:
            if (_is_njit(dec) and not calls & intrinsics and f.name not in keep) or _is_cache(dec):
                drop.update(range(dec.lineno - 1, dec.end_lineno))  # the `@` is on dec.lineno
                twins |= calls & set(PLAIN_TWINS) if _is_njit(dec) else set()
                plain_calls |= calls if _is_njit(dec) else set()
            elif _is_njit(dec):
                compiled_calls |= calls
    lines = source.splitlines(keepends=True)
    return "".join(line for i, line in enumerate(lines) if i not in drop) + "".join(
        "# tests/mutation.py: the intrinsic's plain twin\n" + PLAIN_TWINS[name] for name in sorted(twins)) + "".join(
        "# tests/mutation.py: the compiled helper's plain form\n" + helpers[name]
        for name in sorted((plain_calls - compiled_calls) & set(helpers)))


def package_sources() -> dict[str, str]:
    """Every module of the package as it installs (named as in the copy: evstream/..., evstream/sources/...,
    evstream/sinks/...) -> its source in the work tree."""
    out = {}
    for where, base in (("evstream", ROOT / "evstream"), ("evstream/sources", ROOT / "sources"),
                        ("evstream/sinks", ROOT / "sinks")):
        for path in sorted(base.rglob("*.py")):
            out[f"{where}/{path.relative_to(base)}"] = path.read_text()
    return out


def plain_sources(name: str, sources: dict[str, str] | None = None) -> dict[str, str]:
    """Target `name`'s files to mutate, as its copy has them (`plain_kernels`, keeping `kept_compiled`)."""
    sources = sources or package_sources()
    mutated = {path for pattern in TARGETS[name][0] for path in fnmatch.filter(sources, pattern)}
    keep = kept_compiled(sources, mutated)
    return {path: plain_kernels(sources[path], keep, PLAIN_HELPERS.get(name)) for path in sorted(mutated)}


def _source_of(copy_path: str) -> Path:
    """A file to mutate, named as in the copy (evstream/sources/...), in the work tree (sources/...)."""
    rel = Path(copy_path).relative_to("evstream")
    return ROOT / rel if rel.parts[0] in ("sources", "sinks") else ROOT / "evstream" / rel


def _imports() -> dict[str, list[tuple[str | None, set[str]]]]:
    """tests/NAME.py -> its imports: (None, modules) for `import a.b`, (module, names) for `from a import b`."""
    found = {}
    for test in sorted((ROOT / "tests").glob("*.py")):
        nodes = [n for n in ast.walk(ast.parse(test.read_text())) if isinstance(n, (ast.Import, ast.ImportFrom))]
        found[f"tests/{test.name}"] = [(getattr(n, "module", None), {a.name for a in n.names}) for n in nodes]
    return found


def importers(copy_path: str, imports: dict | None = None) -> set[str]:
    """The test files (tests/NAME.py) importing, in-process, the module `copy_path` or one of its functions
    or classes with methods (from the module or its package): the tests that can reach its mutants."""
    module = copy_path.removesuffix(".py").replace("/", ".")
    package, _, leaf = module.rpartition(".")
    tree = ast.parse(_source_of(copy_path).read_text())
    code = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)
            or (isinstance(n, ast.ClassDef) and any(isinstance(b, ast.FunctionDef) for b in n.body))}
    return {test for test, found in (imports or _imports()).items() if test != "tests/mutation.py" and any(
        (source is None and module in names) or source == module
        or (source == package and (leaf in names or names & code)) for source, names in found)}


def selection_gaps() -> dict[str, list[str]]:
    """target -> the test files importing its functions that its selection leaves out, but for those
    named in LEFT_OUT and the targets in TOOLS (each with its reason): {} when every selection is whole."""
    gaps, imports = {}, _imports()
    for name, (mutate, tests) in TARGETS.items():
        missing = set().union(*(importers(f, imports) for f in mutate)) - set(tests) - set(LEFT_OUT)
        if missing and name not in TOOLS:
            gaps[name] = sorted(missing)
    return gaps


def _config(name: str, ws: Path, tests: list[str]) -> None:
    """The copy's pyproject.toml ([tool.mutmut]: what to mutate, the tests, the limits) and the conftest
    ordering each mutant's tests; rewritten on every run, so a resumed copy gets the current ones."""
    (ws / "conftest.py").write_text(ORDER_CONFTEST)
    pyproject = (ROOT / "pyproject.toml").read_text()
    pyproject = re.sub(r"\[tool\.pytest\.ini_options\][^\[]*", "", pyproject)
    (ws / "pyproject.toml").write_text(pyproject + "\n[tool.mutmut]\n" + "\n".join([
        'source_paths = ["evstream"]',
        f"only_mutate = {json.dumps(TARGETS[name][0])}",
        f"pytest_add_cli_args_test_selection = {json.dumps(tests)}",
        'pytest_add_cli_args = ["-p", "no:cacheprovider", "-q"]',
        'also_copy = ["recordings", "conftest.py"]',
        # mutmut stops a mutant after (clean duration of its tests + constant) x multiplier seconds of
        # wall time (and twice that of CPU). The constant covers what the clean durations leave out
        # (pytest's start, fixtures' setup) on a loaded machine: with 5 s, every mutant of a stage whose
        # tests share a synthetic scene "timed out" (counted as killed) at load 7.
        "timeout_multiplier = 3.0",
        "timeout_constant = 30.0",
    ]) + "\n")


def workspace(name: str, ws: Path, tests: list[str]) -> Path:
    """`ws`: the package as it installs (sources/ and sinks/ inside evstream/), the tests, the shipped
    recordings and a pyproject.toml whose [tool.mutmut] names what to mutate and the tests to run."""
    shutil.rmtree(ws, ignore_errors=True)
    shutil.copytree(ROOT / "evstream", ws / "evstream", ignore=IGNORE)
    for sub in ("sources", "sinks"):
        shutil.copytree(ROOT / sub, ws / "evstream" / sub, ignore=IGNORE)
    shutil.copytree(ROOT / "tests", ws / "tests", ignore=IGNORE)
    shutil.copytree(ROOT / "recordings", ws / "recordings")
    for path, source in plain_sources(name).items():
        (ws / path).write_text(source)
    _config(name, ws, tests)
    return ws


def statuses(ws: Path) -> dict[str, str]:
    """mutant -> status ('killed', 'survived', 'no tests', 'not checked', ...) from mutmut's results."""
    r = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"], cwd=ws,
                       capture_output=True, text=True)
    return dict((s.strip() for s in line.rsplit(":", 1)) for line in r.stdout.splitlines() if ":" in line)


def score(status: dict[str, str]) -> dict:
    """Killed / (killed + survived) with named equivalents set apart; a timeout (a mutant that loops)
    counts as killed, a mutant no test reaches ('no tests') as a survivor, and one not run as neither."""
    counts: dict[str, int] = {}
    status = {m: s for m, s in status.items() if m.partition("__mutmut_")[0] not in NOT_RUN}
    for m, s in status.items():
        s = "equivalent" if m in EQUIVALENT and s in ("survived", "no tests") else s
        counts[s] = counts.get(s, 0) + 1
    killed = counts.get("killed", 0) + counts.get("timeout", 0)
    survived = counts.get("survived", 0) + counts.get("no tests", 0)
    return {"counts": counts, "score": killed / (killed + survived) if killed + survived else None,
            "survivors": sorted(m for m, s in status.items() if s in ("survived", "no tests")
                                and m not in EQUIVALENT)}


def mutmut(ws: Path, names: list[str]) -> dict[str, str]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(ws / ".numba_cache"), PYTHONHASHSEED="0",
               HYPOTHESIS_PROFILE=os.environ.get("HYPOTHESIS_PROFILE", "mutation"))
    env.pop("NUMBA_DISABLE_JIT", None)
    children = os.environ.get("MUTATION_CHILDREN", "2")
    with open(ws / "mutmut.log", "a") as log:
        subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children", children, *names], cwd=ws, env=env,
                       stdout=log, stderr=subprocess.STDOUT)
    return statuses(ws)


def _same_sources(name: str, ws: Path) -> bool:
    """Whether the copy in `ws` was made from the files to mutate as they are now."""
    return all((ws / path).is_file() and (ws / path).read_text() == source
               for path, source in plain_sources(name).items())


def functions(source: str, module: str) -> dict[str, str]:
    """mutmut's name for each function and method of `source` (module 'evstream.framing.fixed':
    'evstream.framing.fixed.x_fn_scan', '...xǁFixedCountǁpush'; a mutant is that + '__mutmut_N') -> what
    its mutants' verdicts depend on in the module: its own source, and for a method its class's source
    but the other methods (fields, defaults, decorators)."""
    tree = ast.parse(source)
    out = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            out[f"{module}.x_{node.name}"] = ast.get_source_segment(source, node, padded=True)
        elif isinstance(node, ast.ClassDef):
            methods = [n for n in node.body if isinstance(n, ast.FunctionDef)]
            lines = source.splitlines(keepends=True)
            skip = {i for m in methods for i in range(m.lineno - 1 - len(m.decorator_list), m.end_lineno)}
            first = min([node.lineno] + [d.lineno for d in node.decorator_list]) - 1
            shell = "".join(line for i, line in enumerate(lines[:node.end_lineno]) if i >= first and i not in skip)
            for m in methods:
                out[f"{module}.xǁ{node.name}ǁ{m.name}"] = shell + ast.get_source_segment(source, m, padded=True)
    return out


def _functions_of(name: str, ws: Path) -> dict[str, str]:
    """`functions` of each file the copy in `ws` mutates, as the copy has them (plain kernels)."""
    out = {}
    for pattern in TARGETS[name][0]:
        for path in ws.glob(pattern):
            if path.suffix == ".py":
                rel = path.relative_to(ws).with_suffix("")
                out.update(functions(path.read_text(), ".".join(rel.parts)))
    return out


def unchanged(verdicts: dict[str, dict], before: dict[str, str], after: dict[str, str]) -> dict[str, dict]:
    """The verdicts whose function (`functions`) reads the same `before` and `after` a change of sources."""
    return {m: v for m, v in verdicts.items()
            if (fn := m.partition("__mutmut_")[0]) in after and before.get(fn) == after[fn]}


def _copy(name: str, ws: Path, tests: list[str]) -> Path:
    """Resume the copy in `ws` if it was made from the files to mutate as they are now (mutmut keeps
    each mutant's result; new tests are copied in), else make a fresh one, keeping the in-process
    verdicts of the functions whose source has not changed (mutmut names mutants per function)."""
    if (ws / "mutants").is_dir() and _same_sources(name, ws):
        shutil.copytree(ROOT / "tests", ws / "tests", dirs_exist_ok=True, ignore=IGNORE)
        _config(name, ws, tests)
        return ws
    verdicts, before = _verdicts(ws / "inproc.json"), _functions_of(name, ws)
    workspace(name, ws, tests)
    if verdicts:
        kept = unchanged(verdicts, before, _functions_of(name, ws))
        (ws / "inproc.json").write_text("".join(json.dumps(v) + "\n" for v in kept.values()))
        print(f"{name}: the sources changed: {len(kept)} of {len(verdicts)} verdicts kept (their functions' "
              f"source is the same)", flush=True)
    return ws


def run(name: str, only: list[str] = (), again: bool = False) -> dict:
    """Mutate and test module `name`, resuming an earlier run of the same sources (remove
    out/mutation/NAME to start over). With `only` (mutant-name globs, e.g. '*.x_accumulate__*'), just
    those not run yet or timed out (the one verdict that depends on the machine's load); with `again`,
    those whatever their earlier result."""
    ws = _copy(name, OUT / name, TARGETS[name][1])
    names = list(only)
    if only and not again and (ws / "mutants").is_dir():
        names = [m for m, s in statuses(ws).items() if s in ("not checked", "timeout")
                 and any(fnmatch.fnmatchcase(m, g) for g in only)]
        if not names:
            names = ["-"]  # nothing left: mutmut's names must match no mutant rather than be empty
    status = mutmut(ws, names)
    result = score(status)
    (ws / "score.json").write_text(json.dumps(result, indent=1))
    return result


# --- the in-process executor (`--inproc`): load-independent verdicts on a shared machine -------------
# mutmut stops a mutant on wall-clock time, so on a loaded machine an equivalent mutant of a slow test
# "times out" and counts as killed. Here mutmut only writes the mutants (its generation step); one
# worker process then runs them one at a time: it sets MUTANT_UNDER_TEST (read by mutmut's trampoline
# at every call) and calls pytest.main on the tests that reach the mutated function (found by a first,
# clean run in mutmut's "stats" mode), fastest first, with -x. Each test's time limit is CPU time
# (ITIMER_PROF: 5 x its clean CPU + 5 s), which the load does not change. A clean run (no
# mutant) before and after must pass: it is the control that nothing one mutant did leaked into the
# next. A worker that dies (a mutant crashing a compiled kernel) is restarted after that mutant, which
# counts as killed ('crash'); so is one the parent's `guard` stops (a loop in compiled code: 'timeout';
# memory without bound: 'memory'). Verdicts go to out/mutation/MODULE/inproc.json, one line per mutant,
# and a resumed run skips those already there; `--again` drops the old ones once the control has passed.

def generate(ws: Path) -> list[str]:
    """mutmut's own mutants of the copy in `ws` (its generation step only), by name."""
    if not (ws / "mutants.done").is_file():  # none yet, or a generation cut short
        shutil.rmtree(ws / "mutants", ignore_errors=True)
        code = ("import os; os.environ['MUTANT_UNDER_TEST'] = 'mutant_generation'\n"
                "from mutmut.__main__ import copy_src_dir, copy_also_copy_files, create_mutants\n"
                "copy_src_dir(); copy_also_copy_files(); create_mutants(2)\n")
        subprocess.run([sys.executable, "-c", code], cwd=ws, check=True, stdout=subprocess.DEVNULL)
        (ws / "mutants.done").touch()
    names = []
    for meta in sorted((ws / "mutants").rglob("*.py.meta")):
        names += json.loads(meta.read_text())["exit_code_by_key"]
    return names


def _verdicts(path: Path) -> dict[str, dict]:
    if not path.is_file():
        return {}
    return {v["mutant"]: v for v in map(json.loads, path.read_text().splitlines()) if v.get("mutant")}


def _redo(ws: Path) -> set[str]:
    """The mutants `--again` runs again whose old verdicts are still in inproc.json (until a control run passes)."""
    return set((ws / "inproc.redo").read_text().split()) if (ws / "inproc.redo").is_file() else set()


def forget_redone(ws: Path, todo: list[str]) -> None:
    """After a passing control run: drop the verdicts of the mutants `--again` asked for that this run
    will run (`todo`). Before it, a failing control (tests newer than the copy's sources, a broken set-up)
    leaves every verdict there; those asked for and not run yet stay asked for."""
    redo = _redo(ws)
    gone = redo & set(todo)
    if gone:
        kept = [v for m, v in _verdicts(ws / "inproc.json").items() if m not in gone]
        (ws / "inproc.json").write_text("".join(json.dumps(v) + "\n" for v in kept))
    if redo - gone:
        (ws / "inproc.redo").write_text("\n".join(sorted(redo - gone)))
    else:
        (ws / "inproc.redo").unlink(missing_ok=True)


def _running(path: Path) -> dict:
    """What the worker is running ({'mutant', 'test', 'limit_s', 'rss_mb'}; {} between mutants)."""
    try:
        return json.loads(path.read_text() or "{}")
    except (FileNotFoundError, json.JSONDecodeError):  # not written yet, or caught mid-write
        return {}


def _cpu_s(pid: int) -> float:
    """The CPU time (user + system) process `pid` has used, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


# The parent's guard: the worker's own CPU-time limit (ITIMER_PROF) runs its handler between Python
# bytecodes, so a mutant looping inside compiled code (a kernel that stays compiled) never sees it:
# session 10's `DensityFilter._grow` 26 ran 11 min and grew to 2.2 GB. The parent reads the worker's
# CPU time and memory from /proc and kills it past the running test's CPU limit + GUARD_CPU_S, past
# GUARD_WALL x that limit of wall time (a mutant blocked without using CPU: no CPU limit sees it; the
# load can reach this one, so it is generous), or past the memory bound the worker gives (2 x the clean
# run's peak + 1 GiB).
GUARD_CPU_S = 10.0
GUARD_WALL = 30.0


def guard(worker: subprocess.Popen, running: Path, poll_s: float = 0.5, cpu_s: float = GUARD_CPU_S,
          wall: float = GUARD_WALL) -> dict | None:
    """Wait for `worker`; kill it if the test it is running (`running`, which it rewrites at each test)
    goes past its limits (see above). The mutant's verdict when it was killed ('timeout', or 'memory'),
    else None."""
    import time

    seen, cpu0, wall0 = None, 0.0, 0.0
    while worker.poll() is None:
        now = _running(running)
        try:
            cpu, rss = _cpu_s(worker.pid), _rss_mb(worker.pid)
        except (FileNotFoundError, ProcessLookupError, IndexError):  # it has just ended
            continue
        key = (now.get("mutant"), now.get("test"))
        if key != seen:
            seen, cpu0, wall0 = key, cpu, time.monotonic()
        if now.get("mutant") and now.get("pid", worker.pid) == worker.pid:
            limit = now.get("limit_s", 20.0)
            why = ("memory" if rss > now.get("rss_mb", float("inf")) else
                   "timeout" if cpu - cpu0 > limit + cpu_s or time.monotonic() - wall0 > wall * limit else None)
            if why:
                worker.kill()
                worker.wait()
                return {"mutant": now["mutant"], "status": why, "failed": [now.get("test")],
                        "guard": f"cpu {cpu - cpu0:.1f} s, wall {time.monotonic() - wall0:.1f} s, rss {rss:.0f} MB "
                                 f"(limit {limit:.1f} s CPU)", "at": time.strftime("%H:%M:%S")}
        time.sleep(poll_s)
    return None


def sampled(names: list[str], n: int) -> list[str]:
    """A seeded random `n` of `names`, in the order drawn, which is the order they run: a run cut short has
    run a random sample too (the first m drawn; for a module of 1,046 or more mutants and n <= 341 they are
    `--sample m`'s, as random.sample draws one by one there). Session 12's first cascade sample ran in name
    order: cut short, it had run whole files and none of others."""
    return random.Random(0).sample(names, n)


def inproc(name: str, only: list[str] = (), again: bool = False, sample: int = 0) -> dict:
    """Run module `name`'s mutants (those matching `only`, if given; a random `sample` of them, the same
    for the same mutants) in-process; the score as `run`'s, over the mutants run."""
    ws = _copy(name, OUT / name, TARGETS[name][1])
    if (ws / "mutants").is_dir():  # a resumed copy: the tests, and the modules it does not mutate, as they are now
        shutil.copytree(ROOT / "tests", ws / "mutants" / "tests", dirs_exist_ok=True, ignore=IGNORE)
        mutated = plain_sources(name)
        for path, source in package_sources().items():
            copy = ws / "mutants" / path
            if path not in mutated and (not copy.is_file() or copy.read_text() != source):
                copy.parent.mkdir(parents=True, exist_ok=True)
                copy.write_text(source)
    names = [m for m in generate(ws) if m.partition("__mutmut_")[0] not in NOT_RUN]
    if only:  # in the order of the globs: the first given run first
        names = [m for g in only for m in names if fnmatch.fnmatchcase(m, g)]
        names = list(dict.fromkeys(names))
    if sample and sample < len(names):  # an unbiased estimate of the score when all would take too long
        names = sampled(names, sample)
    path = ws / "inproc.json"
    if again:  # the worker forgets their verdicts once its control run has passed (forget_redone)
        (ws / "inproc.redo").write_text("\n".join(names))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(ws / ".numba_cache_inproc"), PYTHONHASHSEED="0",
               HYPOTHESIS_PROFILE=os.environ.get("HYPOTHESIS_PROFILE", "mutation"))
    env.pop("NUMBA_DISABLE_JIT", None)
    shutil.rmtree(ws / ".numba_cache_inproc", ignore_errors=True)
    while True:
        todo = [m for m in names if m not in _verdicts(path) or m in _redo(ws)]
        if not todo:
            break
        (ws / "inproc.todo").write_text("\n".join(todo))
        # what the last worker ran is not the new one's: read against it, the new worker's clean run would
        # count as that mutant's test and be stopped, again and again
        (ws / "inproc.running").unlink(missing_ok=True)
        worker = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", name],
                                  cwd=ws / "mutants", env=env)
        stopped = guard(worker, ws / "inproc.running")
        if worker.returncode == 0:
            break
        running = _running(ws / "inproc.running").get("mutant")
        if stopped is None and (worker.returncode > 0 or not running):  # a failed control run or set-up
            raise SystemExit(f"{name}: the in-process worker failed (exit {worker.returncode}); see {path}")
        # the worker died on this mutant (a crash kills it) or the guard stopped it: restart after it
        verdict = stopped or {"mutant": running, "status": "crash", "exit": worker.returncode}
        with open(path, "a") as out:
            out.write(json.dumps(verdict) + "\n")
        print(f"{name}: {verdict}", flush=True)
    status = {m: v["status"] for m, v in _verdicts(path).items() if m in names}
    status = {m: {"crash": "killed", "memory": "killed"}.get(s, s) for m, s in status.items()}
    result = score(status)
    (ws / "score-inproc.json").write_text(json.dumps(result, indent=1))
    return result


class _Timeout(Exception):
    pass


def worker(name: str) -> int:
    """One process, cwd the copy's mutants/: a clean run (mapping tests to the functions they reach),
    each mutant of inproc.todo in turn, a clean run again. Exit 1 if a clean run fails."""
    import resource
    import signal
    import time

    import mutmut.mutation.trampoline as trampoline
    import pytest

    sys.path[0] = os.getcwd()  # the copy's evstream and tests, not those beside this script
    ws = Path.cwd().parent
    hits: set[str] = set()
    trampoline.record_trampoline_hit = lambda fn, caller=None: hits.add(fn)
    timed_out = []

    def on_alarm(signum, frame):
        timed_out.append(True)
        raise _Timeout("CPU time limit")

    signal.signal(signal.SIGPROF, on_alarm)

    def cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    def running(**now) -> None:  # for the parent's guard: what runs now, its limits (atomic: it reads it any time)
        (ws / "inproc.running.tmp").write_text(json.dumps(dict(now, pid=os.getpid()) if now else now))
        os.replace(ws / "inproc.running.tmp", ws / "inproc.running")

    class Record:
        def __init__(self, limits=None, mutant=None, rss_mb=None):
            self.cpu, self.reach, self.failed, self.limits = {}, {}, [], limits
            self.mutant, self.rss_mb = mutant, rss_mb

        @pytest.hookimpl(hookwrapper=True)
        def pytest_runtest_protocol(self, item, nextitem):
            hits.clear()
            t0 = cpu()
            if self.limits is not None:  # each test's own CPU limit: a loop is caught in the test that loops
                limit = self.limits.get(item.nodeid, 20.0)
                running(mutant=self.mutant, test=item.nodeid, limit_s=limit, rss_mb=self.rss_mb)
                signal.setitimer(signal.ITIMER_PROF, limit)
            try:
                yield
            finally:
                signal.setitimer(signal.ITIMER_PROF, 0)
            self.cpu[item.nodeid] = cpu() - t0
            for fn in hits:
                self.reach.setdefault(fn, []).append(item.nodeid)

        def pytest_runtest_logreport(self, report):
            if report.failed:
                self.failed.append(report.nodeid)

    args = ["--rootdir=.", "--tb=line", "-q", "-p", "no:cacheprovider", "-p", "no:randomly"]

    def clean(tag: str) -> Record:
        rec = Record()
        os.environ["MUTANT_UNDER_TEST"] = "stats"
        code = pytest.main(args + TARGETS[name][1], plugins=[rec])
        os.environ["MUTANT_UNDER_TEST"] = ""
        if code != 0:
            print(f"{name}: the clean run {tag} failed ({rec.failed})", file=sys.stderr)
            raise SystemExit(1)
        return rec

    base = clean("before the mutants")
    todo = (ws / "inproc.todo").read_text().split()
    forget_redone(ws, todo)  # --again: the old verdicts go now that the control has passed
    limits = {t: 5 * c + 5 for t, c in base.cpu.items()}
    rss_mb = 2 * resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 + 1024  # ru_maxrss: KiB
    with open(ws / "inproc.json", "a") as out:
        for mutant in todo:
            fn = mutant.partition("__mutmut_")[0]
            if fn not in base.reach:  # no test reaches it: none can kill it, so no need to run them all
                out.write(json.dumps({"mutant": mutant, "status": "no tests", "tests": 0, "reached": False,
                                      "failed": [], "cpu_s": 0.0, "at": time.strftime("%H:%M:%S")}) + "\n")
                out.flush()
                continue
            tests = sorted(base.reach[fn], key=base.cpu.get)
            running(mutant=mutant, rss_mb=rss_mb)
            rec, timed_out[:] = Record(limits, mutant, rss_mb), []
            os.environ["MUTANT_UNDER_TEST"] = mutant
            t0 = cpu()
            try:
                code = pytest.main(args + ["-x"] + tests, plugins=[rec])
            except _Timeout:
                code = -1
            finally:
                signal.setitimer(signal.ITIMER_PROF, 0)
                os.environ["MUTANT_UNDER_TEST"] = ""
            status = ("timeout" if timed_out else "survived" if code == 0 else "killed" if code == 1
                      else f"error {code}")
            out.write(json.dumps({"mutant": mutant, "status": status, "tests": len(tests),
                                  "reached": fn in base.reach, "failed": rec.failed[:1],
                                  "cpu_s": round(cpu() - t0, 2), "at": time.strftime("%H:%M:%S")}) + "\n")
            out.flush()
    running()
    clean("after the mutants")
    return 0


def dry(name: str) -> int:
    """The module's tests against its plain-Python kernels, unmutated: they must pass (and show how
    long mutmut's first, whole-selection run takes)."""
    ws = workspace(name, OUT / f"{name}.dry", TARGETS[name][1])
    env = dict(os.environ, NUMBA_CACHE_DIR=str(ws / ".numba_cache"), PYTHONPATH=str(ws),
               HYPOTHESIS_PROFILE=os.environ.get("HYPOTHESIS_PROFILE", "mutation"))
    tests = TARGETS[name][1]
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q", "--durations=15",
                           *tests], cwd=ws, env=env).returncode


def main(argv: list[str]) -> int:
    if argv[:1] == ["--worker"]:
        return worker(argv[1])
    if argv[:1] == ["--dry"]:
        return max(dry(n) for n in argv[1:])
    only, again, by_hand = [], "--again" in argv, "--inproc" in argv
    argv = [a for a in argv if a not in ("--again", "--inproc")]
    sample = 0
    if "--sample" in argv:  # python tests/mutation.py --inproc --sample 150 framing [--only ...]
        i = argv.index("--sample")
        sample = int(argv[i + 1])
        argv = argv[:i] + argv[i + 2:]
    if "--only" in argv:  # python tests/mutation.py codecs --only '*.x__decode_kernel__*' ... [--again]
        only = argv[argv.index("--only") + 1:]
        argv = argv[:argv.index("--only")]
    names = [n for a in (argv or list(TARGETS)) for n in ALIASES.get(a, [a])]
    for name in names:
        r = inproc(name, only, again, sample) if by_hand else run(name, only, again)
        c = r["counts"]
        pct = "n/a" if r["score"] is None else f"{100 * r['score']:.1f} %"
        print(f"{name}: {pct} killed ({c.get('killed', 0)} killed, {c.get('timeout', 0)} timeout, "
              f"{c.get('survived', 0)} survived, {c.get('no tests', 0)} without a test, "
              f"{c.get('equivalent', 0)} equivalent, {c.get('not checked', 0)} not run; "
              f"survivors in {OUT / name / ('score-inproc.json' if by_hand else 'score.json')})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
