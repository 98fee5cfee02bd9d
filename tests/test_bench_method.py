"""bench_paper's method (no timing asserted): every case runs once per round after a warm-up, in an order
of its own each round when shuffled; a cell that fails says why; a cell's rows give the ratios of the
best times and of the medians."""

import pytest

from benchmarks.bench_paper import chunk_label, pieces, report_cell
from benchmarks.common import cpu_s, in_fresh_process


def test_shuffled_rounds_run_every_case_once_each_in_changing_orders():
    calls = []
    cases = {name: (lambda name=name: calls.append(name)) for name in "abcdef"}
    times = cpu_s(cases, rounds=6, shuffle=True)
    assert calls[:6] == list("abcdef")  # the warm-up, in order
    rounds = [calls[6 + 6 * r : 12 + 6 * r] for r in range(6)]
    assert all(sorted(r) == list("abcdef") for r in rounds)
    assert len({tuple(r) for r in rounds}) > 1
    assert {k: len(v) for k, v in times.items()} == dict.fromkeys("abcdef", 6)
    calls.clear()
    cpu_s(cases, rounds=2)
    assert calls == list("abcdef") * 3  # unshuffled: the given order


def test_a_cell_that_fails_says_which_and_why():
    with pytest.raises(RuntimeError, match=r"(?s)^benchmarks.bench_paper no-such-cell: exit 1: .*KeyError"):
        in_fresh_process("benchmarks.bench_paper", "no-such-cell")


def test_pieces_cover_the_stream_in_chunks():
    assert pieces(25, 10) == [(0, 10), (10, 20), (20, 25)]
    assert pieces(25, None) == [(0, 25)]
    assert [chunk_label(c) for c in (10_000, 100_000, None)] == ["10k", "100k", "one call"]


def test_a_cells_rows_give_the_ratios_of_the_best_times_and_of_the_medians(capsys):
    times = {"BAF stage, 10k": [2.0, 3.0, 4.0], "plain numba BAF, 10k": [1.0, 1.5, 8.0]}
    report_cell(times, 1_000_000)
    rows = capsys.readouterr().out.splitlines()
    assert rows[0].startswith("BAF stage, 10k") and "0.5 M events/s" in rows[0]
    assert "median=0.3M" in rows[0] and "vs_plain_BAF=0.50x / 0.50x" in rows[0]
    assert rows[1].startswith("plain numba BAF, 10k") and "1.0 M events/s" in rows[1]
