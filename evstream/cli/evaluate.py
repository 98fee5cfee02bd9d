"""`evstream synth` and `evstream eval`: scenes with ground truth, and every denoiser scored on them."""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path

from .. import api, batch, noise, synth
from ..events import EventError, Geometry
from ..safe_write import AtomicOutput, probe_writable
from .batch import _warm, add_batch_flags, interrupted, run_tasks, table
from .common import (
    Progress,
    UsageError,
    add_quiet_flag,
    check_numbers,
    counted,
    create_folder,
    folder_note,
    native_output,
    not_the_input,
)

DEFAULT_NOISE_RATIO = 0.5  # what `make recordings` and the README use


def cmd_synth(args) -> int:
    from evstream.sources import native

    check_numbers(args, positive=("duration_ms",), at_least_zero=("seed", "noise_ratio", "ba_rate_hz", "hot_share"))
    native_output(args.out, "synth")  # `synth bar out/s.raw` wrote a native .npz under that name
    geometry = Geometry(args.width, args.height)
    if args.noise_ratio is None and args.ba_rate_hz is None:
        args.noise_ratio = DEFAULT_NOISE_RATIO
    progress = Progress(quiet=args.quiet, desc=f"synth {args.scene} ")
    try:
        events = synth.scene(args.scene, geometry, duration_us=int(args.duration_ms * 1000), seed=args.seed,
                             on_progress=lambda done, total: progress.update(100 * done / total, 100, percent=True))
    finally:
        progress.done()
    meta = {"scene": args.scene, "seed": args.seed, "duration_ms": args.duration_ms, "generator": "evstream synth"}
    if args.noise_ratio or args.ba_rate_hz is not None:
        spec = noise.NoiseSpec(noise_ratio=args.noise_ratio, ba_rate_hz=args.ba_rate_hz,
                               hot_pixels=args.hot_pixels, hot_share=args.hot_share)
        events = noise.inject(events, spec, seed=args.seed + 1, t_start_us=0, t_stop_us=int(args.duration_ms * 1000))
        meta["noise"] = {k: v for k, v in vars(spec).items()}
    created = create_folder(Path(args.out).parent)
    with AtomicOutput(args.out) as part:  # never in place: an interrupted synth leaves the old file
        native.save(part, events, meta)
    counts = events.class_counts("label")
    print(f"wrote {args.out}{folder_note(created)}: {counted(len(events), 'event')} ({counts[0]:,} signal, "
          f"{counts[1]:,} background, {counts[2]:,} hot pixel)")
    return 0


def cmd_eval(args) -> int:
    from .. import evaluation

    check_numbers(args, positive=("seeds",), at_least_zero=("ratios", "rates_hz"))  # --seeds 0: empty tables, exit 0
    if args.real and not Path(args.real).is_dir():  # was Python's "[Errno 20] Not a directory: 'X'"
        raise UsageError(f"--real {args.real}: {'not a folder' if Path(args.real).exists() else 'no such folder'}")
    if args.roc:  # before minutes of work: it was "no ROC plot" at the end, exit 0
        evaluation.check_can_plot(f"--roc {args.roc}")
    inputs = batch.files_named([*args.recordings, *([args.real] if args.real else [])])
    for flag, out in (("--json", args.json), ("--roc", args.roc)):  # before minutes of work, not after
        if out:
            for path in inputs:  # `eval REC --json REC` wrote the rows over the recording
                not_the_input(path, out, f"{flag} ")
            probe_writable(out, f"{flag} ")
    if args.model and (args.out or args.no_reference):
        raise UsageError("--model goes with eval in one process on labelled noise (not with --out or --no-reference)")
    if args.out:
        return _eval_many(args)
    paths = list(args.recordings) or sorted(str(p) for p in Path("recordings").glob("*.npz"))
    if not paths and not args.real:
        raise UsageError(f"no recording to evaluate: none given and no recordings/*.npz in {Path.cwd()}; "
                         "name recordings (evstream eval REC ...), add --real DIR, or run from the repository root")
    named = set(args.recordings)  # a recording the user named and that cannot be read is an error, not a skip
    if args.real:
        paths += sorted(str(p) for p in Path(args.real).iterdir() if p.is_file() and p.suffix != ".md")
    fixed = evaluation.user_models(args.model, paths)  # a model on its own training recording: one line, exit 1
    recordings = read_recordings(paths, args.min_duration_s, "evstream eval", strict=named)
    if not recordings:
        raise UsageError("no recording to evaluate: each one was skipped (above)")
    methods = args.methods.split(",") if args.methods else list(evaluation.METHODS)
    if args.no_reference:
        return _no_reference(recordings, methods)
    if set(methods) & set(evaluation.TRAINED) and len(recordings) < 2:  # was left out without a word
        methods = [m for m in methods if m not in evaluation.TRAINED]
        note = "learned: left out (scored leave-one-recording-out: it needs a second recording to train on)"
        if not methods and not fixed:
            raise UsageError(f"--methods {args.methods}: {note}")
        print(f"evstream eval: note: {note}", file=sys.stderr)
    conditions = [evaluation.Condition(noise_ratio=r) for r in args.ratios] + [
        evaluation.Condition(ba_rate_hz=r) for r in args.rates_hz]
    curves: dict = {}
    progress = Progress(quiet=args.quiet, desc="eval", unit=" runs")

    def say(done, total, what):
        progress.update(done, total)
        progress.postfix(what)

    try:
        rows = evaluation.run(recordings, conditions, range(args.seeds), methods, tune=args.tune,
                              progress=say, curves=curves, fixed=fixed)
    finally:
        progress.done()
    print(evaluation.markdown(rows, tune=args.tune) if args.markdown else evaluation.report(rows, tune=args.tune))
    if args.json:
        write_json_rows(args.json, rows)
        print(f"wrote {args.json} ({counted(len(rows), 'row')})")
    if args.roc:
        names = [c.name for c in conditions]
        condition = args.roc_condition or ("100%" if "100%" in names else names[0])
        evaluation.plot_roc(curves, condition, args.roc)
        print(f"wrote {args.roc}")
    return 0


def write_json_rows(out: str, rows) -> None:
    """`--json FILE`: the result rows, written beside FILE and renamed when whole (never in place)."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    from .. import evaluation

    with AtomicOutput(out, flag="--json ") as part:
        part.write_text(json.dumps(evaluation.as_json_rows(rows), indent=1))


EVAL_SUFFIX = ".eval.json"  # a recording's result rows, written whole: a re-run skips the recording
NOT_A_NUMBER_OK = {"noise_ratio", "ba_rate_hz"}  # None there is a value, not a NaN sent as JSON null


def _eval_many(args) -> int:
    """`eval SOURCE... --out FOLDER`: one task per recording on a Dask cluster (evstream.batch), each
    recording's rows in OUT/ITS-PATH.eval.json; then the tables over every recording's rows."""
    from .. import evaluation

    methods = args.methods.split(",") if args.methods else [m for m in evaluation.METHODS
                                                            if m not in evaluation.TRAINED]
    if set(methods) & set(evaluation.TRAINED):
        raise UsageError("--methods learned: scored leave-one-recording-out, a model per recording trained on "
                         "all the others; run it without --out (one process)")
    if args.no_reference or args.roc:
        raise UsageError("--out FOLDER (a task per recording) takes neither --no-reference nor --roc")
    if args.jobs is not None and (args.jobs < 1 or args.scheduler):
        raise UsageError(f"--jobs {args.jobs}: at least 1, and not with --scheduler")
    sources = list(args.recordings) or ["recordings/"]
    try:
        tasks = batch.plan(sources + ([args.real] if args.real else []), args.out, EVAL_SUFFIX)
    except ValueError as e:
        raise UsageError(str(e)) from None
    params = {"methods": ",".join(methods), "ratios": list(args.ratios), "rates_hz": list(args.rates_hz),
              "seeds": args.seeds, "tune": args.tune, "min_duration_s": args.min_duration_s}
    progress = Progress(quiet=args.quiet, desc="eval ", unit="recordings", delay_s=0.5)

    def on_result(r, done, total):
        if r.status == "failed":
            print(f"evstream eval: {r.source}: {r.error}", file=sys.stderr, flush=True)
        progress.update(done, total)

    warm = functools.partial(_warm, eval_file, EVAL_SUFFIX, {**params, "min_duration_s": 0})  # kernels loaded once
    results, signum = run_tasks(args, tasks, eval_file, params, on_result, warm, progress)
    if signum is not None:  # a Ctrl-C: the tasks stopped (evstream.batch.run_many)
        print(table(results))
        return interrupted(signum, results)
    rows = []
    for r in results:
        if r.status in ("done", "skipped"):
            got = json.loads(Path(r.out).read_text())
            if got["note"]:
                print(f"evstream eval: skipping {r.source}: {got['note']}", file=sys.stderr)
            rows += [{k: float("nan") if v is None and k not in NOT_A_NUMBER_OK else v for k, v in row.items()}
                     for row in got["rows"]]
    if rows:
        print(evaluation.markdown(rows, tune=args.tune) if args.markdown else evaluation.report(rows, tune=args.tune))
    print(table(results))
    if args.json:
        write_json_rows(args.json, rows)
        print(f"wrote {args.json} ({counted(len(rows), 'row')})")
    return 1 if any(r.status == "failed" for r in results) else 0


def eval_file(source: str, out: str, *, methods: str, ratios, rates_hz, seeds: int, tune: bool,
              min_duration_s: float, **_) -> dict:
    """One task of `eval --out` (on a Dask worker): every method on `source` under every condition and
    seed; its rows (and why there are none: too short) into `out`, whole or not at all."""
    from .. import evaluation

    note = ""
    try:
        events = api.read(source)
    except (EventError, ValueError) as e:
        raise ValueError(f"unreadable: {e}") from None
    if events.duration_us * 1e-6 < min_duration_s:
        note, rows = f"{events.duration_us * 1e-6:.3f} s is shorter than --min-duration-s", []
    else:
        conditions = [evaluation.Condition(noise_ratio=r) for r in ratios] + [
            evaluation.Condition(ba_rate_hz=r) for r in rates_hz]
        rows = evaluation.run({Path(source).stem: events}, conditions, range(seeds), methods.split(","), tune=tune)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with AtomicOutput(Path(out), [source]) as part:
        Path(part).write_text(json.dumps({"source": source, "note": note, "rows": evaluation.as_json_rows(rows)}))
    return {"events": len(events), "rows": len(rows)}


def _no_reference(recordings: dict, methods: list[str]) -> int:
    """`eval --no-reference`: the recordings' own (real) noise, no labels: MESR per method."""
    from .. import evaluation, no_reference
    from ..pipeline import build

    unknown = set(methods) - set(evaluation.METHODS)
    if unknown:
        raise UsageError(f"--methods: unknown {sorted(unknown)}; known: {', '.join(evaluation.METHODS)}")
    factories = {}
    for m in methods:
        if m == "learned":  # no labels, nothing to train on: the shipped model
            factories[m] = lambda: build("stage", {"kind": "learned"})
        elif m not in ("refractory", "hotpixel"):
            factories[m] = evaluation.METHODS[m]
    print(no_reference.report(no_reference.run(recordings, factories)))
    if "learned" in factories:
        print("learned: the shipped model (trained on the synthetic scenes and the MIT-licensed recordings "
              "davis346_frames_imu_evlib.aedat4 and prophesee_gen3_vga_evt2_faery.raw)")
    return 0


def read_recordings(paths, min_duration_s: float, command: str, strict: bool | set = False) -> dict:
    """{name: events} of every readable recording in `paths`, saying on stderr which are skipped and why
    (unreadable, shorter than `min_duration_s`, a converted twin of a recording already read).
    `strict` (True, or the set of paths it applies to): an unreadable recording is an error, not a skip
    (the user named it; a folder's other files are skipped)."""
    recordings = {}
    seen = set()  # (events, first t, last t): a converted twin of a file already read is skipped
    for path in paths:
        try:
            events = api.read(path)
        except (EventError, OSError, ValueError) as e:
            if strict is True or (isinstance(strict, set) and path in strict):
                raise
            print(f"{command}: skipping {path}: {e}", file=sys.stderr)
            continue
        duration_s = events.duration_us * 1e-6
        if duration_s < min_duration_s:
            print(f"{command}: skipping {path}: {duration_s:.3f} s is shorter than --min-duration-s", file=sys.stderr)
            continue
        signature = (len(events), int(events.t[0]), int(events.t[-1]))
        if signature in seen:
            print(f"{command}: skipping {path}: same events as a recording already read", file=sys.stderr)
            continue
        seen.add(signature)
        recordings[Path(path).stem] = events
    return recordings


def add_synth_parser(sub) -> None:
    p = sub.add_parser("synth", help="simulate a scene with ground-truth labels")
    p.add_argument("scene", choices=sorted(synth.SCENES), help="the simulated scene")
    p.add_argument("out", help="output .npz (native format)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the scene and its noise (default 0)")
    p.add_argument("--duration-ms", type=float, default=1000.0, help="length of the recording (ms, default 1000)")
    p.add_argument("--width", type=int, default=synth.DEFAULT_GEOMETRY.width, help="pixels (default %(default)s)")
    p.add_argument("--height", type=int, default=synth.DEFAULT_GEOMETRY.height, help="pixels (default %(default)s)")
    p.add_argument("--noise-ratio", type=float,
                   help=f"noise events per signal event (default {DEFAULT_NOISE_RATIO:g} = 50 %%; 0 = none)")
    p.add_argument("--ba-rate-hz", type=float, help="background activity per pixel (instead of a ratio)")
    p.add_argument("--hot-pixels", type=int, default=0, help="hot pixel count (with --ba-rate-hz)")
    p.add_argument("--hot-share", type=float, default=0.1, help="share of noise from hot pixels (ratio)")
    add_quiet_flag(p)
    p.set_defaults(func=cmd_synth)


def add_eval_parser(sub) -> None:
    p = sub.add_parser("eval", help="inject labelled noise, run every denoiser, print the paper's tables")
    p.add_argument("recordings", nargs="*", help="recordings (default: recordings/*.npz); with --out also folders "
                                                 "and globs")
    p.add_argument("--real", metavar="DIR", help="also every readable recording in DIR")
    p.add_argument("--methods", help="comma-separated (default: all)")
    p.add_argument("--model", metavar="MODEL.npz", action="append", default=[], help="also score this model (`evstream "
                   "train`/`calibrate`) as it is, as method model:STEM (repeatable; not on its training data)")
    p.add_argument("--ratios", type=float, nargs="*", default=[0.1, 0.2, 0.5, 1.0, 1.5, 2.0],
                   help="noise ratios (0.5 = 50 %%)")
    p.add_argument("--rates-hz", type=float, nargs="*", default=[1.0, 3.0, 5.0],
                   help="background activity rates, Hz/pixel")
    p.add_argument("--seeds", type=int, default=2, help="noise seeds per condition")
    p.add_argument("--tune", action="store_true", help="tune each threshold on the first half, report the second")
    p.add_argument("--min-duration-s", type=float, default=0.25, help="skip shorter recordings")
    p.add_argument("--no-reference", action="store_true",
                   help="no injected noise: each method on the recordings' own noise, scored by MESR (E-MLB)")
    p.add_argument("--json", metavar="FILE", help="write every result row as JSON")
    p.add_argument("--roc", metavar="FILE.png", help="plot ROC curves")
    p.add_argument("--roc-condition", help="noise condition of the ROC plot, e.g. 100%% or 3Hz (default 100%%)")
    p.add_argument("--markdown", action="store_true",
                   help="print the mean over recordings as Markdown tables (docs/evaluation.md's, docs/generated.py)")
    p.add_argument("--out", metavar="FOLDER", help="a task per recording on a Dask cluster (docs/scale.md), its rows "
                                                    "in FOLDER/PATH.eval.json; a re-run skips what is done")
    add_quiet_flag(p)
    add_batch_flags(p)
    p.set_defaults(func=cmd_eval)
