"""Atomic output: every file and folder dc4gs-cl writes appears complete or not at all.

A file is written under a temporary name beside its final one and renamed into place (a rename within
one folder is atomic); a folder of renders is filled under a temporary name and swapped in whole.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Callable

try:
    import fcntl
except ImportError:   # Windows
    fcntl = None

from .errors import OutputError


# temporary_sibling's names; the marker makes them ours alone (a user's .checkpoint.0123abcd.tmp.npz was removed
# by the next run when the pattern was only a hex token and "tmp")
TEMPORARY_MARKER = "dc4gs"
TEMPORARY_NAME = re.compile(rf"\..+\.[0-9a-f]{{8}}\.{TEMPORARY_MARKER}-(tmp|old)(\.[A-Za-z0-9]+)?")


def temporary_sibling(path: Path, kind: str = "tmp") -> Path:
    """A fresh hidden name beside `path` (same folder, so that a rename onto `path` is atomic), keeping its
    extension, by which writers such as OpenImageIO choose the format."""
    return path.with_name(f".{path.stem}.{secrets.token_hex(4)}.{TEMPORARY_MARKER}-{kind}{path.suffix}")


def is_temporary(path: Path) -> bool:
    """Whether a file's name is one temporary_sibling gives."""
    return TEMPORARY_NAME.fullmatch(path.name) is not None


def check_replaceable(path: Path, folder: bool = False) -> None:
    """OutputError where `path` exists as something an output must never replace: a device, FIFO or socket
    (`export --out /dev/full` once replaced the device node with a regular file), or a folder where a file goes
    (a file where a folder goes). A symbolic link is replaced itself, never followed."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise OutputError(path, f"cannot write: {e.strerror or e}") from e
    if stat.S_ISLNK(mode) or (stat.S_ISDIR(mode) if folder else stat.S_ISREG(mode)):
        return
    kind = ("a folder" if stat.S_ISDIR(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "a file")
    raise OutputError(path, f"is {kind}, not a {'folder' if folder else 'regular file'}: refusing to replace it")


def write_atomic(path: str | os.PathLike, write: Callable[[Path], None], keep_previous: Path | None = None) -> None:
    """Call write(temporary_path), which creates that file, then move it onto `path`: readers see the old
    file or the new one, and a failed or interrupted write leaves no temporary file behind.
    keep_previous: once the new file is complete, the old `path` is moved there instead of being replaced.
    A failing write (disk full, read-only folder, ...) raises OutputError naming `path`, and so does a `path`
    that is not a regular file (check_replaceable), before anything is written."""
    path = Path(path)
    check_replaceable(path)
    tmp = temporary_sibling(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        if keep_previous is not None and path.exists():
            os.replace(path, keep_previous)
        os.replace(tmp, path)
    except OSError as e:
        _remove(tmp)
        raise OutputError(path, f"cannot write: {e.strerror or e}") from e
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: Path) -> None:
    """Remove a temporary file if there is one; where its folder cannot exist (a file in the way) neither can it."""
    with contextlib.suppress(OSError):
        tmp.unlink()


def write_json(path: str | os.PathLike, data) -> None:
    write_atomic(path, lambda tmp: tmp.write_text(json.dumps(data, indent=2)))


def staging_folder(final: Path) -> Path:
    """An empty hidden folder beside `final`, to be filled and then passed to replace_folder (OutputError where
    `final` is something else than a folder: check_replaceable)."""
    check_replaceable(final, folder=True)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".staging", dir=final.parent))
    except OSError as e:
        raise OutputError(final, f"cannot write: {e.strerror or e}") from e


def replace_folder(staging: Path, final: Path) -> None:
    """Swap a finished staging folder in as `final`. An existing `final` is renamed aside first and removed
    last, so it is never lost before the new one is in place."""
    old = None
    try:
        if final.exists():
            old = temporary_sibling(final, "old")
            os.replace(final, old)
        os.replace(staging, final)
    except OSError as e:
        raise OutputError(final, f"cannot write: {e.strerror or e}") from e
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def exclusive_lock(lock: Path, busy: Callable[[str], Exception]):
    """Hold the file `lock` for the block (an exclusive flock on it, the holder's PID written in it); where
    another process holds it, raise busy(that PID). The OS lets go when the process ends, however it ends. (No
    lock on Windows.)"""
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise OutputError(lock.parent, f"cannot be written ({e.strerror})") from e
    try:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                raise busy(os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)
