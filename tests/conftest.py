import os
import signal
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, settings

ROOT = Path(__file__).resolve().parents[1]
REAL_DATA = Path(os.environ.get("EVSTREAM_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))

# `HYPOTHESIS_PROFILE=thorough make test` for a long search; the default keeps `make test` quick.
# `mutation` (tests/mutation.py): fewer, fixed examples, since each mutant reruns the tests with the
# mutated kernels as plain Python; the same examples for every mutant, so scores are reproducible.
# (`mutation` does not shrink a failing example either: one failure kills the mutant, and shrinking it
# cost a killed mutant minutes.)
for name, examples in (("default", 25), ("thorough", 400), ("mutation", 10)):
    settings.register_profile(name, max_examples=examples, deadline=None, derandomize=name == "mutation",
                              suppress_health_check=[HealthCheck.too_slow],
                              phases=[p for p in Phase if name != "mutation" or p is not Phase.shrink])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

# The tests that press Ctrl-C (SIGINT) on a command expect what a terminal gives it. A shell that starts
# `make test &` in the background sets SIGINT to ignored, and an ignored signal stays ignored across
# exec: every command the tests start would then shrug off its Ctrl-C. A handled signal is reset to the
# default at exec, so with Python's own handler here the commands start as from a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def real_data_skip_reason() -> str:
    return (f"real recordings not present at {REAL_DATA}; point EVSTREAM_REAL_DATA=/path/to/real at a folder "
            "of them to run this test")


@pytest.fixture
def real_data() -> Path:
    """The shared folder of real recordings; tests using it skip where it is absent (a user's clone)."""
    if not REAL_DATA.is_dir():
        pytest.skip(real_data_skip_reason())
    return REAL_DATA
