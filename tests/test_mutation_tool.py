"""tests/mutation.py's in-process executor (`--inproc`): the parent's guard on a worker stuck in
compiled code or growing without bound, the verdicts kept across a change of sources and across a
failing control run, and every target's test selection holding the tests that import its functions.
The guard's workers here are real processes (a compiled loop, an allocation, a sleep)."""

import json
import subprocess
import sys
import textwrap

import mutation
import pytest


def _worker(tmp_path, body: str, **now) -> tuple[subprocess.Popen, object]:
    """A process that says (as the executor's worker does, in its running file) what it runs, then runs `body`."""
    running = tmp_path / "inproc.running"
    code = f"import json, pathlib\npathlib.Path({str(running)!r}).write_text(json.dumps({now!r}))\n"
    return subprocess.Popen([sys.executable, "-c", code + textwrap.dedent(body)]), running


@pytest.fixture
def compiled_loop():
    return """
        import signal
        from numba import njit

        @njit
        def spin(n):  # a minute or so (xorshift: nothing to fold away), so that a failing guard ends too
            x = 1
            for _ in range(n):
                x ^= (x << 13) & 0xFFFFFFFF
                x ^= x >> 17
                x ^= (x << 5) & 0xFFFFFFFF
            return x

        spin(1)  # compiled before the limit is set
        def on_alarm(signum, frame):
            raise RuntimeError("the CPU limit, as the worker's")
        signal.signal(signal.SIGPROF, on_alarm)
        signal.setitimer(signal.ITIMER_PROF, 0.1)
        spin(30_000_000_000)
    """


def test_the_guard_stops_a_worker_looping_in_compiled_code(tmp_path, compiled_loop):
    """A mutant looping inside compiled code (session 10: `DensityFilter._grow` 26 ran 11 min): the
    worker's own CPU limit (ITIMER_PROF, whose handler runs between bytecodes) never fires; the parent
    stops it past the test's CPU limit: a timeout, the test named."""
    worker, running = _worker(tmp_path, compiled_loop, mutant="m__mutmut_1", test="t::a", limit_s=0.2, rss_mb=1e6)
    verdict = mutation.guard(worker, running, poll_s=0.05, cpu_s=0.3, wall=1e6)
    assert worker.returncode == -9
    assert verdict["mutant"] == "m__mutmut_1" and verdict["status"] == "timeout" and verdict["failed"] == ["t::a"]


def test_the_guard_stops_a_worker_past_its_memory_bound(tmp_path):
    worker, running = _worker(tmp_path, """
        import time
        held = []
        while len(held) < 100:  # up to 1 GB, then wait: the guard must have stopped it before
            held.append(b"x" * 10_000_000)
            time.sleep(0.01)
        time.sleep(60)
    """, mutant="m__mutmut_2", test="t::b", limit_s=600.0, rss_mb=200.0)
    verdict = mutation.guard(worker, running, poll_s=0.05)
    assert worker.returncode == -9 and verdict["status"] == "memory" and verdict["mutant"] == "m__mutmut_2"


def test_the_guard_stops_a_worker_blocked_past_its_wall_limit(tmp_path):
    """A mutant that blocks (a wait, a deadlock) uses no CPU: only wall time sees it."""
    worker, running = _worker(tmp_path, "import time; time.sleep(60)", mutant="m__mutmut_3", test="t::c",
                              limit_s=0.05, rss_mb=1e6)
    verdict = mutation.guard(worker, running, poll_s=0.05, wall=4.0)
    assert worker.returncode == -9 and verdict["status"] == "timeout" and verdict["mutant"] == "m__mutmut_3"


def test_the_guard_gives_each_test_its_own_limit_and_lets_the_worker_end(tmp_path):
    """Three tests of 0.3 s of CPU each, each within its limit (0.1 + 0.6 s) though the three are not;
    between mutants (nothing running) there is no limit; the worker ends by itself: no verdict. (No wall
    limit here: under load the worker may get a tenth of a core.)"""
    worker, running = _worker(tmp_path, f"""
        import time
        path = pathlib.Path({str(tmp_path / "inproc.running")!r})
        for test in ("t::d", "t::e", "t::f"):
            path.write_text(json.dumps(dict(mutant="m__mutmut_4", test=test, limit_s=0.1, rss_mb=1e6)))
            t0 = time.process_time()
            while time.process_time() - t0 < 0.3:
                pass
        path.write_text("")
        t0 = time.process_time()
        while time.process_time() - t0 < 1.0:
            pass
    """)
    assert mutation.guard(worker, running, poll_s=0.02, cpu_s=0.6, wall=1e6) is None
    assert worker.returncode == 0


def test_the_guard_ignores_what_another_worker_ran(tmp_path):
    """A restarted worker's clean run is no mutant's test: the running file the killed worker left (its
    pid) must not stop it. Seen: a framing_represent run stopped each restarted worker's clean run as
    the last mutant's, 13 times, until stopped by hand."""
    worker, running = _worker(tmp_path, """
        import time
        t0 = time.process_time()
        while time.process_time() - t0 < 1.0:
            pass
    """, mutant="m__mutmut_5", test=None, limit_s=0.1, rss_mb=1e6, pid=1)
    assert mutation.guard(worker, running, poll_s=0.02, cpu_s=0.1, wall=1e6) is None and worker.returncode == 0


def test_a_change_of_sources_keeps_the_verdicts_of_the_functions_it_leaves_alone():
    """mutmut names a mutant by its function and a number; a verdict holds while that function reads the
    same, and for a method while its class does (fields, defaults, decorators) but for its other methods."""
    before = textwrap.dedent("""
        import numpy as np

        LIMIT = 3

        def same(a):
            return a + 1

        def edited(a):
            return a - 1

        def gone(a):
            return a

        @dataclass
        class Kept:
            n: int = 1

            def run(self):
                return self.n

            def other(self):
                return 0

        @dataclass
        class Field:
            n: int = 1

            def run(self):
                return self.n
    """)
    after = (before.replace("return a - 1", "return a - 2").replace("def gone(a):\n    return a\n", "")
             .replace("def other(self):\n        return 0", "def other(self):\n        return 1")
             .replace("class Field:\n    n: int = 1", "class Field:\n    n: int = 2")
             .replace("LIMIT = 3", "LIMIT = 4"))
    m = "evstream.mod."
    verdicts = {f"{m}{fn}__mutmut_{k}": {"status": "killed"} for fn in
                ("x_same", "x_edited", "x_gone", "xǁKeptǁrun", "xǁKeptǁother", "xǁFieldǁrun") for k in (1, 2)}
    kept = mutation.unchanged(verdicts, mutation.functions(before, "evstream.mod"),
                              mutation.functions(after, "evstream.mod"))
    assert sorted(kept) == [f"{m}x_same__mutmut_1", f"{m}x_same__mutmut_2", f"{m}xǁKeptǁrun__mutmut_1",
                            f"{m}xǁKeptǁrun__mutmut_2"]


def test_again_forgets_the_old_verdicts_only_once_the_control_run_has_passed(tmp_path):
    """`--again` names the mutants to run again; their old verdicts stay (and count) until the worker's
    clean run before the mutants passes, so a failing control (tests newer than the copy's sources)
    loses nothing."""
    lines = [{"mutant": f"f__mutmut_{k}", "status": s} for k, s in ((1, "survived"), (2, "killed"), (3, "survived"))]
    (tmp_path / "inproc.json").write_text("".join(json.dumps(v) + "\n" for v in lines))
    before = (tmp_path / "inproc.json").read_text()
    (tmp_path / "inproc.redo").write_text("f__mutmut_1\nf__mutmut_3")  # as `inproc(..., again=True)` does
    assert mutation._redo(tmp_path) == {"f__mutmut_1", "f__mutmut_3"}
    assert (tmp_path / "inproc.json").read_text() == before  # a control failing now leaves them all
    mutation.forget_redone(tmp_path, ["f__mutmut_1", "f__mutmut_4"])  # the control passed; f__mutmut_3 not run now
    assert list(mutation._verdicts(tmp_path / "inproc.json")) == ["f__mutmut_2", "f__mutmut_3"]
    assert mutation._redo(tmp_path) == {"f__mutmut_3"}  # still asked for, its old verdict still there
    mutation.forget_redone(tmp_path, ["f__mutmut_3"])
    assert list(mutation._verdicts(tmp_path / "inproc.json")) == ["f__mutmut_2"]
    assert mutation._redo(tmp_path) == set()
    mutation.forget_redone(tmp_path, ["f__mutmut_2"])  # a restarted worker (after a crash) forgets nothing more
    assert list(mutation._verdicts(tmp_path / "inproc.json")) == ["f__mutmut_2"]


def test_a_kernel_a_compiled_kernel_calls_stays_compiled():
    """Compiled code cannot call a plain-Python function. So in a target's copy a kernel stays compiled
    (and is not mutated) when a compiled kernel calls it: one of a module not mutated, or one kept compiled
    itself, for an `@intrinsic` it calls (which has no Python form), or in turn."""
    sources = {
        "evstream/a.py": textwrap.dedent("""
            @intrinsic
            def _vector(typingctx, x):
                pass

            @njit
            def alone(x):
                return x + 1

            @njit
            def called_from_b(x):
                return deeper(x)

            @njit
            def deeper(x):
                return x

            @njit(cache=True)
            def uses_intrinsic(x):
                return from_c(_vector(x))
        """),
        "evstream/b.py": "@njit\ndef caller(x):\n    return a.called_from_b(x)\n\n"
                         "def python(x):\n    return alone(x)\n",
        "evstream/c.py": "@njit\ndef from_c(x):\n    return x\n\n@njit\ndef free(x):\n    return x\n",
    }
    assert mutation.kept_compiled(sources, {"evstream/a.py"}) == {"called_from_b", "deeper", "uses_intrinsic"}
    assert mutation.kept_compiled(sources, {"evstream/a.py", "evstream/b.py", "evstream/c.py"}) == {
        "uses_intrinsic", "from_c"}
    plain = mutation.plain_kernels(sources["evstream/a.py"], {"called_from_b", "deeper"})
    assert plain.count("@njit") == 3 and "@njit\ndef alone" not in plain


def test_every_target_runs_the_tests_that_import_its_functions(monkeypatch):
    """Session 10's first framing_windows selection left out test_represent.py, where fn_scan's tests are:
    its mutants were 'not reached'. Each target's selection holds every test file importing a function
    of a module it mutates, but those named in LEFT_OUT and TOOLS with their reasons."""
    assert mutation.selection_gaps() == {}, "add these to their target's tests in tests/mutation.py (or to LEFT_OUT)"
    assert {"tests/test_framing.py", "tests/test_represent.py"} <= mutation.importers(mutation.FRAMING + "fixed.py")
    files, tests = mutation.TARGETS["framing_windows"]
    monkeypatch.setitem(mutation.TARGETS, "framing_windows", (files, [t for t in tests if "represent.py" not in t]))
    assert mutation.selection_gaps() == {"framing_windows": ["tests/test_represent.py"]}


def test_a_kernel_calling_an_intrinsic_with_a_plain_twin_runs_plain_and_calls_the_twin(monkeypatch):
    """An `@intrinsic` named in PLAIN_TWINS does not keep its callers compiled: in the copy they run as plain
    Python (and are mutated), the twin bound to the intrinsic's name. The cascade's target so runs every
    kernel plain but `prefetch`, which the learned features' compiled kernel calls."""
    monkeypatch.setitem(mutation.PLAIN_TWINS, "_vector", "_vector = lambda x: x + 1\n")
    source = ("@intrinsic\ndef _vector(typingctx, x):\n    pass\n\n"
              "@njit(cache=True)\ndef uses(x):\n    return _vector(x)\n")
    assert mutation.kept_compiled({"evstream/a.py": source}, {"evstream/a.py"}) == set()
    plain = mutation.plain_kernels(source)
    assert "@njit" not in plain and plain.endswith("_vector = lambda x: x + 1\n")
    space = {"intrinsic": lambda f: f}
    exec(plain, space)
    assert space["uses"](1) == 2
    copy = mutation.plain_sources("denoise_cascade")
    assert {path for path, src in copy.items() if "@njit" in src} == {mutation.DENOISE + "prefetch.py"}
    assert copy[mutation.DENOISE + "rowsum.py"].count("reference_add(") == 5  # its definition and 4 twins


def test_a_sample_runs_in_the_order_drawn_so_a_run_cut_short_is_a_smaller_sample():
    """`--sample N` runs its mutants in the order drawn: the first m run are `--sample m`'s mutants (the same
    seed, N <= 341 of 1,046 or more), a random sample of the whole, not the first files'."""
    names = [f"evstream.m{k // 300}.x_f__mutmut_{k}" for k in range(2000)]
    for small, large in ((120, 200), (200, 341), (5, 6)):
        assert mutation.sampled(names, large)[:small] == mutation.sampled(names, small)
    first = mutation.sampled(names, 200)[:60]
    assert len({m.split(".")[1] for m in first}) > 3 and first != sorted(first, key=names.index)


def test_a_mutant_of_a_function_no_test_reaches_is_no_tests_at_once(tmp_path):
    """The worker runs a mutant against the tests its clean run saw reach the mutated function. One that no
    test reaches is 'no tests' (a survivor in the score) without running any: no test can kill it, and running
    them all cost a learned mutant the whole selection (~3 min of CPU). A real worker, on a toy module whose
    functions record their calls (in mutmut's stats mode) and misbehave as mutant 1, as mutmut's trampoline does."""
    mutants = tmp_path / "mutants"
    mutants.mkdir()
    (mutants / "toy.py").write_text(textwrap.dedent("""
        import os

        from mutmut.mutation import trampoline


        def _mutated(fn):
            if os.environ.get("MUTANT_UNDER_TEST") == "stats":
                trampoline.record_trampoline_hit(fn)
            return os.environ.get("MUTANT_UNDER_TEST") == fn + "__mutmut_1"


        def f(x):
            return x + 2 if _mutated("toy.x_f") else x + 1


        def g(x):
            return x - 2 if _mutated("toy.x_g") else x - 1
    """))
    (mutants / "test_toy.py").write_text("import toy\n\n\ndef test_f():\n    assert toy.f(1) == 2\n\n\n"
                                         "def test_f_again():\n    assert toy.f(0) == 1\n")
    (tmp_path / "inproc.todo").write_text("toy.x_g__mutmut_1\ntoy.x_f__mutmut_1\n")
    code = (f"import sys; sys.path.insert(0, {str(mutation.ROOT / 'tests')!r}); import mutation; "
            "mutation.TARGETS['toy'] = ([], ['test_toy.py']); sys.exit(mutation.worker('toy'))")
    done = subprocess.run([sys.executable, "-c", code], cwd=mutants, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    verdicts = mutation._verdicts(tmp_path / "inproc.json")
    assert verdicts["toy.x_g__mutmut_1"]["status"] == "no tests" and verdicts["toy.x_g__mutmut_1"]["tests"] == 0
    assert verdicts["toy.x_f__mutmut_1"]["status"] == "killed" and verdicts["toy.x_f__mutmut_1"]["tests"] == 2
    assert mutation.score({m: v["status"] for m, v in verdicts.items()})["counts"] == {"killed": 1, "no tests": 1}


def test_a_plain_kernel_calls_the_plain_form_of_a_compiled_helper_where_its_target_asks():
    """PLAIN_HELPERS: in the learned target's copy the features' plain kernel calls `ix`'s own Python body and
    skips `prefetch` (a hint), not numba's dispatcher (~1 us a call); not where a kernel of the file stays
    compiled (numba would meet a Python function), and not in the other targets' copies."""
    helpers = {"ix": "ix = ix.py_func\n"}
    plain = mutation.plain_kernels("@njit\ndef k(a, i):\n    return a[ix(i)]\n", helpers=helpers)
    assert "@njit" not in plain and plain.endswith("ix = ix.py_func\n")
    kept = mutation.plain_kernels("@njit\ndef k(a, i):\n    return a[ix(i)]\n\n"
                                  "@njit\ndef c(a, i):\n    return a[ix(i)]\n", keep={"c"}, helpers=helpers)
    assert kept.count("@njit") == 1 and "py_func" not in kept
    features = mutation.plain_sources("denoise_learned")[mutation.DENOISE + "learned/features.py"]
    assert features.endswith("ix = ix.py_func\n# tests/mutation.py: the compiled helper's plain form\n"
                             "prefetch = lambda a, i: None\n") and "@njit" not in features
    space = {}
    exec("from evstream.nowrap import ix\nix = ix.py_func\n", space)
    assert space["ix"](5) == 5 and not hasattr(space["ix"], "py_func")
    sources = mutation.package_sources()
    assert all("py_func" not in src for name in mutation.TARGETS if name != "denoise_learned"
               for src in mutation.plain_sources(name, sources).values())
