"""The built wheel, installed into a fresh venv, is all a user gets: evstream and nothing named `sources` or
`sinks`; `evstream --help`, the API and the examples work there.

The fresh venv has no evstream but the wheel's: the project tree is not on its path (it runs from a
temporary directory), the test venv's editable install is not active in it (its `.pth` hook lives in a
site directory the fresh venv does not process), and it sees the test venv's site-packages only through a
path line, for the dependencies (installing numba, rerun-sdk, ... again would take minutes and the network).
"""

import json
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

import evstream

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("pyproject.toml", "README.md", "evstream", "sources", "sinks")  # what the build reads


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"  # a copy: a build in the tree would leave build/ and *.egg-info there
    src.mkdir()
    for name in SHIPPED:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
        else:
            shutil.copy2(ROOT / name, src / name)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", tmp / "dist", src],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    (wheel,) = (tmp / "dist").glob("evstream-*.whl")
    env = tmp / "venv"
    venv.EnvBuilder(with_pip=False).create(env)
    python = env / "bin" / "python"
    site = Path(subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "deps-from-the-test-venv.pth").write_text(sysconfig.get_path("purelib") + "\n")
    r = subprocess.run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--quiet", wheel],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    work = tmp / "work"  # the current directory of every command: not the tree
    work.mkdir()
    return {"wheel": wheel, "env": env, "python": python, "site": site, "work": work}


def run(installed, *argv, **kw):
    return subprocess.run([*map(str, argv)], cwd=installed["work"], capture_output=True, text=True, timeout=600, **kw)


def test_the_wheel_holds_evstream_only(installed):
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"evstream"}
    tree = {f"evstream/{p.relative_to(ROOT / 'evstream').as_posix()}" for p in (ROOT / "evstream").rglob("*.py")}
    for folder in ("sources", "sinks"):
        tree |= {f"evstream/{folder}/{p.name}" for p in (ROOT / folder).glob("*.py")}
    assert sorted(tree - set(names)) == []  # every module of the tree ships (a package left out of pyproject did not)


def test_import_sources_fails_and_evstream_is_the_wheels(installed):
    for name in ("sources", "sinks"):
        r = run(installed, installed["python"], "-c", f"import {name}")
        assert r.returncode == 1 and f"No module named '{name}'" in r.stderr
    r = run(installed, installed["python"], "-c",
            "import evstream, evstream.sources, evstream.cli\n"
            "print(evstream.__file__)\nprint(evstream.sources.__file__)")
    assert r.returncode == 0, r.stderr
    for line in r.stdout.split():
        assert Path(line).is_relative_to(installed["site"]), line  # not the tree, not an editable finder


def test_the_command_line_runs_from_the_wheel(installed):
    r = run(installed, installed["env"] / "bin" / "evstream", "--help")
    assert r.returncode == 0 and "replay" in r.stdout and "stages" in r.stdout
    r = run(installed, installed["env"] / "bin" / "evstream", "info", ROOT / "recordings" / "bar.npz", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["events"] == evstream.info(ROOT / "recordings" / "bar.npz")["events"]


def test_the_api_and_examples_run_from_the_wheel(installed):
    bar = ROOT / "recordings" / "bar.npz"
    script = f"""
import json, numpy as np, evstream
events = evstream.read({str(bar)!r})
classes = evstream.classify("paper", events)
with evstream.open_sink("clean.mcap", geometry=events.geometry) as sink:
    sink.write(evstream.clean("paper", events))
archived = evstream.info("clean.mcap")["events"]
print(json.dumps({{"classes": np.bincount(classes, minlength=3).tolist(), "archived": archived}}))
"""
    r = run(installed, installed["python"], "-c", script)
    assert r.returncode == 0, r.stderr
    want = evstream.classify("paper", evstream.read(bar))
    got = json.loads(r.stdout)
    assert got["classes"] == [int((want == c).sum()) for c in range(3)] and got["archived"] == got["classes"][0]
    r = run(installed, installed["python"], ROOT / "examples" / "replay_count.py", bar)
    assert r.returncode == 0, r.stderr
    assert f"signal      {int((want == 0).sum()):>10,}" in r.stdout
