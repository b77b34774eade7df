"""User-facing errors: each names the file (or setting) at fault and the problem in one line.

The CLI turns any `InputError` into that line on stderr and a non-zero exit; everything else is a bug
and keeps its traceback.
"""
from __future__ import annotations

import os


class InputError(Exception):
    """Bad input from the user: a missing or malformed file, or settings that make no sense."""

    def __init__(self, path: str | os.PathLike | None, problem: str):
        self.path = None if path is None else os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path is not None else problem)


class OutputError(InputError):
    """An output that cannot be written (disk full, read-only folder, ...): named like bad input, but the
    CLI exits 1, as the fault is the machine's, not the user's input. Earlier outputs are left intact."""


class DeviceError(Exception):
    """No usable OpenCL platform or device, or a kernel failed to build (the message holds the build log)."""
