"""A bounded, seeded mutation fuzzer over every format we read (tests/fuzzing.py makes the mutants: bit
flips, header bytes, length fields, truncation, duplicated and dropped blocks, zip members whose sizes
lie, zip bombs). Every mutant either reads as valid events or fails with one EventError naming the file —
never another exception, a signal, a hang, or more memory than the file justifies. In-process through
the API for speed; a sample through the CLI checks the exit code and the one line.

`EVSTREAM_FUZZ_MUTANTS=N` (default 200 per format) and `EVSTREAM_FUZZ_SEED=S` (default 22) to fuzz more
or elsewhere; a finding prints its class, index and seed, so `fuzzing.mutants` can make it again."""

import collections
import faulthandler
import os
import resource
import subprocess
import sys
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from cli_checks import one_line_error
from conftest import REAL_DATA
from fuzzing import mutants, read, seed_files

from evstream.events import EventError

MUTANTS = int(os.environ.get("EVSTREAM_FUZZ_MUTANTS", "200"))
SEED = int(os.environ.get("EVSTREAM_FUZZ_SEED", "22"))
HANG_S = 120  # one mutant taking this long is a hang: the process dumps its stack and exits


def memory_allowed(size: int) -> int:
    """What reading a file of `size` bytes may hold at once: a reader's fixed working set (blocks of about
    1 MiB per column, a 64 MiB bound on a compressed chunk's claim) or 64 bytes per byte of the file."""
    return max(160 << 20, 64 * size)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    return seed_files(tmp_path_factory.mktemp("seeds"), REAL_DATA if REAL_DATA.is_dir() else None)


FORMATS = ["evt3.raw", "evt2.raw", "event2d.dat", "nmnist.bin", "aedat2.aedat", "events.txt", "events.h5",
           "events.npy", "native.npz", "stored.npz", "events.mat", "archive.mcap", "real.aedat4"]


@pytest.mark.parametrize("name", FORMATS)
def test_mutants_read_as_events_or_fail_in_one_line(seeds, tmp_path, name):
    if name not in seeds:
        pytest.skip(f"{name}: made from the real recordings, not present at {REAL_DATA} (set EVSTREAM_REAL_DATA)")
    data = seeds[name].read_bytes()
    assert read(seeds[name]) > 0  # the seed itself is valid
    rng = np.random.default_rng([SEED, FORMATS.index(name)])
    outcomes = collections.Counter()
    findings = []
    path = tmp_path / f"mutant.{name.rsplit('.', 1)[1]}"
    faulthandler.dump_traceback_later(HANG_S, exit=True)
    tracemalloc.start()
    try:
        for k, (kind, mutant) in enumerate(mutants(name, data, rng, MUTANTS)):
            path.write_bytes(mutant)
            tracemalloc.reset_peak()
            faulthandler.dump_traceback_later(HANG_S, exit=True)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # a truncated file says so as a warning: not a finding
                    read(path)
                outcome = "events"
            except EventError as e:
                outcome = "one-line error"
                if "\n" in str(e) or str(path) not in str(e):
                    findings.append(f"{kind} #{k}: error not one line naming the file: {str(e)[:300]!r}")
            except Exception as e:  # noqa: BLE001 - any other exception is the finding
                outcome = "other exception"
                findings.append(f"{kind} #{k}: {type(e).__name__}: {str(e)[:300]}")
            peak = tracemalloc.get_traced_memory()[1]
            if peak > memory_allowed(len(mutant)):
                findings.append(f"{kind} #{k}: {peak >> 20} MiB held for a {len(mutant)}-byte file")
            outcomes[(kind, outcome)] += 1
    finally:
        tracemalloc.stop()
        faulthandler.cancel_dump_traceback_later()
    print(f"\n{name}: {MUTANTS} mutants (seed {SEED}): "
          + ", ".join(f"{kind} -> {outcome} {n}" for (kind, outcome), n in sorted(outcomes.items())))
    assert not findings, f"{name} (seed {SEED}): " + "\n".join(findings[:20])


def _limit_memory():  # a child that tries to take the machine's memory gets MemoryError instead
    resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))


def test_a_sample_of_mutants_through_the_cli(seeds, tmp_path):
    """The command line on a few mutants per format: exit 0, or exit 1 with one line — no traceback,
    internal error, Rust panic or signal."""
    rng = np.random.default_rng([SEED, 99])
    ran = 0
    for name in FORMATS:
        if name not in seeds:
            continue
        for k, (kind, mutant) in enumerate(mutants(name, seeds[name].read_bytes(), rng, 2)):
            path = tmp_path / f"{k}-{name}"
            path.write_bytes(mutant)
            r = subprocess.run([sys.executable, "-m", "evstream.cli", "info", str(path)], capture_output=True,
                               text=True, timeout=HANG_S, preexec_fn=_limit_memory)
            assert r.returncode in (0, 1), f"{name} {kind}: exit {r.returncode}: {r.stderr[-2000:]}"
            if r.returncode == 1:
                line = one_line_error(r.stderr)
                assert str(path) in line, line
            else:
                assert "Traceback" not in r.stderr and "panicked" not in r.stderr, r.stderr
            ran += 1
    assert ran >= 2 * (len(FORMATS) - 1)


def test_the_fuzzer_makes_every_class_of_mutant(seeds):
    """The mutants are what the docstring says: each class appears, zip ones for .npz, bombs included."""
    kinds = collections.Counter(kind for kind, _ in mutants("native.npz", seeds["native.npz"].read_bytes(),
                                                           np.random.default_rng(0), 100))
    assert set(kinds) == {"bit flips", "header bytes", "length field", "truncation", "duplicated block",
                          "dropped block", "zip sizes", "zip bomb"}
    assert Path(seeds["native.npz"]).stat().st_size < 10_000
