"""`evstream train`: fit the learned denoiser to the user's own recordings; `evstream calibrate`: set a
model's operating point on recordings of a new sensor, without labels (docs/learned.md)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..events import shown
from ..safe_write import file_in_the_way, not_a_folder
from .common import UsageError, not_the_input
from .evaluate import read_recordings


def _numbers(what: str, example: str, rule: str, ok):
    """The argparse type of a list of numbers `F,F...` (`--thin` fractions, `--time-scale` factors): each must
    pass `ok`, else one line saying what was expected."""
    import argparse

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(f) for f in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what} like {example}, got {shown(text)}") from None
        if not all(ok(f) for f in values):
            raise argparse.ArgumentTypeError(f"{what} must be {rule}, got {shown(text)}")
        return values

    return parse


_fractions = _numbers("fractions", "0.3,0.1", "in (0, 1)", lambda f: 0 < f < 1)
_scales = _numbers("factors", "2,4", "positive", lambda f: f > 0)


class Steps:
    """Training's progress on stderr, one step at a time: on a terminal one line rewritten in place; else
    (a pipe, a log, a CI job) a line per step with the seconds since the start, flushed as it comes,
    so that a minute of feature computation does not look like a hung command."""

    def __init__(self, start_s: float):
        self.start_s = start_s  # time.perf_counter() when training began
        self.tty = sys.stderr.isatty()

    def __call__(self, message: str) -> None:
        if self.tty:
            print(f"\r{message}\x1b[K", end="", file=sys.stderr, flush=True)
        else:
            print(f"evstream train: {time.perf_counter() - self.start_s:.0f} s: {message}", file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.tty:
            print(file=sys.stderr)


def cmd_train(args) -> int:
    from ..denoise.learned import train

    if not 0 < args.keep < 1:
        raise UsageError(f"--keep must be a fraction in (0, 1), got {args.keep}")
    if args.kind == "mlp" and not 1 <= args.hidden <= 64:
        raise UsageError(f"--hidden must be in 1..64, got {args.hidden}")
    if args.events_per_stream < 1000:
        raise UsageError(f"--events-per-stream must be >= 1000, got {args.events_per_stream}")
    from ..denoise.learned import FEATURES

    unknown = [f for f in args.without if f not in FEATURES]
    if unknown:
        raise UsageError(f"--without: unknown feature(s) {', '.join(unknown)}; the features: {', '.join(FEATURES)}")
    out = Path(args.out)
    for rec in args.recordings:
        not_the_input(rec, out, "--out ")
    if out.suffix != ".npz":
        raise UsageError(f"--out {out}: a model file ends in .npz")
    if file_in_the_way(out.parent):  # it exists, as a file: not "does not exist"
        raise not_a_folder(out.parent)
    if not out.parent.is_dir():
        raise UsageError(f"--out {out}: folder {out.parent} does not exist")
    t0 = time.perf_counter()
    say = None if args.quiet else Steps(t0)
    if say:
        say(f"reading {len(args.recordings)} recording(s)")
    recordings = read_recordings(args.recordings, args.min_duration_s, "evstream train", strict=True)
    if not recordings:
        raise UsageError("no recording to train on")
    sources = {Path(p).stem: p for p in args.recordings}
    if say:
        say(f"{len(recordings)} recording(s) read; features under {len(train.TRAIN_CONDITIONS)} noise conditions "
            f"each{' and thinned copy' if args.thin else ''}, then the fit")
    model = train.train(recordings, kind=args.kind, hidden=args.hidden, keep=args.keep, seed=args.seed,
                        per_stream=args.events_per_stream, sources=sources, thin=args.thin, time_scale=args.time_scale,
                        without=args.without, progress=say)
    if say:
        say.done()
    model.save(out)
    held = model.meta.get("held_out_keep_at_training_keep")
    print(f"wrote {out}: {model.meta['kind']} model on {len(recordings)} recording(s), "
          f"{model.meta['training_events']:,} events, training AUC {model.meta['training_auc']:.3f}, "
          f"threshold {model.threshold():.3f} for {100 * model.keep:.0f} % signal kept "
          f"({model.meta['calibration']}), {time.perf_counter() - t0:.0f} s")
    if held:
        print(f"  cross-fitted: a threshold fixed on training data for 85 % kept {100 * held['0.85']:.1f} % "
              f"on the recording left out (mean); the calibration corrects for that")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("train", help="fit the learned denoiser to your recordings (injected labelled noise)")
    p.add_argument("recordings", nargs="+", help="recordings whose events are signal (their hot pixels set aside)")
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="the model file to write")
    p.add_argument("--keep", type=float, default=0.85, help="signal fraction to keep by default (0.85)")
    p.add_argument("--kind", choices=("logistic", "mlp"), default="logistic", help="model (default logistic)")
    p.add_argument("--hidden", type=int, default=16, help="hidden units of the MLP")
    p.add_argument("--seed", type=int, default=0, help="noise and sampling seed")
    p.add_argument("--events-per-stream", type=int, default=20_000,
                   help="warm events sampled per recording and noise condition")
    p.add_argument("--thin", type=_fractions, default=(), metavar="F,F...",
                   help="calibrate the operating point on each recording's signal thinned at random to "
                        "these fractions too (e.g. 0.3,0.1,0.03: sparser scenes; the weights are fitted on "
                        "the recordings as they are; docs/learned.md)")
    p.add_argument("--time-scale", type=_scales, default=(), metavar="F,F...",
                   help="also fit the weights on each recording with its timestamps stretched by these factors "
                        "(e.g. 2: a scene twice as slow; docs/learned.md)")
    p.add_argument("--without", type=lambda t: [w for w in t.split(",") if w], default=[], metavar="F,F...",
                   help="features the score leaves out (docs/learned.md: the shipped model leaves out the DC ones)")
    p.add_argument("--min-duration-s", type=float, default=0.0, help="skip shorter recordings")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=cmd_train)


def cmd_calibrate(args) -> int:
    from ..denoise.learned import model as model_file
    from ..denoise.learned import train

    out = Path(args.out)
    for rec in args.recordings:
        not_the_input(rec, out, "--out ")
    not_the_input(args.model or model_file.DEFAULT_MODEL, out, "--out ", "the model being calibrated")
    if out.suffix != ".npz":
        raise UsageError(f"--out {out}: a model file ends in .npz")
    if file_in_the_way(out.parent):  # it exists, as a file: not "does not exist"
        raise not_a_folder(out.parent)
    if not out.parent.is_dir():
        raise UsageError(f"--out {out}: folder {out.parent} does not exist")
    model = model_file.load(args.model)
    recordings = read_recordings(args.recordings, 0.0, "evstream calibrate", strict=True)
    calibrated = train.calibrate_to(model, recordings)
    used = {n: v for n, v in calibrated.meta.get("calibrated_on", {}).items() if isinstance(v, dict)}
    if not used:
        raise UsageError("no recording long enough to calibrate on (each needs 2,000 events after "
                         "its first 256 ms)")
    calibrated.save(out)
    shares = ", ".join(f"{n} {100 * v['noise_share']:.0f} %" for n, v in used.items())
    print(f"wrote {out}: threshold {model.threshold():.3f} -> {calibrated.threshold():.3f} for "
          f"{100 * calibrated.keep:.0f} % signal kept, set on {len(used)} recording(s) without labels "
          f"(noise share estimated: {shares})")
    return 0


def add_calibrate_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="set a learned model's operating point on recordings of your sensor "
                                         "(no labels needed)")
    p.add_argument("recordings", nargs="+", help="recordings of the sensor and scenes the model will run on")
    p.add_argument("--model", default=None, metavar="MODEL.npz", help="the model to calibrate (default: the "
                                                                      "shipped one)")
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="the calibrated model file to write")
    p.set_defaults(func=cmd_calibrate)
