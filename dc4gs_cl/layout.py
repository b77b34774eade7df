"""Host/device records, each written once: an ordered list of named fields of 4-byte lanes.

A `Record` is the one description both sides use:
- rows of per-Gaussian arrays (the backward's sums, the densification window, the split geometry): the
  kernels index a row by the field offsets the record emits as -D defines, `<PREFIX>_<FIELD>` and
  `<PREFIX>_WIDTH`; the host reads the same rows through `views()`;
- structs passed to a kernel by value (the camera, Adam's step): `c_struct()` writes the C typedef the
  kernels include (kernels/records.h is generated from these records, see runtime.kernel_source), and
  `pack()` fills the NumPy value pyopencl sends. All lanes are 4 bytes, so the C struct has no padding
  and its layout is the NumPy dtype's (tests/test_layout.py checks it on the device).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LANE_TYPES = {"float": np.float32, "int": np.int32, "uint": np.uint32}


@dataclass(frozen=True)
class Field:
    name: str
    width: int = 1            # lanes
    lane: str = "float"       # float, int or uint


class Record:
    """Named fields of 4-byte lanes, in order. Equal records (same prefix and fields) are interchangeable:
    they hash alike, so kernels built for one serve the other."""

    def __init__(self, prefix: str, fields: list[Field | tuple[str, int]]):
        self.prefix = prefix
        self.fields = tuple(f if isinstance(f, Field) else Field(*f) for f in fields)
        names = [f.name for f in self.fields]
        if len(set(names)) != len(names):
            raise ValueError(f"record {prefix}: a field name repeats in {names}")
        if any(f.width < 1 or f.lane not in LANE_TYPES for f in self.fields):
            raise ValueError(f"record {prefix}: widths must be >= 1 and lanes one of {tuple(LANE_TYPES)}")
        self.offsets, at = {}, 0
        for f in self.fields:
            self.offsets[f.name] = at
            at += f.width
        self.width = at

    def __eq__(self, other) -> bool:
        return isinstance(other, Record) and (self.prefix, self.fields) == (other.prefix, other.fields)

    def __hash__(self) -> int:
        return hash((self.prefix, self.fields))

    def __repr__(self) -> str:
        return f"Record({self.prefix}: " + ", ".join(f"{f.name}[{f.width}]" for f in self.fields) + ")"

    def __contains__(self, name: str) -> bool:
        return name in self.offsets

    def widths(self) -> dict[str, int]:
        return {f.name: f.width for f in self.fields}

    # rows --------------------------------------------------------------------------------------------
    def defines(self) -> dict[str, int]:
        """<PREFIX>_<FIELD> = the field's first lane, <PREFIX>_WIDTH = lanes per row."""
        out = {f"{self.prefix}_{name.upper()}": at for name, at in self.offsets.items()}
        out[f"{self.prefix}_WIDTH"] = self.width
        return out

    def views(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        """(n, width) rows -> name: (n,) for one-lane fields, (n, width) otherwise (views, not copies)."""
        return {f.name: rows[:, self.offsets[f.name]] if f.width == 1
                else rows[:, self.offsets[f.name]:self.offsets[f.name] + f.width] for f in self.fields}

    def rows(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """The inverse of views: name -> (n,) or (n, width) arrays -> (n, width) float32 rows."""
        n = len(next(iter(values.values())))
        return np.concatenate([np.asarray(values[f.name], np.float32).reshape(n, f.width) for f in self.fields], 1)

    # structs passed by value --------------------------------------------------------------------------
    @property
    def dtype(self) -> np.dtype:
        return np.dtype([(f.name, LANE_TYPES[f.lane]) if f.width == 1 else (f.name, LANE_TYPES[f.lane], f.width)
                         for f in self.fields])

    def c_struct(self, type_name: str) -> str:
        members = "".join(f"    {f.lane} {f.name}{'' if f.width == 1 else f'[{f.width}]'};\n" for f in self.fields)
        return f"typedef struct {{\n{members}}} {type_name};\n"

    def pack(self, **values) -> np.void:
        """One struct value for a kernel argument; fields not given are zero."""
        unknown = set(values) - set(self.offsets)
        if unknown:
            raise ValueError(f"record {self.prefix} has no field {sorted(unknown)}")
        v = np.zeros(1, self.dtype)
        for name, value in values.items():
            v[name] = value
        return v[0]
