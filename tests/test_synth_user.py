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


@pytest.mark.parametrize("argv", [["convert", "recordings/bar.npz", "{out}/x.raw"],
                                  ["archive", "recordings/bar.npz", "{out}/sub/x.mcap"],
                                  ["replay", "recordings/bar.npz", "--save", "{out}/x.rrd"],
                                  ["synth", "bar", "{out}/x.npz", "--duration-ms", "20"]])
def test_an_output_in_a_folder_that_is_a_file_says_so_in_one_line(tmp_path, capsys, argv):
    """An output's folder that is a regular file (a typo, a name reused) was Python's '[Errno 17] File
    exists: ...'; the file stays as it was."""
    a_file = tmp_path / "notes"
    a_file.write_text("mine")
    code, out, err = run(capsys, *[a.format(out=a_file) for a in argv])
    assert code == 1
    assert err.strip().splitlines() == [err.strip()]
    assert err.startswith(f"evstream: error: {a_file}: is a file, not a folder")
    assert "Errno" not in err and a_file.read_text() == "mine"


@pytest.mark.parametrize("argv, folder", [(["frames", "recordings/bar.npz", "--out", "{f}"], "{f}"),
                                          (["frames", "recordings/bar.npz", "--out", "{f}/png"], "{f}/png"),
                                          (["frames", "recordings/bar.npz", "--out", "{f}/a/b"], "{f}/a/b"),
                                          (["train", "recordings/bar.npz", "--out", "{f}/m.npz"], "{f}"),
                                          (["calibrate", "recordings/bar.npz", "--out", "{f}/x/m.npz"], "{f}/x")])
def test_frames_and_train_out_in_a_file_say_so_as_the_other_commands_do(tmp_path, capsys, argv, folder):
    """`frames --out FILE/png` said Python's '[Errno 17] File exists: FILE' ('[Errno 20] Not a directory' one
    folder deeper), `--out FILE` 'FILE: is a file, not a folder' without the output's folder; `train --out
    FILE/m.npz` 'folder FILE does not exist' (exit 2): it exists, as a file. Now the other commands' line."""
    a_file = tmp_path / "notes"
    a_file.write_text("mine")
    code, out, err = run(capsys, *[a.format(f=a_file) for a in argv])
    assert code == 1
    folder = folder.format(f=a_file)
    assert err == f"evstream: error: {a_file}: is a file, not a folder (the output's folder is {folder})\n"
    assert a_file.read_text() == "mine" and sorted(tmp_path.iterdir()) == [a_file]
