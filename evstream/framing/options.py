"""Command-line flags for framers (`--framer NAME` and one flag per parameter), shared by every command.

A parameter flag applies to the framers that have that parameter; naming one that none of the chosen
framers has is a usage error, as is a bad value (both exit 2).
"""

from __future__ import annotations

import dataclasses

from ..pipeline import build, kinds

# flag -> (parameter, type, help)
PARAM_FLAGS = {
    "--window-us": ("window_us", int, "frame length / slice length Δt, µs (fw, oa, adaptive; default 10000)"),
    "--stride-us": ("stride_us", int, "time between frame starts, µs (oa; default half the window)"),
    "--n-events": ("n_events", int, "events per frame (fn; default 8000)"),
    "--max-window-us": ("max_window_us", int, "close a frame this long after its first event (fn; default 1 s)"),
    "--n-base": ("n_base", int, "baseline events per slice N_base (adaptive; default 8000 for 346x260)"),
    "--k-us-per-event": ("k_us_per_event", float, "overlap step k, µs per event (adaptive; default 1)"),
    "--overlap-max-us": ("overlap_max_us", int, "largest overlap O_max, µs (adaptive; default half the window)"),
    "--window": ("window", str, "windows of a representation: fw, fn, oa or adaptive (default fw)"),
    "--tau-us": ("tau_us", float, "decay time constant τ, µs (timesurface; default 50000)"),
    "--bins": ("bins", int, "temporal bins B (voxel; default 5)"),
}


def add_framer_flags(p, *, default: str | None = "none", several: bool = False) -> None:
    """Add `--framer` (one kind, or a comma-separated list when `several`) and the parameter flags."""
    names = "fw|fn|oa|adaptive|timesurface|voxel|histogram|count|timestamp" + ("" if several else "|none")
    p.add_argument("--framer", metavar=names if not several else names + "[,...]", default=default,
                   help="framer: fixed window, fixed count, overlapping accumulation, the paper's adaptive "
                        "overlap, or a representation over one of those (--window)"
                        + (" (comma-separated to compare)" if several else "") + f"; default {default}")
    for flag, (_, typ, text) in PARAM_FLAGS.items():
        p.add_argument(flag, type=typ, default=None, help=text)
    p.add_argument("--all-events", action="store_true",
                   help="build frames from every event, not only those classed SIGNAL")


def framer_kinds(args) -> list[str]:
    """The framer kinds named by `--framer` (empty for none); raises ValueError for unknown ones."""
    spec = (getattr(args, "framer", None) or "none").strip()
    if spec == "none":
        return []
    names = [n.strip() for n in spec.split(",") if n.strip()]
    known = kinds("framer")
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise ValueError(f"--framer {spec}: unknown framer {', '.join(bad) or '(empty)'}; "
                         f"choose from {', '.join(known)} or none")
    return names


def framer_spec(kind: str, args) -> dict:
    """`{"kind": kind, **parameters given on the command line that this framer has}`."""
    fields = {f.name for f in dataclasses.fields(build("framer", {"kind": kind}))}
    spec = {"kind": kind}
    for _, (name, _, _) in PARAM_FLAGS.items():
        value = getattr(args, name, None)
        if value is not None and name in fields:
            spec[name] = value
    if getattr(args, "all_events", False):
        spec["all_events"] = True
    return spec


def framers_from_args(args) -> list:
    """Fresh framers for `--framer` and its parameter flags (ValueError on a bad combination)."""
    names = framer_kinds(args)
    used = set()
    specs = []
    for kind in names:
        spec = framer_spec(kind, args)
        used |= set(spec)
        specs.append(spec)
    given = [flag for flag, (name, _, _) in PARAM_FLAGS.items() if getattr(args, name, None) is not None]
    unused = [flag for flag in given if PARAM_FLAGS[flag][0] not in used]
    if unused:
        raise ValueError(f"{', '.join(unused)} does not apply to --framer {','.join(names) or 'none'}")
    return [build("framer", spec) for spec in specs]
