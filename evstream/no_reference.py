"""Denoisers on real noise without labels: MESR (E-MLB, Ding et al., IEEE TMM 2024), honestly compared.

Per recording and method, the method classifies the recording's own events (no noise injected) and
the kept events are cut into packets of N = 30,000; per packet NTSS = Σ n_p(n_p − 1)/(N(N − 1)) (events
piling on few pixels: edges) and L_N = Σ (1 − 3^(−n_p)) over the pixels (the area the packet covers),
ESR = sqrt(NTSS·L_N), MESR the mean over packets (`metrics.esr_parts`).

MESR moves when events are merely deleted at random (a packet of fixed N then spans more time: E-MLB
notes it rising; on our DVS128 recordings it falls), so a method is compared with a seeded **random
subsample of the raw stream at the same kept fraction**: it must beat that, not the raw stream. NTSS and L_N are
reported apart, with the kept fraction.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numpy as np

from .events import EventChunk, NoiseClass
from .metrics import esr_parts

PACKET_EVENTS = 30_000


def mesr_parts(events: EventChunk, packet_events: int = PACKET_EVENTS) -> dict:
    """Mean NTSS, L_N and ESR over full packets of `packet_events` (NaN without one full packet)."""
    k = len(events) // packet_events
    if k == 0:
        return {"mesr": math.nan, "ntss": math.nan, "l_n": math.nan, "packets": 0}
    parts = np.array([esr_parts(events.x[i * packet_events:(i + 1) * packet_events],
                                events.y[i * packet_events:(i + 1) * packet_events], events.geometry)
                      for i in range(k)])
    return {"mesr": float(parts[:, 2].mean()), "ntss": float(parts[:, 0].mean()), "l_n": float(parts[:, 1].mean()),
            "packets": k}


def evaluate(recording: str, events: EventChunk, methods: dict[str, Callable[[], object]], seed: int = 0,
             packet_events: int = PACKET_EVENTS) -> list[dict]:
    """A row per method (and one for the raw stream): kept fraction, MESR, NTSS, L_N, and the MESR of a
    random subsample of the raw stream keeping the same fraction."""
    events = events.replace(label=None, cls=None)
    raw = mesr_parts(events, packet_events)
    rows = [{"recording": recording, "method": "raw", "kept": 1.0, **raw, "random_mesr": raw["mesr"]}]
    rng = np.random.default_rng(seed)
    u = rng.random(len(events))  # one draw per event: the random subsamples of every fraction are nested
    for name, make in methods.items():
        stage = make()
        kept = stage(events).cls == NoiseClass.SIGNAL
        frac = float(kept.mean()) if len(kept) else math.nan
        ours = mesr_parts(events[kept], packet_events)
        rand = mesr_parts(events[u < frac], packet_events)
        rows.append({"recording": recording, "method": name, "kept": frac, **ours, "random_mesr": rand["mesr"]})
    return rows


def run(recordings: dict[str, EventChunk], methods: dict[str, Callable[[], object]],
        progress: Callable[[str], None] | None = None) -> list[dict]:
    rows = []
    for name, events in recordings.items():
        if progress:
            progress(name)
        rows.extend(evaluate(name, events, methods))
    return rows


def report(rows: Iterable[dict]) -> str:
    """One table per recording: method, kept %, MESR, MESR of a random subsample at the same kept
    fraction, the difference, NTSS and L_N."""
    rows = list(rows)
    out = []
    for rec in dict.fromkeys(r["recording"] for r in rows):
        out.append(f"no reference (MESR, packets of {PACKET_EVENTS:,} events) — {rec}")
        out.append(f"{'method':<12}{'kept %':>8}{'MESR':>9}{'random':>9}{'gain':>8}{'NTSS':>10}{'L_N':>9}")
        for r in rows:
            if r["recording"] != rec:
                continue
            gain = r["mesr"] - r["random_mesr"]
            out.append(f"{r['method']:<12}{100 * r['kept']:>8.1f}{_f(r['mesr'], 3):>9}{_f(r['random_mesr'], 3):>9}"
                       f"{_f(gain, 3, True):>8}{_f(r['ntss'] * 1e4, 2):>10}{_f(r['l_n'], 0):>9}")
        out.append("")
    out.append("random: MESR of a random subsample of the raw stream keeping the same fraction (the bar to "
               "beat); gain = MESR − random; NTSS × 1e4; nan: fewer kept events than one packet")
    return "\n".join(out)


def _f(v: float, digits: int, sign: bool = False) -> str:
    if v is None or math.isnan(v):
        return "nan"
    return f"{v:+.{digits}f}" if sign else f"{v:.{digits}f}"
