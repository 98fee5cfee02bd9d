"""The framer flags every command shares (evstream/framing/options.py), parsed in-process."""

from __future__ import annotations

import argparse

import pytest

from evstream.framing import FixedWindow
from evstream.framing.options import PARAM_FLAGS, add_framer_flags, framer_kinds, framer_spec, framers_from_args

KINDS = "fw|fn|oa|adaptive|timesurface|voxel|histogram|count|timestamp"


def _parser(**kw) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="x", formatter_class=lambda prog: argparse.HelpFormatter(prog, width=10_000))
    add_framer_flags(p, **kw)
    return p


def test_one_framer_flags_default_to_none_and_say_so():
    p = _parser()
    a = p.parse_args([])
    assert a.framer == "none" and framers_from_args(a) == [] and not a.all_events
    assert all(getattr(a, name) is None for name, _, _ in PARAM_FLAGS.values())
    text = " ".join(p.format_help().split())
    assert f"--framer {KINDS}|none " in text and "; default none" in text and "comma-separated" not in text
    assert "build frames from every event, not only those classed SIGNAL" in text
    for _, _, help_text in PARAM_FLAGS.values():
        assert " ".join(help_text.split()) in text


def test_several_framers_take_a_list():
    p = _parser(default="fw", several=True)
    text = " ".join(p.format_help().split())
    assert f"--framer {KINDS}[,...] " in text and "(comma-separated to compare); default fw" in text
    a = p.parse_args(["--framer", "fw,fn", "--window-us", "2000", "--all-events"])
    fw, fn = framers_from_args(a)
    assert (fw.kind, fw.window_us, fw.all_events, fn.kind, fn.all_events) == ("fw", 2000, True, "fn", True)


@pytest.mark.parametrize("spec, message", [
    ("fw,bogus", "--framer fw,bogus: unknown framer bogus; choose from "),
    ("a,b", "--framer a,b: unknown framer a, b; choose from "),
    (",", "--framer ,: unknown framer (empty); choose from "),
])
def test_unknown_framers_are_named(spec, message):
    with pytest.raises(ValueError) as e:
        framer_kinds(argparse.Namespace(framer=spec))
    assert str(e.value).startswith(message)


def test_framer_spec_takes_all_events_only_when_given():
    assert framer_spec("fw", argparse.Namespace(window_us=5)) == {"kind": "fw", "window_us": 5}  # no all_events
    assert framer_spec("fw", argparse.Namespace(all_events=True)) == {"kind": "fw", "all_events": True}


def test_a_whole_float_is_taken_as_an_int():
    fw = FixedWindow(window_us=1000.0)
    assert fw.window_us == 1000 and type(fw.window_us) is int


def test_a_flag_no_chosen_framer_has_is_named():
    p = _parser()
    with pytest.raises(ValueError, match=r"^--window-us does not apply to --framer none$"):
        framers_from_args(p.parse_args(["--window-us", "5"]))
    with pytest.raises(ValueError, match=r"^--tau-us, --bins does not apply to --framer fw$"):
        framers_from_args(p.parse_args(["--framer", "fw", "--bins", "3", "--tau-us", "9"]))


def test_the_flags_helps_read_whole():
    helps = {a.dest: a.help for a in _parser()._actions}
    assert helps["framer"] == ("framer: fixed window, fixed count, overlapping accumulation, the paper's adaptive "
                               "overlap, or a representation over one of those (--window); default none")
    assert helps["all_events"] == "build frames from every event, not only those classed SIGNAL"


def test_a_command_without_the_framer_flags_has_no_framer():
    """A command whose parser has no framer flags (its namespace lacks them) builds no framer."""
    args = argparse.Namespace()
    assert framer_kinds(args) == [] and framers_from_args(args) == []
    assert [f.params() for f in framers_from_args(argparse.Namespace(framer="fw"))] == [FixedWindow().params()]
