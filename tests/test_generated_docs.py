"""The blocks of the docs that a command prints (docs/generated.py) match what it prints now.

The full evaluation (docs/evaluation.md's main tables: 9 recordings, six of them real, 2 seeds, tuned)
takes minutes and the real recordings: it runs with EVSTREAM_FULL_EVAL=1 (and the recordings). The small
configuration beside it (the shipped bar recording, four methods, three conditions, one seed; ~20 s) runs
always, so a change in any method, metric or table layout shows here.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("generated", ROOT / "docs" / "generated.py")
generated = importlib.util.module_from_spec(spec)
spec.loader.exec_module(generated)

BLOCKS = [(path, command, body) for path in generated.DOCS
          for command, body, _ in generated.blocks(path.read_text(encoding="utf-8"))]


def test_the_evaluation_doc_has_full_blocks_and_one_the_tests_always_check():
    commands = [c for p, c, _ in BLOCKS if p.name == "evaluation.md"]
    assert any("--real" not in c and generated.REAL not in c for c in commands)
    assert any("--real" in c for c in commands) and any(generated.REAL + "/*" in c for c in commands)


@pytest.mark.parametrize("path, command, body", BLOCKS, ids=[f"{p.name}: {c}" for p, c, _ in BLOCKS])
def test_generated_block_matches_what_its_command_prints(path, command, body):
    if "--real" in command or generated.REAL in command:
        real = Path(os.environ.get("EVSTREAM_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
        if not real.is_dir():
            pytest.skip(f"needs the real recordings at {real} (set EVSTREAM_REAL_DATA=/path/to/real)")
        if os.environ.get("EVSTREAM_FULL_EVAL") != "1":
            pytest.skip("the full evaluation takes minutes: EVSTREAM_FULL_EVAL=1 runs it "
                        "(the small configuration's block is checked always)")
    printed = generated.run(command)
    assert printed == body, (f"{path.relative_to(ROOT)}: the block of `{command}` is stale; "
                             "`.venv/bin/python docs/generated.py` rewrites it")
