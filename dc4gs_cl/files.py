"""Atomic output: every file and folder dc4gs-cl writes appears complete or not at all.

A file is written under a temporary name beside its final one and renamed into place (a rename within
one folder is atomic); a folder of renders is filled under a temporary name and swapped in whole.
"""
from __future__ import annotations

import json
import os
import secrets
import shutil
import tempfile
from pathlib import Path
from typing import Callable


def temporary_sibling(path: Path, kind: str = "tmp") -> Path:
    """A fresh hidden name beside `path` (same folder, so that a rename onto `path` is atomic), keeping its
    extension, by which writers such as OpenImageIO choose the format."""
    return path.with_name(f".{path.stem}.{secrets.token_hex(4)}.{kind}{path.suffix}")


def write_atomic(path: str | os.PathLike, write: Callable[[Path], None]) -> None:
    """Call write(temporary_path), which creates that file, then move it onto `path`: readers see the old
    file or the new one, and a failed or interrupted write leaves no temporary file behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_sibling(path)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path: str | os.PathLike, data) -> None:
    write_atomic(path, lambda tmp: tmp.write_text(json.dumps(data, indent=2)))


def staging_folder(final: Path) -> Path:
    """An empty hidden folder beside `final`, to be filled and then passed to replace_folder."""
    final.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".staging", dir=final.parent))


def replace_folder(staging: Path, final: Path) -> None:
    """Swap a finished staging folder in as `final`. An existing `final` is renamed aside first and removed
    last, so it is never lost before the new one is in place."""
    old = None
    if final.exists():
        old = temporary_sibling(final, "old")
        os.replace(final, old)
    os.replace(staging, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
