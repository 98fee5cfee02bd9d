"""What a newcomer meets in the first hour (issue 15): progress on a terminal, defaults as the README
shows them, messages that say where to look, archives replayed with their own classes."""

from __future__ import annotations

import json
import os
import pty
import re
import select
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evstream.cli import main

ROOT = Path(__file__).resolve().parents[1]
EVSTREAM = [sys.executable, "-m", "evstream.cli"]


def on_a_terminal(args, cwd, timeout_s=120):
    """Run evstream with stderr on a pseudo-terminal; returns (exit code, what the terminal showed)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(EVSTREAM + args, cwd=cwd, stdout=subprocess.DEVNULL, stderr=slave,
                            env={**os.environ, "COLUMNS": "100"})
    os.close(slave)
    shown = b""
    while True:
        ready, _, _ = select.select([master], [], [], timeout_s)
        if not ready:
            proc.kill()
            pytest.fail(f"evstream {' '.join(args)}: no end after {timeout_s} s")
        try:
            data = os.read(master, 4096)
        except OSError:  # the other end closed
            break
        if not data:
            break
        shown += data
    os.close(master)
    return proc.wait(timeout_s), shown.decode(errors="replace")


@pytest.mark.parametrize("quiet", [False, True])
def test_synth_shows_progress_on_a_terminal_and_none_with_quiet(tmp_path, quiet):
    args = ["synth", "turntable", str(tmp_path / "t.npz"), "--duration-ms", "1500"] + (["--quiet"] if quiet else [])
    rc, shown = on_a_terminal(args, tmp_path)
    assert rc == 0
    if quiet:
        assert shown == ""
    else:
        assert re.search(r"synth turntable +\d+%\|", shown), shown  # a tqdm bar with its percentage


def test_no_progress_when_stderr_is_not_a_terminal(tmp_path):
    r = subprocess.run(EVSTREAM + ["synth", "bar", str(tmp_path / "b.npz"), "--duration-ms", "1500"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stderr == ""


def test_synth_adds_the_noise_the_readme_shows_by_default(tmp_path, capsys):
    """README: `[--noise-ratio 0.5]`; `make recordings` passes 0.5 too. 0 is no noise."""
    from evstream.sources import open_source

    for ratio, args in ((0.5, []), (0.0, ["--noise-ratio", "0"])):
        out = tmp_path / f"b{ratio}.npz"
        assert main(["synth", "bar", str(out), "--duration-ms", "200", *args]) == 0
        labels = np.concatenate([c.label for c in open_source(out)])
        signal, noise = int((labels == 0).sum()), int((labels != 0).sum())
        assert noise == pytest.approx(ratio * signal, rel=0.05, abs=0)
    readme = (ROOT / "README.md").read_text()
    assert "evstream synth turntable|ball|bar OUT.npz [--noise-ratio 0.5]" in readme


def test_eval_outside_the_repository_names_the_folder_and_the_flags(tmp_path, capsys):
    os.chdir(tmp_path)
    try:
        assert main(["eval"]) == 2
    finally:
        os.chdir(ROOT)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert str(tmp_path) in err and "--real DIR" in err and "recordings/*.npz" in err


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """The bar classified by the paper's cascade, noise kept, and the cascade's counts."""
    tmp = tmp_path_factory.mktemp("archive")
    out = tmp / "bar.mcap"
    r = subprocess.run(EVSTREAM + ["archive", str(ROOT / "recordings" / "bar.npz"), str(out), "--keep-noise",
                                   "--json"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout.splitlines()[-1])


def test_replaying_an_archive_keeps_its_stored_classes_unless_asked(archive, tmp_path, capsys):
    path, archived = archive
    assert main(["replay", str(path), "--save", str(tmp_path / "a.rrd"), "--json"]) == 0
    kept = json.loads(capsys.readouterr().out.splitlines()[-1])
    for k in ("events_in", "events_signal", "events_background", "events_hot_pixel"):
        assert kept[k] == archived[k], k
    assert main(["replay", str(path), "--save", str(tmp_path / "b.rrd")]) == 0
    assert "noise classes as stored in the archive (--denoise NAME classifies again)" in capsys.readouterr().out
    assert main(["replay", str(path), "--save", str(tmp_path / "c.rrd"), "--json", "--denoise", "paper"]) == 0
    again = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert again["events_in"] == archived["events_in"]
    assert again["events_signal"] < archived["events_signal"]  # a second cascade over the first one's signal


def test_summary_lines_say_which_folders_were_created(tmp_path, capsys):
    rec = str(ROOT / "recordings" / "bar.npz")
    assert main(["convert", rec, str(tmp_path / "a" / "b" / "bar.raw")]) == 0
    assert f"(created folder {tmp_path / 'a'}/)" in capsys.readouterr().out
    assert main(["convert", rec, str(tmp_path / "a" / "b" / "bar2.raw")]) == 0
    assert "created" not in capsys.readouterr().out  # there already
    assert main(["archive", rec, str(tmp_path / "m" / "bar.mcap")]) == 0
    assert f"(created folder {tmp_path / 'm'}/)" in capsys.readouterr().out
    assert main(["frames", rec, "--framer", "fw", "--denoise", "none", "--out", str(tmp_path / "f")]) == 0
    assert f"(created folder {tmp_path / 'f'}/)" in capsys.readouterr().out
    assert main(["synth", "bar", str(tmp_path / "s" / "bar.npz"), "--duration-ms", "100"]) == 0
    assert f"(created folder {tmp_path / 's'}/)" in capsys.readouterr().out
    assert main(["replay", rec, "--save", str(tmp_path / "r" / "bar.rrd"), "--denoise", "none"]) == 0
    assert f"(created folder {tmp_path / 'r'}/)" in capsys.readouterr().out


def test_tests_that_need_the_real_recordings_say_how_to_give_them():
    from conftest import REAL_DATA, real_data_skip_reason

    assert "EVSTREAM_REAL_DATA" in real_data_skip_reason() and str(REAL_DATA) in real_data_skip_reason()
    assert "EVSTREAM_REAL_DATA" in (ROOT / "README.md").read_text()


def test_the_ssh_tunnel_advice_names_both_ports_of_the_web_viewer():
    """`--serve` needs the web page's port and the gRPC port the page streams from."""
    from evstream.sinks import rerun_viewer

    readme = (ROOT / "README.md").read_text()
    advice = readme[readme.index("ssh -L"):][:400]
    for port in (rerun_viewer.DEFAULT_WEB_PORT, rerun_viewer.DEFAULT_GRPC_PORT):
        assert f"{port}:127.0.0.1:{port}" in advice


def test_every_argument_of_every_command_says_what_it_is():
    """`evstream info --help` listed `source` with nothing beside it (so did replay and publish; archive's and
    convert's OUT; synth's scene, --seed, --duration-ms, --width, --height)."""
    import argparse

    from evstream.cli import parser

    commands = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    silent = {name: [a.option_strings[0] if a.option_strings else a.dest for a in p._actions
                     if not a.help and a.dest != "help"] for name, p in commands.items()}
    assert {name: args for name, args in silent.items() if args} == {}
    said = commands["info"].format_help()
    assert "\n  REC " in said and "a recording, any format evstream reads" in said
