"""Mutation testing (`make mutation`, outside CI): mutmut over one module at a time, each mutant run
against that module's fast tests only, in a copy of the tree under out/mutation/ (the work tree is
never touched). Prints the score per module and lists the survivors.

    python tests/mutation.py testing codecs        # modules by name (see TARGETS); none: all of them

Numba: mutmut 3 mutates plain functions only (it skips decorated ones, so the @njit kernels are not
mutated; their plain-Python references in the tests guard them), and forks each mutant from one
process that already compiled the kernels. NUMBA_DISABLE_JIT is not usable: as plain Python the
kernels overflow numpy's fixed-width integers (uint8 * int under NumPy 2 promotion) where numba
widens them. Numba's cache goes to a fresh folder per run, so no compiled code outlives a run.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "mutation"

# module -> (files to mutate, as paths in the copy, where sources/ lives at evstream/sources/; tests)
TARGETS = {
    "testing": (["evstream/testing.py"], ["tests/test_invariant_kit.py"]),
    "sources_base": (["evstream/sources/_base.py"],
                     ["tests/test_sources_formats.py", "tests/test_sources_bad_input.py",
                      "tests/test_sources_kernels.py"]),
    "framing": (["evstream/framing/*"], ["tests/test_framing.py", "tests/test_invariant_kit.py"]),
    "codecs": (["evstream/codecs/*"], ["tests/test_codecs_evt2.py", "tests/test_codecs_evt3.py",
                                       "tests/test_event_packet.py", "tests/test_zenoh_attachment.py"]),
    "denoise": (["evstream/denoise/*"], ["tests/test_baselines.py", "tests/test_paper_cascade.py",
                                         "tests/test_rowsum.py"]),
}
IGNORE = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.pyc")


def workspace(name: str) -> Path:
    """out/mutation/NAME: the package as it installs (sources/ and sinks/ inside evstream/), the tests,
    the shipped recordings and a pyproject.toml whose [tool.mutmut] names what to mutate and run."""
    mutate, tests = TARGETS[name]
    ws = OUT / name
    shutil.rmtree(ws, ignore_errors=True)
    shutil.copytree(ROOT / "evstream", ws / "evstream", ignore=IGNORE)
    for sub in ("sources", "sinks"):
        shutil.copytree(ROOT / sub, ws / "evstream" / sub, ignore=IGNORE)
    shutil.copytree(ROOT / "tests", ws / "tests", ignore=IGNORE)
    shutil.copytree(ROOT / "recordings", ws / "recordings")
    pyproject = (ROOT / "pyproject.toml").read_text()
    pyproject = re.sub(r"\[tool\.pytest\.ini_options\][^\[]*", "", pyproject)
    (ws / "pyproject.toml").write_text(pyproject + "\n[tool.mutmut]\n" + "\n".join([
        'source_paths = ["evstream"]',
        f"only_mutate = {json.dumps(mutate)}",
        f"pytest_add_cli_args_test_selection = {json.dumps(tests)}",
        'pytest_add_cli_args = ["-p", "no:cacheprovider", "-q"]',
        'also_copy = ["recordings"]',
    ]) + "\n")
    return ws


def score(ws: Path) -> dict:
    """Counts per status from mutmut's own per-file results."""
    r = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"], cwd=ws,
                       capture_output=True, text=True)
    counts: dict[str, int] = {}
    survivors = []
    for line in r.stdout.splitlines():
        if ":" not in line:
            continue
        mutant, status = (s.strip() for s in line.rsplit(":", 1))
        counts[status] = counts.get(status, 0) + 1
        if status == "survived":
            survivors.append(mutant)
    killed = counts.get("killed", 0) + counts.get("timeout", 0)
    total = killed + counts.get("survived", 0)
    return {"counts": counts, "score": killed / total if total else None, "survivors": survivors}


def run(name: str) -> dict:
    ws = workspace(name)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(ws / ".numba_cache"), PYTHONHASHSEED="0")
    env.pop("NUMBA_DISABLE_JIT", None)
    children = os.environ.get("MUTATION_CHILDREN", "2")
    with open(ws / "mutmut.log", "w") as log:
        subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children", children], cwd=ws, env=env,
                       stdout=log, stderr=subprocess.STDOUT)
    result = score(ws)
    (ws / "score.json").write_text(json.dumps(result, indent=1))
    return result


def main(argv: list[str]) -> int:
    names = argv or list(TARGETS)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        print(f"unknown module {unknown}; choose from {', '.join(TARGETS)}", file=sys.stderr)
        return 2
    for name in names:
        r = run(name)
        c = r["counts"]
        pct = "n/a" if r["score"] is None else f"{100 * r['score']:.1f} %"
        print(f"{name}: {pct} killed ({c.get('killed', 0)} killed, {c.get('timeout', 0)} timeout, "
              f"{c.get('survived', 0)} survived, {c.get('no tests', 0)} without a test; "
              f"survivors in {OUT / name / 'score.json'})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
