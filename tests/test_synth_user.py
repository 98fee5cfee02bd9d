"""`evstream synth` and `evstream eval` as a user types them: what synth writes, and flags that cannot work."""

from __future__ import annotations

import pytest

from evstream.cli import main


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("name", ["bar.raw", "bar.h5", "bar"])
def test_synth_to_a_name_of_another_format_is_refused_not_written_as_npz(tmp_path, capsys, name):
    """`synth bar out/bar.raw` wrote a native .npz under a .raw name (Metavision and `info` saw a zip)."""
    code, out, err = run(capsys, "synth", "bar", tmp_path / name, "--duration-ms", "20")
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and name in err and ".npz" in err and "convert" in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("flag, value", [("--seed", "-1"), ("--duration-ms", "0"), ("--duration-ms", "nan"),
                                         ("--noise-ratio", "-1"), ("--noise-ratio", "nan"), ("--hot-share", "-0.5")])
def test_synth_flag_out_of_range_is_a_usage_error_naming_the_flag(tmp_path, capsys, flag, value):
    """Were exit 1 with numpy's words ('expected non-negative integer', 'lam < 0 or lam is NaN')."""
    code, out, err = run(capsys, "synth", "bar", tmp_path / "bar.npz", "--duration-ms", "20", flag, value)
    assert code == 2
    assert err.strip().splitlines() == [err.strip()] and f"{flag} " in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("flag, values", [("--ratios", ["0.5", "-1"]), ("--rates-hz", ["-3"]), ("--ratios", ["nan"])])
def test_eval_noise_levels_out_of_range_are_usage_errors_naming_the_flag(capsys, flag, values):
    """Were exit 1 naming the parameter inside (`noise_ratio must be >= 0, got -1.0`), after reading."""
    code, out, err = run(capsys, "eval", "recordings/bar.npz", "--methods", "stcf", "--seeds", "1", flag, *values)
    assert code == 2 and out == ""
    assert err.strip().splitlines() == [err.strip()] and f"{flag} " in err
