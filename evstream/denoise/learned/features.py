"""Causal per-event features for the learned denoiser, and the fused kernel that scores them.

For event m at (x, y, t, p), from the events before it only (FEATURES, version FEATURE_VERSION):

- counts in the 20 ms window (exact, as the density filter keeps them): N, the events in the 5×5 box
  around m (its own pixel included), N_same the same-polarity ones, and the pixel's own count —
  each as log1p (a lookup table: counts are small integers);
- two references for "how busy is the sensor": the events of the whole sensor in the window, scaled
  to one 5×5 box, log((g + 1) · 25 / (W·H)), and the same for m's 16×16 block — so that a score can
  compare the local count with what background alone would give, whatever the noise rate and the
  sensor size (counts above 65535 are looked up at 1/64 resolution: 0.1 % error);
- neighbour support from the last event of each of the 8 neighbours, its time in ticks of 16 µs: the
  fraction that fired within 125 ticks (2 ms, any polarity), within 625 and 3125 ticks (10 and 50 ms,
  same polarity) — ages in whole ticks, ⌊t/16⌋ − ⌊t_q/16⌋;
- log1p of the time since the pixel's own last event, in ms (quantised to 4 ticks, capped at 262 ms);
- the paper's DC components (Jiang et al., the fine stage, evstream/denoise/timeseries.py): over the
  last 64 activity bins of 4 ms (bins anchored at t = 0, the current one included), the fraction a
  pixel was active in — DC_own for m's pixel, DC_nb the mean over its 8 neighbours (off-sensor
  neighbours count as never active). A hot pixel is active in nearly every bin, its neighbours not.

State, all bounded (O(W·H + events per 20 ms)): one int64 word per pixel (last tick and polarity,
last active DC bin, its events and ON events in the last 20 ms) and one int64 bitmap of its active bins
(bit k: active in the bin k before its last), read for the pixel, its 8 neighbours and its 5×5 box in
one vector pass (neighbours.py); block counts; and the FIFO of the window's events, one ring of (time,
entry) pairs. The DC components need no FIFO: a bitmap shifted by the bins elapsed drops the old bins.

After the model, two rules (a linear score cannot express either) make an event a HOT_PIXEL (score
HOT_SCORE): its pixel fired `hot_min` (4) times or more in the last 20 ms and more than a third of its
5×5 box's events; or DC_own − DC_nb > `dc_lam` (0.2), the paper's fine-stage test. Leave-one-recording-out
(docs/learned.md) the first rule alone missed hot pixels beside another hot pixel (the pair fills the
box count); the DC rule catches them.

One kernel is compiled per configuration (hidden units 0 = logistic score, else a one-hidden-layer
ReLU MLP; scores, feature rows, whether earlier stages rejected events): no option costs anything per
event. The features are standardised by folding the training mean and std into the first layer.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ...jit import njit
from ...nowrap import ix
from ..prefetch import prefetch
from .neighbours import BIN_SHIFT, COUNT_SHIFT, SUPPORT_TICKS, TICK_MASK, WORD_TAIL, nb8_support

FEATURE_VERSION = 2
FEATURES = (
    "log1p_n_5x5_20ms", "log1p_n_same_5x5_20ms", "log1p_own_20ms", "log_ref_global", "log_ref_block",
    "nb8_any_2ms", "nb8_same_10ms", "nb8_same_50ms", "log1p_age_ms", "dc_own", "dc_nb8",
)
N_FEATURES = len(FEATURES)
RADIUS_PX = 2          # the 5×5 box
WINDOW_US = 20_000     # the counts' window
BLOCK_PX = 16          # the block reference
TICK_US = 16           # the last-event map's time unit: neighbour ages in whole ticks
BIN_US = 4_000         # DC: activity bins of 4 ms (the paper's fs = 250 Hz) ...
N_BINS = 64            # ... 64 of them (256 ms)
HISTORY_US = N_BINS * BIN_US  # the longest time a feature looks back
AGE_SHIFT = 2          # age quantised to 4 ticks = 64 µs
AGE_CELLS = 4096       # ... up to 4096 · 64 µs = 262 ms
LOG_CELLS = 1 << 16    # log1p table for counts
FAR_TICKS = 1 << 20    # "never" and anything older: far past every window and cap
REBASE_TICKS = 1 << 23  # the 23-bit tick field is rebased (an O(W·H) pass) once every ~2 min of stream
PREFETCH_EVENTS = 4    # each event asks for the word and bitmap rows of the event this far ahead
HOT_SCORE = -1e9       # the score of an event a hot-pixel rule rejects
DC_MARGIN = 51         # the DC rule: 8 · DC_own - Σ DC_nb > 51 bins, i.e. DC_own - mean DC_nb > 0.1

LARGE_SHIFT = 6
LOG_LARGE = math.log(1 << LARGE_SHIFT)
LOG1P = np.log1p(np.arange(LOG_CELLS, dtype=np.float64))
AGE_LOG1P_MS = np.log1p(np.arange(AGE_CELLS, dtype=np.float64) * (TICK_US << AGE_SHIFT) / 1000.0)
TABLES = np.concatenate([LOG1P, AGE_LOG1P_MS])  # one array for the kernel: age cell k at LOG_CELLS + k

# One int64 word per pixel (padded by RADIUS_PX on each side, and WORD_TAIL words at the end) holds
# everything read about a pixel, so that the 8 neighbours and the 5×5 box cost one vector read per row:
# bits 0-23 (tick << 1) | polarity of its last event, the tick counted from `base` (0 = never); 24-31
# its last active DC bin modulo 256 (with `bins`, its bitmap, this gives its DC component:
# neighbours.py); 32-47 its events in the last 20 ms; 48-63 the ON ones among them.
OWN_ONE = 1 << COUNT_SHIFT
ON_ONE = 1 << (COUNT_SHIFT + 16)


def block_log_scale(width: int, height: int) -> np.ndarray:
    """Per 16×16 block: log(25 / block area in pixels), blocks at the right/bottom edge being smaller."""
    bw, bh = -(-width // BLOCK_PX), -(-height // BLOCK_PX)
    cols = np.minimum(BLOCK_PX, width - BLOCK_PX * np.arange(bw))
    rows = np.minimum(BLOCK_PX, height - BLOCK_PX * np.arange(bh))
    return np.log(25.0 / np.outer(rows, cols).astype(np.float64)).reshape(-1)


def _placed(like: np.ndarray, offset_bytes: int) -> np.ndarray:
    """A zeroed copy of `like` starting `offset_bytes` past a 4 KiB boundary. Why: large arrays come
    page-aligned from the allocator, so the maps' cells of one pixel would share their address bits
    0-11, and a load after a store to another map at the same bits waits for it (4K aliasing, in the
    CPU's store-to-load forwarding): placed 1 KiB apart, the kernel measured ~1 ns/event (3 %) faster."""
    buf = np.zeros(like.nbytes + 4096 + offset_bytes, np.uint8)
    start = (-buf.ctypes.data) % 4096 + offset_bytes
    return buf[start : start + like.nbytes].view(like.dtype).reshape(like.shape)


def new_state(width: int, height: int) -> dict:
    """Fresh state for a width × height sensor."""
    r = RADIUS_PX
    wp = width + 2 * r
    cap = 1 << 12
    return {
        "width_padded": wp,
        "word": _placed(np.empty((height + 2 * r) * wp + WORD_TAIL, np.int64), 0),
        "block": np.zeros(-(-width // BLOCK_PX) * -(-height // BLOCK_PX), np.int32),
        "block_log_scale": block_log_scale(width, height),
        # the 20 ms window's events, (time, map index | polarity << 32 | block << 33) each
        "fifo": _placed(np.empty(2 * cap, np.int64), 3072),
        "fifo_state": np.zeros(2, np.int64),  # head, size (in pairs)
        # per pixel: its active DC bins, a bitmap
        "bins": _placed(np.empty((height + 2 * r) * wp, np.int64), 1024),
        "clock": np.array([0, 0, 0], np.int64),  # tick base, current DC bin, 1 once started
    }


@njit(cache=True, nogil=True, inline="always")
def _log1p_count(table, c):
    """log1p(c) of a count by table, exact below LOG_CELLS, then to 0.1 % (c >> 6, + log 64), capped at
    2^22. No call to log1p: LLVM would evaluate it speculatively on every event (measured 5× slower)."""
    if c < LOG_CELLS:
        return table[ix(c)]
    return table[ix(min(c >> LARGE_SHIFT, LOG_CELLS - 1))] + LOG_LARGE


@njit(cache=True, nogil=True)
def _rebase(word, shift):
    """Move the tick origin `shift` ticks later: every pixel's last tick drops by `shift`, clamped at 0
    (never), which changes no feature: such a pixel's age was >= FAR_TICKS before and after."""
    for k in range(len(word)):
        w = word[k]
        tf = w & TICK_MASK
        tick = max((tf >> 1) - shift, 0)
        word[k] = (w - tf) | (tick << 1) | (tf & 1)


@njit(cache=True, nogil=True, inline="always")
def _counted(nb):
    """The features counted by the neighbour pass (its packed result): support within 2, 10, 50 ms,
    DC_own, DC_nb."""
    return ((nb & 0xFFF) * 0.125, ((nb >> 12) & 0xFFF) * 0.125, ((nb >> 24) & 0xFFF) * 0.125,
            (nb >> 48) * (1.0 / N_BINS), ((nb >> 36) & 0xFFF) * (1.0 / (8 * N_BINS)))


@njit(cache=True, nogil=True, inline="always")
def _hot(own_c, n_all, nb, hot_min, dc_margin):
    """The hot-pixel rules (a linear score cannot express them): the pixel fired hot_min times or more
    in 20 ms and more than a third of its box's events; or its DC exceeds its neighbours' mean by more
    than dc_margin / 512."""
    return ((own_c >= hot_min) & (3 * own_c > n_all)) | (8 * (nb >> 48) - ((nb >> 36) & 0xFFF) > dc_margin)


BATCH = 120  # an MLP's events per scoring pass (their features, 11 × 120 float64, stay in the L1 cache)


@functools.cache
def feature_kernel(n_hidden: int, want_score: bool, want_features: bool, all_live: bool):
    """The kernel for one configuration: `n_hidden` 0 scores with a logistic model (w1[0], b1[0]),
    else with a ReLU layer of `n_hidden` units (w1, b1) and an output layer (w2, b2). The features are
    scalars (registers), the 8 neighbours and the 5×5 box one vector pass (neighbours.py), the FIFO
    stores each event's block and polarity with its map index (no division on expiry; an expiry
    updates one word and one block count). Each event prefetches the word and bitmap rows of the event
    PREFETCH_EVENTS ahead: the two maps miss the L2 cache.

    A logistic score is computed event by event. An MLP's is not: the events of a batch (BATCH) keep
    their features in a matrix (feature × event), and a scoring pass after the batch runs along it one
    hidden unit at a time, loops with no table lookups or dependences between events that LLVM
    vectorises (measured 1.6-1.9× faster for 8 and 16 units; for the logistic score the same pass
    was 6 % slower than scoring in place)."""
    R = RADIUS_PX
    batch = BATCH if n_hidden else 1 << 62  # (a logistic score needs no batches)

    @njit(cache=True, nogil=True, fastmath=True)
    def kernel(t, x, y, p, start, codes, threshold, hot_min, dc_margin, word, block, blog, wp,
               fifo, fifo_state, bins, clock, width, height,
               w1, b1, w2, b2, out_score, out_feat, tables):
        """Score events `start..` whose code is SIGNAL: BACKGROUND below `threshold`, HOT_PIXEL by either
        hot-pixel rule (module docstring). Returns the index reached: len(t) unless a FIFO is full (the
        caller grows it and calls again from there)."""
        cap = len(fifo) >> 1
        mask = cap - 1
        head = fifo_state[0]
        size = fifo_state[1]
        base = clock[0]
        b = clock[1]
        started = clock[2]
        bin_start = b * BIN_US
        bw = (width + 15) // 16
        log_global_scale = math.log(25.0 / (width * height))
        # an MLP's batch: the features (one row each), the neighbour passes, box | own counts, scores
        m_max = BATCH if n_hidden else 0
        feat = np.empty((N_FEATURES, m_max), np.float64)
        nbs = np.empty(m_max, np.int64)
        counts = np.empty(m_max, np.int64)
        score = np.empty(m_max, np.float64)
        hidden = np.empty(m_max, np.float64)
        # a logistic model's weights as scalars: no array pointers held across the loop
        c0, c1, c2, c3, c4, c5 = w1[0, 0], w1[0, 1], w1[0, 2], w1[0, 3], w1[0, 4], w1[0, 5]
        c6, c7, c8, c9, c10, c_bias = w1[0, 6], w1[0, 7], w1[0, 8], w1[0, 9], w1[0, 10], b1[0]
        n = len(t)
        i = start
        while i < n:
            stop = min(n, i + cap - size, i + batch)  # each event pushes at most one: no full-FIFO test inside
            if stop == i:
                break
            first = i
            while i < stop:
                if not all_live and codes[ix(i)] != 0:
                    i += 1
                    continue
                ahead = min(i + PREFETCH_EVENTS, n - 1)  # its upper left neighbour
                row = (np.intp(y[ix(ahead)]) + R - 1) * wp + np.intp(x[ix(ahead)]) + R - 1
                for k in range(3):
                    prefetch(bins, row + k * wp)
                for k in range(-1, 4):  # the box's rows of words, at the pixel's column
                    prefetch(word, row + k * wp + 1)
                ti = t[ix(i)]
                if started == 0:
                    base = (ti >> 4) - FAR_TICKS
                    started = 1
                tick = (ti >> 4) - base
                if tick >= REBASE_TICKS:
                    _rebase(word, tick - FAR_TICKS)
                    base += tick - FAR_TICKS
                    tick = np.int64(FAR_TICKS)  # int64, not a literal: typed alike wherever compiled (pycc too)
                oldest = ti - WINDOW_US
                while size > 0 and fifo[ix(2 * head)] <= oldest:
                    e = fifo[ix(2 * head + 1)]
                    word[ix(e & 0xFFFFFFFF)] -= OWN_ONE + ((e & (1 << 32)) << 16)  # its count, and ON count
                    block[ix(e >> 33)] -= 1
                    head = (head + 1) & mask
                    size -= 1
                if np.uint64(ti - bin_start) >= np.uint64(BIN_US):  # another DC bin: a division
                    b = ti // BIN_US
                    bin_start = b * BIN_US
                xi = np.intp(x[ix(i)])
                yi = np.intp(y[ix(i)])
                pi = np.intp(p[ix(i)])
                bk = (yi >> 4) * bw + (xi >> 4)
                centre = (yi + R) * wp + xi + R
                # the pixel, its 8 neighbours and its 5×5 box in one vector pass (neighbours.py)
                nb, own_bins, box = nb8_support(word, bins, centre, wp, tick, pi, b & 0xFF)
                n_all = box & 0xFFFF
                n1 = box >> 16  # ON events in the box
                n0 = n_all - n1
                w = word[ix(centre)]
                own_c = (w >> COUNT_SHIFT) & 0xFFFF
                age_own = tick - ((w & TICK_MASK) >> 1)
                blk = block[ix(bk)]
                f0 = tables[ix(n_all)]  # < 65536: the 16-bit fields they are kept in
                f1 = tables[ix(n1 if pi else n0)]
                f2 = tables[ix(own_c)]
                f3 = _log1p_count(tables, size) + log_global_scale
                f4 = _log1p_count(tables, blk) + blog[ix(bk)]
                f8 = tables[ix(LOG_CELLS + min(age_own >> AGE_SHIFT, AGE_CELLS - 1))]
                if n_hidden == 0:
                    f5, f6, f7, f9, f10 = _counted(nb)
                    if want_features:
                        out_feat[ix(i), 0] = f0
                        out_feat[ix(i), 1] = f1
                        out_feat[ix(i), 2] = f2
                        out_feat[ix(i), 3] = f3
                        out_feat[ix(i), 4] = f4
                        out_feat[ix(i), 5] = f5
                        out_feat[ix(i), 6] = f6
                        out_feat[ix(i), 7] = f7
                        out_feat[ix(i), 8] = f8
                        out_feat[ix(i), 9] = f9
                        out_feat[ix(i), 10] = f10
                    s = (c_bias + c0 * f0 + c1 * f1 + c2 * f2 + c3 * f3 + c4 * f4 + c5 * f5 + c6 * f6
                         + c7 * f7 + c8 * f8 + c9 * f9 + c10 * f10)
                    hot = _hot(own_c, n_all, nb, hot_min, dc_margin)
                    s = HOT_SCORE if hot else s
                    if want_score:
                        out_score[ix(i)] = s
                    # branchless: 0 kept, else 1 (background) or 2 (a hot-pixel rule)
                    codes[ix(i)] = (s < threshold) * (1 + hot)
                else:  # scored after the batch
                    k = ix(i - first)
                    feat[0, k] = f0
                    feat[1, k] = f1
                    feat[2, k] = f2
                    feat[3, k] = f3
                    feat[4, k] = f4
                    feat[8, k] = f8
                    counts[k] = n_all | (own_c << 16)
                    nbs[k] = nb
                block[ix(bk)] = blk + 1
                slot = (head + size) & mask
                fifo[ix(2 * slot)] = ti
                fifo[ix(2 * slot + 1)] = centre | (pi << 32) | (bk << 33)
                size += 1
                bins[ix(centre)] = own_bins | 1  # active in bin b
                word[ix(centre)] = ((((w >> COUNT_SHIFT) + 1 + (pi << 16)) << COUNT_SHIFT) | ((b & 0xFF) << BIN_SHIFT)
                                    | (tick << 1) | pi)
                i += 1
            if n_hidden == 0:
                continue
            # an MLP's scoring pass (the columns of events an earlier stage rejected hold garbage:
            # scored like the others, their scores and codes not written)
            m = i - first
            for k in range(m):
                feat[5, k], feat[6, k], feat[7, k], feat[9, k], feat[10, k] = _counted(nbs[k])
            score[:m] = b2
            for u in range(n_hidden):
                for k in range(m):
                    hidden[k] = (b1[u] + w1[u, 0] * feat[0, k] + w1[u, 1] * feat[1, k] + w1[u, 2] * feat[2, k]
                                 + w1[u, 3] * feat[3, k] + w1[u, 4] * feat[4, k] + w1[u, 5] * feat[5, k]
                                 + w1[u, 6] * feat[6, k] + w1[u, 7] * feat[7, k] + w1[u, 8] * feat[8, k]
                                 + w1[u, 9] * feat[9, k] + w1[u, 10] * feat[10, k])
                for k in range(m):
                    score[k] += w2[u] * max(hidden[k], 0.0)
            for k in range(m):
                j = ix(first + k)
                live = all_live or codes[j] == 0
                if want_features and live:
                    for f in range(N_FEATURES):
                        out_feat[j, f] = feat[f, k]
                hot = _hot(counts[k] >> 16, counts[k] & 0xFFFF, nbs[k], hot_min, dc_margin)
                s = HOT_SCORE if hot else score[k]
                if want_score:
                    out_score[j] = s if live else out_score[j]
                codes[j] = (s < threshold) * (1 + hot) if live else codes[j]
        fifo_state[0] = head
        fifo_state[1] = size
        clock[0] = base
        clock[1] = b
        clock[2] = started
        return i

    return kernel


def _ref_log1p(c: int) -> float:
    return math.log1p(c) if c < LOG_CELLS else math.log1p(min(c >> LARGE_SHIFT, LOG_CELLS - 1)) + LOG_LARGE


def reference_features(t, x, y, p, width: int, height: int) -> np.ndarray:
    """The features in plain Python from the definitions (O(n²)), for tests against the kernel."""
    n = len(t)
    out = np.zeros((n, N_FEATURES))
    last_t: dict[tuple[int, int], int] = {}
    last_p: dict[tuple[int, int], int] = {}
    bins: dict[tuple[int, int], set] = {}
    bw = -(-width // BLOCK_PX)
    blog = block_log_scale(width, height)
    for i in range(n):
        ti, xi, yi, pi = int(t[i]), int(x[i]), int(y[i]), int(p[i])
        tick, b = ti // TICK_US, ti // BIN_US
        win = [j for j in range(i) if int(t[j]) > ti - WINDOW_US]
        box = [j for j in win if abs(int(x[j]) - xi) <= 2 and abs(int(y[j]) - yi) <= 2]
        same = [j for j in box if int(p[j]) == pi]
        own = [j for j in box if int(x[j]) == xi and int(y[j]) == yi]
        bk = (yi // 16) * bw + xi // 16
        blk = [j for j in win if (int(y[j]) // 16) * bw + int(x[j]) // 16 == bk]

        def dc(q, b=b):  # active DC bins of pixel q among b - N_BINS + 1 .. b
            return sum(b - N_BINS < c <= b for c in bins.get(q, ()))

        s = np.zeros(3)
        dc_nb = 0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                q = (xi + dx, yi + dy)
                if (dy, dx) == (0, 0):
                    continue
                dc_nb += dc(q)
                if q not in last_t:
                    continue
                age = tick - last_t[q] // TICK_US
                sm = last_p[q] == pi
                s[0] += age < SUPPORT_TICKS[0]
                s[1] += age < SUPPORT_TICKS[1] and sm
                s[2] += age < SUPPORT_TICKS[2] and sm
        age_own = tick - last_t[(xi, yi)] // TICK_US if (xi, yi) in last_t else FAR_TICKS
        cell = min(age_own >> AGE_SHIFT, AGE_CELLS - 1)
        out[i] = [_ref_log1p(len(box)), _ref_log1p(len(same)), _ref_log1p(len(own)),
                  _ref_log1p(len(win)) + math.log(25.0 / (width * height)), _ref_log1p(len(blk)) + blog[bk],
                  s[0] / 8, s[1] / 8, s[2] / 8,
                  math.log1p(cell * (TICK_US << AGE_SHIFT) / 1000.0),
                  dc((xi, yi)) / N_BINS, dc_nb / (8 * N_BINS)]
        last_t[(xi, yi)] = ti
        last_p[(xi, yi)] = pi
        bins.setdefault((xi, yi), set()).add(b)
    return out
