"""Causal per-event features for the learned denoiser, and the fused kernel that scores them.

For event m at (x, y, t, p), from the events before it only (FEATURES, version FEATURE_VERSION):

- counts in the 20 ms window (exact, as the density filter keeps them): N, the events in the 5×5 box
  around m (its own pixel included), N_same the same-polarity ones, and the pixel's own count —
  each as log1p (a lookup table: counts are small integers);
- two references for "how busy is the sensor": the events of the whole sensor in the window, scaled
  to one 5×5 box, log((g + 1) · 25 / (W·H)), and the same for m's 16×16 block — so that a score can
  compare the local count with what background alone would give, whatever the noise rate and the
  sensor size (counts above 65535 are looked up at 1/64 resolution: 0.1 % error);
- neighbour support from the last timestamp of each pixel (self excluded): the 8 neighbours that
  fired within 2 ms (any polarity), within 10 ms and 50 ms (same polarity), as fractions (the 24 of the
  5×5 box within 20 ms were measured too: +0.1 EDP at 100 % noise for 16 more reads, dropped);
- log1p of the time since the pixel's own last event, in ms (quantised to 64 µs, capped at 262 ms).

State: a last-timestamp-and-polarity map, a row-summed count map per polarity (`rowsum`), the own
and block counts, and a FIFO of the window's events: O(W·H + events per 20 ms), bounded.

After the model, one rule: an event whose pixel fired `hot_min` (4) times or more in the last 20 ms,
and more than a third of the events of its 5×5 box (its own included), is a HOT_PIXEL (score
HOT_SCORE). Measured at 100 % noise (a model trained on the six real recordings): the logistic score
alone removed 91.1 % (N-Caltech101) and 97.2 % (DVXplorer) of the hot-pixel events — the kept ones
are 200–1600 Hz pixels in busy areas, whose own events fill the box count — with the rule 98.0 % and
99.7 %, for 0.05 % and 0.03 % of the signal.

One kernel is compiled per configuration (hidden units 0 = logistic score, else a one-hidden-layer
ReLU MLP; scores, feature rows, whether earlier stages rejected events): no option costs anything per
event. The features are standardised by folding the training mean and std into the first layer.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from ...nowrap import ix
from ..rowsum import column_sum, padded_map, row_add

FEATURE_VERSION = 1
FEATURES = (
    "log1p_n_5x5_20ms", "log1p_n_same_5x5_20ms", "log1p_own_20ms", "log_ref_global", "log_ref_block",
    "nb8_any_2ms", "nb8_same_10ms", "nb8_same_50ms", "log1p_age_ms",
)
N_FEATURES = len(FEATURES)
RADIUS_PX = 2          # the 5×5 box
WINDOW_US = 20_000     # the counts' window
BLOCK_PX = 16          # the block reference
SUPPORT_US = (2_000, 10_000, 50_000)  # nb8 any, nb8 same, nb8 same
HISTORY_US = 50_000    # the longest time a feature looks back
AGE_SHIFT = 6          # age quantised to 64 µs
AGE_CELLS = 4096       # ... up to 4096 · 64 µs = 262 ms
LOG_CELLS = 1 << 16    # log1p table for counts
NEVER_US = -(2**61)
HOT_SCORE = -1e9       # the score of an event the hot-pixel rule rejects  # (t << 1) stays in int64

LARGE_SHIFT = 6
LOG_LARGE = math.log(1 << LARGE_SHIFT)
LOG1P = np.log1p(np.arange(LOG_CELLS, dtype=np.float64))
AGE_LOG1P_MS = np.log1p(np.arange(AGE_CELLS, dtype=np.float64) * (1 << AGE_SHIFT) / 1000.0)


def offsets(width_padded: int) -> np.ndarray:
    """Flat offsets of the 8 neighbours (self excluded) in a map padded by RADIUS_PX."""
    inner = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
    return np.array([dy * width_padded + dx for dy, dx in inner], np.int64)


def block_log_scale(width: int, height: int) -> np.ndarray:
    """Per 16×16 block: log(25 / block area in pixels), blocks at the right/bottom edge being smaller."""
    bw, bh = -(-width // BLOCK_PX), -(-height // BLOCK_PX)
    cols = np.minimum(BLOCK_PX, width - BLOCK_PX * np.arange(bw))
    rows = np.minimum(BLOCK_PX, height - BLOCK_PX * np.arange(bh))
    return np.log(25.0 / np.outer(rows, cols).astype(np.float64)).reshape(-1)


def new_state(width: int, height: int) -> dict:
    """Fresh state for a width × height sensor."""
    r = RADIUS_PX
    wp = width + 2 * r
    cap = 1 << 12
    return {
        "width_padded": wp,
        "last": np.full((height + 2 * r) * wp, NEVER_US << 1, np.int64),  # (t << 1) | p
        # one row-summed map, each cell packing (all events) | (ON events) << 16: one read per row gives
        # both N and N_ON (counts per 20 ms in a 5×5 box stay far below 65536)
        "hsum": padded_map(width, height, r, np.uint32),
        "own": np.zeros(width * height, np.uint16),
        "block": np.zeros(-(-width // BLOCK_PX) * -(-height // BLOCK_PX), np.int32),
        "block_log_scale": block_log_scale(width, height),
        "offsets": offsets(wp),
        "fifo_t": np.zeros(cap, np.int64),
        "fifo_pos": np.zeros(cap, np.int64),
        "fifo_pix": np.zeros(cap, np.int64),
        "fifo_state": np.zeros(2, np.int64),
    }


@njit(cache=True, nogil=True, inline="always")
def _log1p_count(table, c):
    """log1p(c) of a count by table, exact below LOG_CELLS, then to 0.1 % (c >> 6, + log 64), capped at
    2^22. No call to log1p: LLVM would evaluate it speculatively on every event (measured 5× slower)."""
    if c < LOG_CELLS:
        return table[ix(c)]
    return table[ix(min(c >> LARGE_SHIFT, LOG_CELLS - 1))] + LOG_LARGE


@functools.cache
def feature_kernel(n_hidden: int, want_score: bool, want_features: bool, all_live: bool):
    """The kernel for one configuration: `n_hidden` 0 scores with a logistic model (w1[0], b1[0]),
    else with a ReLU layer of `n_hidden` units (w1, b1) and an output layer (w2, b2). The features are
    scalars (registers), the neighbour loop is unrolled, the FIFO stores each event's block with its
    pixel (no division on expiry)."""
    L = 2 * RADIUS_PX + 1
    R = RADIUS_PX

    @njit(cache=True, nogil=True, fastmath=True)
    def kernel(t, x, y, p, start, codes, threshold, hot_min, last, hsum, own, block, blog, offs,
               width_padded, fifo_t, fifo_pos, fifo_pix, fifo_state, width, height, w1, b1, w2, b2,
               out_score, out_feat, log1p, age_log1p):
        """Score events `start..` whose code is SIGNAL: BACKGROUND below `threshold` (HOT_PIXEL when the
        pixel's own 20 ms count is >= `hot_min`). Returns the index reached: len(t) unless the FIFO is
        full (the caller grows it and calls again from there)."""
        cap = len(fifo_t)
        mask = cap - 1
        head = fifo_state[0]
        size = fifo_state[1]
        bw = (width + 15) // 16
        log_global_scale = math.log(25.0 / (width * height))
        n = len(t)
        i = start
        while i < n:
            stop = min(n, i + cap - size)
            if stop == i:
                break
            while i < stop:
                if not all_live and codes[ix(i)] != 0:
                    i += 1
                    continue
                ti = t[ix(i)]
                oldest = ti - WINDOW_US
                while size > 0 and fifo_t[ix(head)] <= oldest:
                    pos = fifo_pos[ix(head)]  # the cell; bit 40 says ON
                    row_add(hsum, pos & 0xFFFFFFFFFF, -(1 + ((pos >> 40) << 16)), L)
                    packed = fifo_pix[ix(head)]
                    own[ix(packed & 0xFFFFFFFF)] -= 1
                    block[ix(packed >> 32)] -= 1
                    head = (head + 1) & mask
                    size -= 1
                xi = np.intp(x[ix(i)])
                yi = np.intp(y[ix(i)])
                pi = np.intp(p[ix(i)])
                corner = yi * width_padded + xi
                packed_sum = column_sum(hsum, corner + R, width_padded, L)
                n_all = packed_sum & 0xFFFF
                n1 = packed_sum >> 16  # ON events in the box
                n0 = n_all - n1
                pix = yi * width + xi
                b = (yi >> 4) * bw + (xi >> 4)
                own_c = own[ix(pix)]
                centre = corner + R * width_padded + R
                s2 = 0
                s10 = 0
                s50 = 0
                for k in range(8):  # last[q] = (timestamp << 1) | polarity: one read per neighbour
                    v = last[ix(centre + offs[k])]
                    age = ti - (v >> 1)
                    same = (v & 1) == pi
                    s2 += age < 2_000
                    s10 += (age < 10_000) & same
                    s50 += (age < 50_000) & same
                age_own = ti - (last[ix(centre)] >> 1)
                f0 = _log1p_count(log1p, n0 + n1)
                f1 = _log1p_count(log1p, n1 if pi else n0)
                f2 = _log1p_count(log1p, own_c)
                f3 = _log1p_count(log1p, size) + log_global_scale
                f4 = _log1p_count(log1p, block[ix(b)]) + blog[ix(b)]
                f5 = s2 * 0.125
                f6 = s10 * 0.125
                f7 = s50 * 0.125
                f8 = age_log1p[ix(min(age_own >> AGE_SHIFT, AGE_CELLS - 1))]
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
                if n_hidden == 0:
                    s = (b1[0] + w1[0, 0] * f0 + w1[0, 1] * f1 + w1[0, 2] * f2 + w1[0, 3] * f3 + w1[0, 4] * f4
                         + w1[0, 5] * f5 + w1[0, 6] * f6 + w1[0, 7] * f7 + w1[0, 8] * f8)
                else:
                    s = b2
                    for j in range(n_hidden):
                        h = (b1[j] + w1[j, 0] * f0 + w1[j, 1] * f1 + w1[j, 2] * f2 + w1[j, 3] * f3
                             + w1[j, 4] * f4 + w1[j, 5] * f5 + w1[j, 6] * f6 + w1[j, 7] * f7 + w1[j, 8] * f8)
                        s += w2[j] * max(h, 0.0)
                # hot-pixel rule: the pixel fired hot_min times or more in 20 ms, at least half as
                # often as all its 24 neighbours together (a linear score cannot express it)
                hot = (own_c >= hot_min) & (3 * own_c > n0 + n1)
                s = HOT_SCORE if hot else s
                if want_score:
                    out_score[ix(i)] = s
                # branchless: 0 kept, else 1 (background) or 2 (the hot-pixel rule)
                codes[ix(i)] = (s < threshold) * (1 + hot)
                pos = corner + R * width_padded
                row_add(hsum, pos, 1 + (pi << 16), L)
                own[ix(pix)] += 1
                block[ix(b)] += 1
                slot = (head + size) & mask
                fifo_t[ix(slot)] = ti
                fifo_pos[ix(slot)] = pos | (pi << 40)
                fifo_pix[ix(slot)] = (b << 32) | pix
                size += 1
                last[ix(centre)] = (ti << 1) | pi
                i += 1
        fifo_state[0] = head
        fifo_state[1] = size
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
    bw = -(-width // BLOCK_PX)
    blog = block_log_scale(width, height)
    for i in range(n):
        ti, xi, yi, pi = int(t[i]), int(x[i]), int(y[i]), int(p[i])
        win = [j for j in range(i) if int(t[j]) > ti - WINDOW_US]
        box = [j for j in win if abs(int(x[j]) - xi) <= 2 and abs(int(y[j]) - yi) <= 2]
        same = [j for j in box if int(p[j]) == pi]
        own = [j for j in box if int(x[j]) == xi and int(y[j]) == yi]
        b = (yi // 16) * bw + xi // 16
        blk = [j for j in win if (int(y[j]) // 16) * bw + int(x[j]) // 16 == b]
        s = np.zeros(3)
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if (dy, dx) == (0, 0) or (xi + dx, yi + dy) not in last_t:
                    continue
                age = ti - last_t[(xi + dx, yi + dy)]
                sm = last_p[(xi + dx, yi + dy)] == pi
                s[0] += age < 2_000
                s[1] += age < 10_000 and sm
                s[2] += age < 50_000 and sm
        age_own = ti - last_t.get((xi, yi), NEVER_US)
        out[i] = [_ref_log1p(len(box)), _ref_log1p(len(same)), _ref_log1p(len(own)),
                  _ref_log1p(len(win)) + math.log(25.0 / (width * height)), _ref_log1p(len(blk)) + blog[b],
                  s[0] / 8, s[1] / 8, s[2] / 8,
                  math.log1p(min(age_own >> AGE_SHIFT, AGE_CELLS - 1) * (1 << AGE_SHIFT) / 1000.0)]
        last_t[(xi, yi)] = ti
        last_p[(xi, yi)] = pi
    return out
