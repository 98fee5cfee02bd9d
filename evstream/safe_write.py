"""Writing an output without destroying anything: the one way every writer (archive, convert, replay
--save, frames --out, subscribe --archive) puts a file in place.

- An output that is one of the inputs, by file identity (device and inode: hard and symbolic links
  included), is refused before anything is opened (`OutputIsInput`).
- Bytes go to a temporary file beside the target, created exclusively (`TARGET.part`, or
  `TARGET.N.part` when that name is taken), so the temporary is never an existing file — not an
  input, not the partial output of an earlier run — and is renamed onto the target only when whole.
- A failed run leaves the target as it was. Its partial output is removed, or kept when the writer
  asks (an MCAP archive closed after an error is readable up to it); the error then says where.
- A full disk is one error naming the target: "no space left on the device"; a folder that cannot be
  written (read-only, no permission) too: "TARGET: cannot write there: REASON" (`cannot_write`).

A killed process leaves its temporary where it was (`TARGET.part`): what it wrote so far, the target
untouched. A run cut short on purpose (Ctrl-C in a file command) closes its output properly and sets it
aside (`set_aside`) as `STEM.partial.EXT` (`STEM.partial.N.EXT` when taken): readable by every tool that
reads EXT, named so that nobody takes it for the whole output; the target is left as it was, or absent.

A target that is a device or a named pipe (`--json /dev/null`, `/dev/stdout`, a FIFO another process reads)
is written into, as `cp` does: there is no file to keep, and a rename would put a regular file in its place
(as root, over /dev/null itself).
"""

from __future__ import annotations

import errno
import os
import stat
import weakref
from pathlib import Path

__all__ = ["AtomicFolder", "AtomicOutput", "OutputIsInput", "being_read", "cannot_write", "check_not_input",
           "is_no_space", "is_special", "no_space_error", "numbered_name", "partial_name", "probe_writable", "reading"]

_NO_SPACE = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC), errno.EFBIG}
_MAX_PART_NAMES = 1000


class OutputIsInput(ValueError):
    """The output is (a link to) an input file: writing it would destroy what is being read."""


def _identity(path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def check_not_input(target, inputs, flag: str = "", what: str = "the input recording") -> None:
    """Raise `OutputIsInput` when `target` exists and is the same file as one of `inputs` (`what` they are)."""
    mine = _identity(target)
    if mine is None:
        return
    for path in inputs:
        if path is not None and _identity(path) == mine:
            raise OutputIsInput(f"{flag}{os.fspath(target)}: that is {what}; "
                                "writing there would destroy it")


# Recordings this process has open for reading (`evstream.open`), weakly: a source that is gone no longer
# counts. `evstream.open_sink` refuses to write over any of them, so a script cannot destroy the recording
# it reads, whether or not it says what it reads.
_READING: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def reading(source, path) -> None:
    """Note that `source` (an object alive while it is being read) reads the file `path`."""
    try:
        _READING[source] = os.fspath(path)
    except TypeError:  # an object that cannot be weakly referenced: not tracked
        pass


def being_read() -> list[str]:
    """The files of the sources opened with `evstream.open` that are still alive in this process."""
    return list(_READING.values())


def is_no_space(e: BaseException) -> bool:
    """Whether `e` says the disk (or the quota, or the largest file size) is full."""
    while e is not None:
        if isinstance(e, OSError) and e.errno in _NO_SPACE:
            return True
        if "No space left on device" in str(e) or "os error 28" in str(e):
            return True
        e = e.__cause__ or e.__context__
    return False


def no_space_error(target) -> OSError:
    """The one-line error for a full disk, naming the file that could not be written."""
    e = OSError(f"{os.fspath(target)}: no space left on the device; nothing written there "
                "(an earlier file of that name is left as it was)")
    e.errno = errno.ENOSPC
    return e


def cannot_write(target, e: OSError) -> OSError:
    """The one-line error for an output that cannot be created (a read-only disk or folder, no permission,
    a full disk), naming the target, not its temporary."""
    if is_no_space(e):
        return no_space_error(target)
    error = OSError(f"{os.fspath(target)}: cannot write there: {e.strerror or e}")
    error.errno = e.errno
    return error


def file_in_the_way(folder) -> Path | None:
    """The file (not a folder) that stands where `folder` or one of its parents would be, if any."""
    folder = Path(os.fspath(folder))
    return next((f for f in (folder, *folder.parents) if f.exists() and not f.is_dir()), None)


def not_a_folder(folder) -> NotADirectoryError:
    """The one-line error for an output folder with a file in its way: "FILE: is a file, not a folder (the
    output's folder is FOLDER)" (Python said "[Errno 17] File exists: 'FILE'" or "[Errno 20] Not a directory")."""
    return NotADirectoryError(f"{file_in_the_way(folder) or os.fspath(folder)}: is a file, not a folder "
                              f"(the output's folder is {os.fspath(folder)})")


def make_folder(folder) -> None:
    """`folder` and its parents, made where missing; a file in their way is `not_a_folder`."""
    try:
        Path(os.fspath(folder)).mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise not_a_folder(folder) from None


def probe_writable(target, flag: str = "") -> None:
    """Before minutes of work: `target` can be created (its folder made if need be), else one line
    ("FLAG TARGET: cannot write there: REASON"); only a probe, no file left behind."""
    target = Path(target)
    try:
        if not target.parent.exists():
            target.parent.mkdir(parents=True)
        existed = target.exists()
        open(target, "a").close()
        if not existed:
            target.unlink()
    except OSError as e:
        raise OSError(f"{flag}{os.fspath(target)}: cannot write there: {e.strerror or e}") from None


def is_special(path: Path) -> bool:
    """`path` (through its links) is there and is neither a regular file nor a folder: a device, a pipe."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _create_part(target: Path, folder: bool = False) -> Path:
    """A new, empty file (or `folder`) beside `target` that did not exist before (O_EXCL, mkdir): TARGET.part,
    TARGET.1.part, ..."""
    for n in range(_MAX_PART_NAMES):
        part = target.with_name(f"{target.name}.part" if n == 0 else f"{target.name}.{n}.part")
        try:
            if folder:
                part.mkdir()
            else:
                os.close(os.open(part, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        except OSError as e:  # Python's "[Errno 30] ...: 'TARGET.part'" named a file the user never typed
            raise cannot_write(target, e) from None
        return part
    raise OSError(f"{target}: {_MAX_PART_NAMES} temporary {'folders' if folder else 'files'} {target.name}.N.part "
                  "are in the way; remove them")


def partial_name(target, n: int = 0) -> Path:
    """Where a run cut short keeps its output: `STEM.partial.EXT` (n > 0: `STEM.partial.N.EXT`), so that the
    extension still says the format (viewers pick their loader by it) and the name says it is not whole."""
    target = Path(os.fspath(target))
    middle = ".partial" if n == 0 else f".partial.{n}"
    return target.with_name(f"{target.stem}{middle}{target.suffix}")


def numbered_name(target, n: int) -> Path:
    """`STEM.N.EXT` beside `target` (n = 0: the target itself): where an output that must not replace an
    earlier file goes (`AtomicOutput(keep_existing=True)`)."""
    target = Path(os.fspath(target))
    return target if n == 0 else target.with_name(f"{target.stem}.{n}{target.suffix}")


class AtomicOutput:
    """A temporary file `part` beside `target`; `commit()` renames it onto the target, `discard()` removes
    it (or keeps it, with `keep_partial`). As a context manager: commit on success, discard on error,
    with a full disk said as one line naming the target. `keep_existing`: the target is a name the
    program chose, not the user: a file already there is left as it is and the output goes to the first
    free `STEM.N.EXT` (`.target` then says where; `.taken` is the name that was in use).

        with AtomicOutput("out.mcap", inputs=["rec.raw"]) as part:
            write_everything_to(part)
    """

    def __init__(self, target, inputs=(), *, keep_partial: bool = False, flag: str = "", sync: bool = True,
                 keep_existing: bool = False):
        self.sync = sync  # flush the bytes to the disk before the rename (survives a power cut too)
        self.keep_existing = keep_existing
        self.taken: Path | None = None
        self.target = Path(os.fspath(target))
        self.inputs = [os.fspath(p) for p in inputs if p is not None]
        self.keep_partial = keep_partial
        check_not_input(self.target, self.inputs, flag)
        if self.target.is_dir():
            raise IsADirectoryError(f"{flag}{self.target}: is a directory")
        self.direct = is_special(self.target)  # a device or a pipe: written into, never renamed over
        self.part = self.target if self.direct else _create_part(self.target)
        self.kept: Path | None = None  # the partial output, when a failure kept it
        self.done = False

    def commit(self) -> Path:
        """Put the whole output in place: flush it to the disk, then rename it onto the target."""
        if self.done or self.direct:
            self.done = True
            return self.target
        check_not_input(self.target, self.inputs)  # a link made to an input meanwhile
        try:
            if self.sync:
                fd = os.open(self.part, os.O_RDONLY)
                try:
                    os.fsync(fd)  # the rename must not reach the disk before the bytes do
                finally:
                    os.close(fd)
            if self.keep_existing:
                self._link_to_a_free_name()
            else:
                os.replace(self.part, self.target)
        except OSError as e:
            self.discard()
            if is_no_space(e):
                raise no_space_error(self.target) from None
            raise
        self.done = True
        return self.target

    def _link_to_a_free_name(self) -> None:
        """The whole output under the target's name or, when a file has it, the first free STEM.N.EXT: a hard
        link never replaces a file (one made meanwhile by another process included)."""
        wanted = self.target
        for n in range(_MAX_PART_NAMES):
            name = numbered_name(wanted, n)
            try:
                os.link(self.part, name)
            except FileExistsError:
                continue
            except OSError:  # no hard links here: a rename onto a name free a moment ago
                if os.path.lexists(name):
                    continue
                os.replace(self.part, name)
            else:
                self.part.unlink(missing_ok=True)
            self.taken = wanted if n else None
            self.target = name
            return
        raise OSError(f"{wanted}: {_MAX_PART_NAMES} files {wanted.stem}.N{wanted.suffix} are in the way; remove some")

    def set_aside(self) -> Path:
        """The run was cut short on purpose (Ctrl-C) and its output closed whole up to there: keep it under a
        new name, `partial_name(target)` (created by a hard link, so never over an existing file), and leave
        the target as it was. Where hard links are not possible the output stays at `part`. Returns where
        it is."""
        if self.done or self.direct:
            self.done = True
            return self.kept or self.target
        self.done = True
        self.kept = self.part
        for n in range(_MAX_PART_NAMES):
            name = partial_name(self.target, n)
            try:
                os.link(self.part, name)
            except FileExistsError:
                continue
            except OSError:  # no hard links here (some network or FAT file systems): keep TARGET.part
                return self.part
            self.part.unlink(missing_ok=True)
            self.kept = name
            break
        return self.kept

    def discard(self, keep: bool | None = None) -> Path | None:
        """Remove the temporary (or keep it when `keep`, default `keep_partial`, and it holds bytes);
        returns the kept path or None. The target is not touched."""
        if self.done or self.direct:  # a device's bytes are gone, and the device must stay
            self.done = True
            return self.kept
        self.done = True
        keep = self.keep_partial if keep is None else keep
        try:
            if keep and self.part.stat().st_size > 0:
                self.kept = self.part
                return self.part
        except OSError:
            pass
        self.part.unlink(missing_ok=True)
        return None

    def failed(self, e: BaseException) -> BaseException:
        """Discard after `e` and return the error to raise: a full disk as one line naming the target (its
        partial output removed: it is cut short and takes the space), else `e` saying where the partial
        output is, if kept."""
        if is_no_space(e):
            self.discard(keep=False)
            return no_space_error(self.target)
        kept = self.discard()
        if kept is not None and isinstance(e, KeyboardInterrupt) and not e.args:  # a second Ctrl-C
            e.args = (f"{self.target} left as it was; the output up to there is in {kept}",)
        elif kept is not None and len(e.args) == 1 and isinstance(e.args[0], str) and isinstance(e, Exception):
            e.args = (f"{e.args[0]} ({self.target} left as it was; the output up to there is in {kept})",)
        return e

    def __enter__(self) -> Path:
        return self.part

    def __exit__(self, kind, e, tb) -> bool:
        if e is None:
            self.commit()
            return False
        raised = self.failed(e)
        if raised is not e:
            raise raised from None
        return False


class AtomicFolder:
    """A folder of outputs (`frames --out DIR`: one file per frame) written whole or not at all: the files
    go to a new folder beside the target (`DIR.part/`, `DIR.N.part/`, created exclusively) and are moved
    into DIR only when the run succeeded. There they replace the files of the same kind from an earlier
    run (`replaces`, e.g. "frame_*.png": no stale frames past the new last one); other files in DIR are
    not touched. A failed run removes its folder: DIR as it was, and no DIR at all if there was none.

        with AtomicFolder("out/frames", replaces=("frame_*.png",)) as part:
            write_frames_into(part)
    """

    def __init__(self, target, replaces=()):
        self.target = Path(os.fspath(target))
        self.replaces = tuple(replaces)
        if file_in_the_way(self.target):
            raise not_a_folder(self.target)
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.part = _create_part(self.target, folder=True)
        self.done = False

    def commit(self) -> Path:
        """Move every file written into the target (folders as they were laid out), remove the files of
        `replaces` the run did not write again, then the temporary folder."""
        if self.done:
            return self.target
        import shutil

        try:
            written: dict[Path, set[str]] = {}
            for folder, _, files in os.walk(self.part):
                rel = Path(folder).relative_to(self.part)
                dest = self.target / rel
                dest.mkdir(parents=True, exist_ok=True)
                written[dest] = set(files)
                for name in files:
                    os.replace(Path(folder) / name, dest / name)
            for dest, names in written.items():  # only in folders this run wrote files into
                for pattern in self.replaces if names else ():
                    for old in dest.glob(pattern):
                        if old.name not in names and old.is_file():
                            old.unlink()
        except OSError as e:
            if is_no_space(e):
                raise no_space_error(self.target) from None
            raise
        finally:
            shutil.rmtree(self.part, ignore_errors=True)
            self.done = True
        return self.target

    def discard(self) -> None:
        """Remove the temporary folder and what is in it; the target is not touched."""
        import shutil

        if not self.done:
            shutil.rmtree(self.part, ignore_errors=True)
            self.done = True

    def __enter__(self) -> Path:
        return self.part

    def failed(self, e: BaseException) -> BaseException:
        """After an error: the temporary folder removed; the error to raise (a full disk said of the target
        folder, not of a file in the temporary one, which is gone)."""
        self.discard()
        if not is_no_space(e):
            return e
        error = OSError(f"{self.target}: no space left on the device; nothing written there (what the folder "
                        "held is left as it was)")
        error.errno = errno.ENOSPC
        return error

    def __exit__(self, kind, e, tb) -> bool:
        if e is None:
            self.commit()
            return False
        raised = self.failed(e)
        if raised is not e:
            raise raised from None
        return False
