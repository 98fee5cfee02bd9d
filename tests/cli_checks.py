"""Checks shared by the tests that run `evstream` the way a user does."""


def one_line_error(err: str) -> str:
    """The one non-blank line of `err`: an error a user reads, not a traceback or a Rust panic."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "internal error" not in lines[0] and "Traceback" not in err and "panicked" not in err, err
    return lines[0]
