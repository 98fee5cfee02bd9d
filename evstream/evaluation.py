"""Labelled evaluation of denoisers: inject noise with exact labels, run every method, score honestly.

Protocol (docs/evaluation.md):
- the recording's own events are the signal (synthetic recordings: their SIGNAL-labelled events);
  a real recording's own hot pixels are detected and **set aside** (removed) first, so no method is
  charged for finding them or credited for keeping them;
- noise: the paper's ratios (noise events / signal events, 10 % of the noise from hot pixels at
  50–2000 Hz) and fixed physical background rates (Hz per pixel, as DND21), over several seeds;
- each method classifies the noisy stream in one pass and scores every event (higher = more
  signal-like); metrics are taken on warm state only (after each method's history, at most 30 % of
  the recording);
- EDP never stands alone: it is shown beside the signal kept (TPR); methods are ranked by EDP at
  matched signal kept (the highest score threshold keeping ≥ 80 % / 90 % of the signal) and by AUC;
- `tune`: the threshold reaching 80 % signal kept is chosen on the first half of each stream and the
  metrics are reported on the second half.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from . import metrics
from .events import EventChunk, NoiseClass
from .noise import Condition, NoiseSpec, as_signal, find_hot_pixels, inject  # noqa: F401 - re-exported
from .pipeline import build

RATIOS = (0.1, 0.2, 0.5, 1.0, 1.5, 2.0)
RATES_HZ = (1.0, 3.0, 5.0)
TPR_TARGETS = (0.8, 0.9)
WARMUP_CAP = 0.3  # never skip more than this fraction of a recording as warm-up


def default_conditions() -> list[Condition]:
    return [Condition(noise_ratio=r) for r in RATIOS] + [Condition(ba_rate_hz=r) for r in RATES_HZ]


def _stage(kind: str, **params):
    return lambda: build("stage", {"kind": kind, **params})


# name -> factory of a fresh stage. Each has `classify_scored(chunk) -> (codes, scores)`.
METHODS: dict[str, Callable[[], object]] = {
    "paper": _stage("paper"),
    "paper-abs": _stage("paper", coarse={"mode": "absolute"}),
    "baf": _stage("baf"),
    "stcf": _stage("stcf"),
    "khodamoradi": _stage("khodamoradi"),
    "ynoise": _stage("ynoise"),
    "dwf": _stage("dwf"),
    "refractory": _stage("refractory"),
    "hotpixel": _stage("hotpixel"),
}
RULE_BASED = tuple(METHODS)  # every method above is a hand-designed rule (no learned model)
# Trained methods: scored leave-one-recording-out — the model for recording R is trained on the other
# recordings given (noise seeds from train.SEED_BASE, never the evaluation's), never on R itself.
TRAINED = ("learned",)
METHODS["learned"] = None  # built per recording by `loo_models`
MODEL_PREFIX = "model:"  # a user's model file, the same on every recording (`eval --model FILE`)
LOO_EVENTS_PER_STREAM = 8_000


def loo_models(recordings: dict[str, EventChunk], progress: Callable[[str], None] | None = None) -> dict:
    """{recording: the learned model fitted on all the other recordings} (leave-one-recording-out).
    Each recording's training features are computed once and shared by the folds."""
    from .denoise.learned import train

    signals = {name: ev for name, ev in recordings.items() if len(as_signal(ev)[0]) >= 100}
    S = train.samples(signals, per_stream=LOO_EVENTS_PER_STREAM, progress=progress)
    models = {}
    for gi, name in enumerate(S.names):
        if progress:
            progress(f"learned: fitting without {name}")
        models[name] = train.fit(S.subset(S.group != gi))
        models[name].meta["name"] = f"trained without {name}"
    return models


def user_models(files: Iterable[str], paths: Iterable[str]) -> dict:
    """{"model:STEM": Model} of the user's model files (`eval --model`), for `run(fixed=)`. A model scored
    on a recording it was trained on (the same bytes: its file keeps each training recording's SHA-256)
    would say nothing about new data: a ValueError naming both."""
    from .denoise.learned import load, train

    hashes = {p: train.sha256(p) for p in paths if Path(p).is_file()}
    fixed = {}
    for file in files:
        model = load(file)
        trained = {r.get("sha256") for r in model.meta.get("trained_on", []) if isinstance(r, dict)}
        for path, digest in hashes.items():
            if digest in trained:
                raise ValueError(f"--model {file} was trained on {path}: score it on recordings it never saw")
        fixed[f"{MODEL_PREFIX}{Path(file).stem}"] = model
    return fixed


def history_us(stage) -> int:
    """How long a method needs before its decisions are at full strength."""
    h = getattr(stage, "history_us", None)
    if h is not None:
        return int(h)
    params = stage.params() if hasattr(stage, "params") else {}
    windows = [int(v) for k, v in params.items() if k.endswith("_us") and isinstance(v, (int, float))]
    return max(windows, default=0)


# -- running ------------------------------------------------------------------------------------------
def _metrics_at(label: np.ndarray, keep: np.ndarray, score: np.ndarray) -> dict:
    s = metrics.summary(label, keep)
    out = {"edp": s["edp"], "esnr": s["esnr_db"], "tpr": s["tpr"], "fpr": s["fpr"],
           "background_removed": s["removed_background"],
           "hot_pixel_removed": s["removed_hot_pixel"],
           "auc": metrics.roc_auc(label, score)}
    for target in TPR_TARGETS:
        out[f"edp_at_tpr{round(100 * target)}"] = metrics.edp_at_tpr(label, score, target)
    return out


def evaluate(recording: str, signal: EventChunk, condition: Condition, seed: int,
             methods: Iterable[str], tune: bool = False, curves: dict | None = None,
             models: dict | None = None, fixed: dict | None = None) -> list[dict]:
    """One noisy stream, every method: a result row per method. With `curves`, each method's ROC
    (downsampled to 200 points) is stored there under (recording, condition name, method). Trained
    methods take their model from `models[recording]` (one that never saw this recording); a method named
    "model:NAME" takes `fixed[name]`, a model file the user gives (`eval --model`)."""
    noisy = inject(signal, condition.spec(), seed=seed, t_start_us=int(signal.t[0]),
                   t_stop_us=int(signal.t[-1]) + 1)
    label = noisy.label
    t0, t1 = int(noisy.t[0]), int(noisy.t[-1])
    rows = []
    for name in methods:
        if name in TRAINED or name.startswith(MODEL_PREFIX):
            from .denoise.learned import LearnedFilter

            stage = LearnedFilter(model=models[recording] if name in TRAINED else fixed[name])
        else:
            stage = METHODS[name]()
        codes, score = stage.classify_scored(noisy.replace(label=None))
        keep = codes == NoiseClass.SIGNAL
        warm_from = t0 + min(history_us(stage), int(WARMUP_CAP * (t1 - t0)))
        warm = noisy.t >= warm_from
        row = {"recording": recording, "method": name, "condition": condition.name,
               "noise_ratio": condition.noise_ratio, "ba_rate_hz": condition.ba_rate_hz, "seed": seed,
               "events": int(warm.sum()), "warmup_us": warm_from - t0}
        row.update(_metrics_at(label[warm], keep[warm], score[warm]))
        if curves is not None:
            f, t, _ = metrics.roc_curve(label[warm], score[warm])
            pick = np.unique(np.linspace(0, len(f) - 1, min(len(f), 200)).astype(int))
            curves[(recording, condition.name, name)] = (f[pick], t[pick])
        if tune:
            row.update(_tuned(noisy.t, label, score, warm, (t0 + t1) // 2))
        rows.append(row)
    return rows


def _tuned(t, label, score, warm, t_split) -> dict:
    """Threshold for 80 % signal kept chosen on the first half, metrics reported on the second."""
    first, second = warm & (t < t_split), t >= t_split
    thr = metrics.operating_point(label[first], score[first], TPR_TARGETS[0])["threshold"]
    if math.isnan(thr):
        return {"tuned_edp": math.nan, "tuned_tpr": math.nan, "tuned_esnr": math.nan}
    s = metrics.summary(label[second], score[second] >= thr)
    return {"tuned_edp": s["edp"], "tuned_tpr": s["tpr"], "tuned_esnr": s["esnr_db"]}


def run(recordings: dict[str, EventChunk], conditions: Iterable[Condition], seeds: Iterable[int],
        methods: Iterable[str], tune: bool = False, progress: Callable[[int, int, str], None] | None = None,
        curves: dict | None = None, fixed: dict | None = None) -> list[dict]:
    """Every recording × condition × seed × method; rows as `evaluate` returns them. ROC curves of the
    first seed go into `curves` when given. `progress(done, total, what)` is called before each
    recording × condition × seed (and once at the end, done == total). `fixed`: {"model:NAME": Model},
    the user's model files, scored as they are on every recording (the caller makes sure none was trained
    on them)."""
    methods, seeds, conditions = list(methods), list(seeds), list(conditions)
    methods += [m for m in (fixed or {}) if m not in methods]
    unknown = set(methods) - set(METHODS) - set(fixed or {})
    if unknown:
        raise ValueError(f"unknown method(s) {sorted(unknown)}; known: {', '.join(METHODS)}")
    models = None
    if any(m in TRAINED for m in methods):
        if len(recordings) < 2:  # nothing to train on that is not the recording itself
            methods = [m for m in methods if m not in TRAINED]
        else:
            models = loo_models(recordings, (lambda what: progress(0, 1, what)) if progress else None)
    rows = []
    per_recording = len(conditions) * len(seeds)
    total, done = len(recordings) * per_recording, 0
    for rec, events in recordings.items():
        signal, notes = as_signal(events)
        if len(signal) < 100:
            done += per_recording
            continue
        for cond in conditions:
            for seed in seeds:
                if progress:
                    progress(done, total, f"{rec} {cond.name} seed {seed}")
                done += 1
                keep_curves = curves if seed == seeds[0] else None
                for row in evaluate(rec, signal, cond, seed, methods, tune, keep_curves, models, fixed):
                    rows.append({**row, **notes})
    if progress:
        progress(total, total, "")
    return rows


# -- reporting ----------------------------------------------------------------------------------------
def mean_over_seeds(rows: list[dict]) -> list[dict]:
    """Rows averaged over seeds (numeric fields), keyed by recording, method and condition."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["recording"], r["method"], r["condition"]), []).append(r)
    out = []
    for rs in groups.values():
        m = dict(rs[0])
        for k, v in rs[0].items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and v is not None and k != "seed":
                vals = np.array([r[k] for r in rs], np.float64)
                m[k] = float(np.mean(vals))
                if k in ("edp", "tpr", "auc", "edp_at_tpr80"):
                    m[k + "_std"] = float(np.std(vals))
        m["seeds"] = len(rs)
        m.pop("seed", None)
        out.append(m)
    return out


def table(rows: list[dict], recording: str, cell: Callable[[dict], str], title: str) -> str:
    """The paper's layout: rows = methods, columns = noise conditions."""
    rs = [r for r in rows if r["recording"] == recording]
    conds = list(dict.fromkeys(r["condition"] for r in rs))
    methods = list(dict.fromkeys(r["method"] for r in rs))
    by = {(r["method"], r["condition"]): r for r in rs}
    width = max(11, *(len(cell(r)) for r in rs)) if rs else 11
    name = max(12, *(len(m) + 1 for m in methods)) if methods else 12  # a user's model:NAME can be longer
    lines = [f"{title} — {recording}", f"{'method':<{name}}" + "".join(f"{c:>{width + 1}}" for c in conds)]
    for m in methods:
        lines.append(f"{m:<{name}}" + "".join(f"{cell(by[(m, c)]) if (m, c) in by else '-':>{width + 1}}"
                                          for c in conds))
    return "\n".join(lines)


def fmt(v: float, digits: int = 1) -> str:
    return "nan" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


TABLES = {
    "EDP % / signal kept %": lambda r: f"{fmt(r['edp'])}/{fmt(100 * r['tpr'], 0)}",
    "ESNR dB / signal kept %": lambda r: f"{fmt(r['esnr'])}/{fmt(100 * r['tpr'], 0)}",
    "EDP % at signal kept >= 80 % / >= 90 %": lambda r: f"{fmt(r['edp_at_tpr80'])}/{fmt(r['edp_at_tpr90'])}",
    "ROC AUC": lambda r: fmt(r["auc"], 3),
}


def report(rows: list[dict], tune: bool = False) -> str:
    """Every table for every recording, then the mean over recordings."""
    mean = mean_over_seeds(rows)
    recs = list(dict.fromkeys(r["recording"] for r in mean))
    tables = dict(TABLES)
    if tune:
        tables["tuned on 1st half -> 2nd half: EDP % / signal kept %"] = (
            lambda r: f"{fmt(r['tuned_edp'])}/{fmt(100 * r['tuned_tpr'], 0)}")
    overall = _mean_over_recordings(mean) if len(recs) > 1 else []
    parts = []
    if any(r["method"] in TRAINED for r in mean):
        parts.append(f"learned: scored leave-one-recording-out — on each recording, a model trained on the other "
                     f"{len(recs) - 1} only (never on the recording it is scored on)")
    for rec in recs + (["all recordings (mean)"] if overall else []):
        rs = overall if rec == "all recordings (mean)" else mean
        for title, cell in tables.items():
            parts.append(table(rs, rec, cell, title))
    return "\n\n".join(parts)


MARKDOWN_TABLES = {  # title -> (cell values, digits, which values to bold where best); `eval --markdown`
    "EDP % at matched signal kept, ≥ 80 % / ≥ 90 % (the ranking measure)":
        (lambda r: (r["edp_at_tpr80"], r["edp_at_tpr90"]), 1, (0, 1)),
    "ROC AUC": (lambda r: (r["auc"],), 3, (0,)),
    "At the default operating point, no tuning — EDP % / signal kept %":
        (lambda r: (r["edp"], 100 * r["tpr"]), 1, (0,)),
}
TUNED_TABLE = ("Tuned on the first half, reported on the second — EDP % / signal kept %",
               (lambda r: (r["tuned_edp"], 100 * r["tuned_tpr"]), 1, (0,)))


def markdown(rows: list[dict], tune: bool = False) -> str:
    """The mean over recordings (and seeds) as Markdown tables, the best of each column in bold: what
    docs/evaluation.md shows, regenerated by `evstream eval ... --markdown` (docs/generated.py)."""
    mean = mean_over_seeds(rows)
    recs = list(dict.fromkeys(r["recording"] for r in mean))
    rs = _mean_over_recordings(mean) if len(recs) > 1 else mean
    conds = list(dict.fromkeys(r["condition"] for r in rs))
    methods = list(dict.fromkeys(r["method"] for r in rs))
    by = {(r["method"], r["condition"]): r for r in rs}
    tables = dict(MARKDOWN_TABLES)
    if tune:
        tables[TUNED_TABLE[0]] = TUNED_TABLE[1]
    parts = [f"Mean over {len(recs)} recording{'s' if len(recs) > 1 else ''} ({', '.join(recs)}), "
             f"{max(r['seeds'] for r in mean)} seed(s) per condition."]
    if any(r["method"] in TRAINED for r in mean):
        parts[0] += (" learned: scored leave-one-recording-out (on each recording, a model trained on the other "
                     f"{len(recs) - 1} only).")
    for title, (values, digits, bold) in tables.items():
        text = {k: [fmt(v, digits) for v in values(r)] for k, r in by.items()}
        best = {}
        for c in conds:  # the best printed value of each column (and of each half of a pair)
            cells = [text[(m, c)] for m in methods if (m, c) in text]
            best[c] = [max((float(v[i]) for v in cells if v[i] != "nan"), default=None) for i in range(len(cells[0]))]
        lines = [f"{title}:", "", "| method | " + " | ".join(conds) + " |", "|---" * (len(conds) + 1) + "|"]
        for m in methods:
            row = []
            for c in conds:
                if (m, c) not in text:
                    row.append("-")
                    continue
                row.append("/".join(f"**{v}**" if i in bold and v != "nan" and float(v) == best[c][i] else v
                                    for i, v in enumerate(text[(m, c)])))
            lines.append(f"| {m} | " + " | ".join(row) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


def _mean_over_recordings(mean_rows: list[dict]) -> list[dict]:
    groups: dict[tuple, list[dict]] = {}
    for r in mean_rows:
        groups.setdefault((r["method"], r["condition"]), []).append(r)
    out = []
    for (method, cond), rs in groups.items():
        m = {"recording": "all recordings (mean)", "method": method, "condition": cond}
        for k in ("edp", "esnr", "tpr", "fpr", "auc", "edp_at_tpr80", "edp_at_tpr90", "tuned_edp", "tuned_tpr"):
            vals = [r[k] for r in rs if k in r and r[k] is not None and not math.isnan(r[k]) and not math.isinf(r[k])]
            m[k] = float(np.mean(vals)) if vals else math.nan
        out.append(m)
    return out


def ranking(rows: list[dict], min_ratio: float = 0.5) -> dict[str, dict[str, float]]:
    """Mean over recordings, seeds and conditions with noise ratio >= `min_ratio` of EDP at matched
    signal kept and of AUC, per method (for the headline and docs/evaluation.md)."""
    out: dict[str, dict[str, list]] = {}
    for r in rows:
        if r["noise_ratio"] is None or r["noise_ratio"] < min_ratio:
            continue
        d = out.setdefault(r["method"], {"edp_at_tpr80": [], "edp_at_tpr90": [], "auc": []})
        for k in d:
            if not math.isnan(r[k]):
                d[k].append(r[k])
    return {m: {k: float(np.mean(v)) if v else math.nan for k, v in d.items()} for m, d in out.items()}


def check_can_plot(what: str) -> None:
    """An OSError naming `what` when matplotlib (an optional dependency: `pip install evstream[eval]`) is
    not installed."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise OSError(f"{what}: the ROC plot needs matplotlib, which is not installed (pip install matplotlib; "
                      "or leave out --roc)") from None


def plot_roc(curves: dict, condition: str, path) -> None:
    """One panel per recording: every method's ROC at one noise condition, to a PNG (matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recs = list(dict.fromkeys(k[0] for k in curves if k[1] == condition))
    if not recs:
        raise ValueError(f"no ROC curves for condition {condition!r}")
    cols = min(3, len(recs))
    rows = math.ceil(len(recs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4 * rows), squeeze=False)
    for ax, rec in zip(axes.flat, recs):
        for (r, c, method), (f, t) in curves.items():
            if r == rec and c == condition:
                ax.plot(f, t, label=method, lw=2.2 if method.startswith("paper") else 1.2)
        ax.set_xscale("log")  # the interesting part: little noise kept
        ax.set(title=f"{rec} — noise {condition}", xlabel="noise kept (FPR, log)", ylabel="signal kept (TPR)",
               xlim=(1e-4, 1), ylim=(0, 1))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(recs):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    from .safe_write import AtomicOutput

    try:
        with AtomicOutput(path) as part:  # never in place; the format from the target's name, not the temporary's
            fig.savefig(part, dpi=90, format=Path(os.fspath(path)).suffix.lstrip(".").lower() or "png")
    finally:
        plt.close(fig)


def as_json_rows(rows: list[dict]) -> list[dict]:
    """JSON-safe rows (NaN and inf as null)."""
    def clean(v):
        if isinstance(v, float) and (math.isnan(v) or math.isinf(v)):
            return None
        return v
    return [{k: clean(v) for k, v in r.items()} for r in rows]


__all__ = ["Condition", "METHODS", "as_signal", "default_conditions", "evaluate", "find_hot_pixels",
           "markdown", "report", "run"]
