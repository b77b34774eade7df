"""The standard 3DGS PLY: what the Inria code writes (with `plyfile`) and viewers read.

One `vertex` element of float32 properties, in this order:
  x y z nx ny nz f_dc_0..2 f_rest_0..f_rest_{3(K-1)-1} opacity scale_0..2 rot_0..3
Normals are zero; f_rest is channel-major (f_rest index = channel * (K-1) + coefficient - 1); opacity is
the logit, scales are logs and rot is (w, x, y, z), as stored in GaussianModel.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .constants import MAX_ABS_LOG_SCALE, MAX_ABS_MEAN, SH_MAX_DEGREE, sh_coeffs
from .errors import InputError
from .files import write_atomic
from .model import GaussianModel

_WRITE_ROWS = 1 << 16          # Gaussians converted and written at a time (bounded memory)
_MAX_HEADER_BYTES = 1 << 20    # a longer header is not a PLY we can use

# PLY scalar type names (both spellings) -> NumPy type without byte order.
_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_REST_COUNTS = {3 * (sh_coeffs(d) - 1): d for d in range(SH_MAX_DEGREE + 1)}  # 0, 9, 24, 45
_FIXED = (["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
          + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])


def property_names(sh_degree: int) -> list[str]:
    """The vertex properties of a model of this SH degree, in file order."""
    rest = 3 * (sh_coeffs(sh_degree) - 1)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def ply_header(count: int, sh_degree: int) -> bytes:
    """The header `plyfile` writes for the Inria layout: no comments, LF line ends."""
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    lines += [f"property float {name}" for name in property_names(sh_degree)]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply(path: str | os.PathLike, model: GaussianModel) -> None:
    """Write `model` as a 3DGS PLY. Atomic: the file appears complete or not at all (a failed write
    leaves an existing file as it was and no temporary file behind). Creates missing parent folders."""
    def write(tmp: Path) -> None:
        with open(tmp, "xb") as f:  # "x": never clobber
            f.write(ply_header(len(model), model.sh_degree))
            for start in range(0, len(model), _WRITE_ROWS):
                f.write(_vertex_rows(model, start, start + _WRITE_ROWS).tobytes())
            f.flush()
            os.fsync(f.fileno())  # the data is on disk before the name points at it
    write_atomic(path, write)


def _vertex_rows(model: GaussianModel, start: int, stop: int) -> np.ndarray:
    """Rows [start, stop) of the vertex table, little-endian float32."""
    sh = model.sh[start:stop]
    n = len(sh)
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)  # channel-major
    return np.concatenate([
        model.means[start:stop], np.zeros((n, 3), np.float32), sh[:, 0, :], rest,
        model.opacity_logits[start:stop, None], model.log_scales[start:stop], model.quats[start:stop],
    ], axis=1).astype("<f4", copy=False)


def read_ply(path: str | os.PathLike) -> GaussianModel:
    """Read a 3DGS PLY: binary (either byte order) or ASCII, any numeric property types, properties in
    any order, extra properties and elements ignored. The SH degree follows from the number of f_rest
    properties. Raises InputError for an unreadable, malformed, truncated or empty file, missing
    properties, or NaN/Inf values."""
    try:
        with open(path, "rb") as f:
            order, elements = read_header(path, f)
            index = next((i for i, e in enumerate(elements) if e["name"] == "vertex"), None)
            if index is None:
                raise InputError(path, "no 'vertex' element")
            vertex = elements[index]
            lists = [name for name, t in vertex["props"].items() if t is None]
            if lists:
                raise InputError(path, f"vertex list properties are not 3DGS: {' '.join(lists)}")
            names = _wanted(path, vertex["props"])
            if vertex["count"] == 0:
                raise InputError(path, "no Gaussians (the vertex element is empty)")
            if order is None:
                cols = _read_ascii(path, f, elements[:index], vertex)
            else:
                cols = _read_binary(path, f, order, elements[:index], vertex)
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None
    return _to_model(path, cols, names)


def read_header(path, f) -> tuple[str | None, list[dict]]:
    """Byte order ('<', '>', or None for ASCII) and the elements, each {name, count, props}; props maps
    a property name to its NumPy type, or for a list property to None (with the types in `lists`)."""
    if f.readline(8).rstrip(b"\r\n") != b"ply":
        raise InputError(path, "not a PLY file (it does not start with 'ply')")
    order, elements, size = False, [], 0
    while True:
        raw = f.readline(_MAX_HEADER_BYTES)
        size += len(raw)
        if not raw.endswith(b"\n") or size > _MAX_HEADER_BYTES:
            raise InputError(path, "malformed PLY header: no 'end_header' line")
        try:
            words = raw.decode("ascii").split()
        except UnicodeDecodeError:
            raise InputError(path, "malformed PLY header: non-ASCII bytes") from None
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        bad = InputError(path, f"malformed PLY header line '{' '.join(words)}'")
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS or words[2] != "1.0" or order is not False:
                raise bad
            order = _FORMATS[words[1]]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit() or any(e["name"] == words[1] for e in elements):
                raise bad
            elements.append({"name": words[1], "count": int(words[2]), "props": {}, "lists": {}})
        elif words[0] == "property" and elements:
            e = elements[-1]
            if len(words) == 3 and words[1] in _TYPES and words[2] not in e["props"]:
                e["props"][words[2]] = _TYPES[words[1]]
            elif (len(words) == 5 and words[1] == "list" and words[2] in _TYPES and words[3] in _TYPES
                  and words[4] not in e["props"]):
                e["props"][words[4]] = None
                e["lists"][words[4]] = (_TYPES[words[2]], _TYPES[words[3]])
            else:
                raise bad
        else:
            raise bad
    if order is False:
        raise InputError(path, "malformed PLY header: no 'format' line")
    _check_counts(path, f, order, elements)
    return order, elements


def _check_counts(path, f, order: str | None, elements: list[dict]) -> None:
    """InputError where the elements' counts promise more rows than the file's bytes can hold, before any reader
    sizes a buffer by them (`element chunk 1000000000000` ended in MemoryError, 20 digits in OverflowError): a
    binary row takes at least its properties' bytes (a list its length), an ASCII row at least two ("0\n")."""
    left = os.fstat(f.fileno()).st_size - f.tell()
    for e in elements:
        row = 2 if order is None else sum(np.dtype(t if t is not None else e["lists"][name][0]).itemsize
                                          for name, t in e["props"].items())
        if e["count"] * max(row, 1) > left:
            raise InputError(path, f"truncated: the header promises {e['count']:,} '{e['name']}' rows of at least "
                                   f"{row} bytes, more than the {max(left, 0):,} bytes after the header")
        left -= e["count"] * row


def _wanted(path, props: dict) -> list[str]:
    """The properties to read, in model order (_FIXED, then f_rest by index)."""
    missing = [name for name in _FIXED if name not in props]
    if missing:
        raise InputError(path, f"missing vertex properties: {' '.join(missing)}")
    rest = [name for name in props if name.startswith("f_rest_")]
    if len(rest) not in _REST_COUNTS:
        raise InputError(path, f"{len(rest)} f_rest properties; expected 0, 9, 24 or 45 (SH degree 0..3)")
    wanted = [f"f_rest_{i}" for i in range(len(rest))]
    if set(rest) != set(wanted):
        raise InputError(path, f"f_rest properties are not numbered f_rest_0..f_rest_{len(rest) - 1}")
    return _FIXED + wanted


def _read_binary(path, f, order, before, vertex) -> np.ndarray:
    """The vertex table as a structured array, after skipping the elements before it."""
    for e in before:
        _skip_binary(path, f, order, e)
    dtype = np.dtype([(name, order + t) for name, t in vertex["props"].items()])
    size = dtype.itemsize * vertex["count"]
    left = os.fstat(f.fileno()).st_size - f.tell()
    if left < size:  # checked before reading: a corrupt count must not allocate a huge buffer
        raise InputError(path, f"truncated: the header promises {vertex['count']} vertices of "
                               f"{dtype.itemsize} bytes but only {max(left, 0) // dtype.itemsize} are there")
    return np.frombuffer(f.read(size), dtype=dtype)


def _skip_binary(path, f, order, element) -> None:
    """Move past one element: in one seek when its properties are all scalars, else row by row."""
    props, lists = element["props"], element["lists"]
    if not lists:
        f.seek(element["count"] * sum(np.dtype(t).itemsize for t in props.values()), os.SEEK_CUR)
        return
    for _ in range(element["count"]):
        for name, t in props.items():
            if t is not None:
                f.seek(np.dtype(t).itemsize, os.SEEK_CUR)
                continue
            length_type, value_type = np.dtype(order + lists[name][0]), np.dtype(lists[name][1])
            raw = f.read(length_type.itemsize)
            if len(raw) < length_type.itemsize:
                raise InputError(path, f"truncated in element '{element['name']}'")
            f.seek(int(np.frombuffer(raw, length_type)[0]) * value_type.itemsize, os.SEEK_CUR)


def _read_ascii(path, f, before, vertex) -> dict[str, np.ndarray]:
    """The vertex columns of an ASCII body (one element row per line)."""
    skip, count, names = sum(e["count"] for e in before), vertex["count"], list(vertex["props"])
    rows = f.read().split(b"\n")[skip:skip + count]
    try:
        values = np.array(b" ".join(rows).split(), dtype=np.float64)
    except ValueError:
        raise InputError(path, "malformed ASCII vertex data (a value is not a number)") from None
    if len(values) < count * len(names):
        raise InputError(path, f"truncated: the header promises {count} vertices of {len(names)} values "
                               f"but only {len(values)} values are there")
    if len(values) > count * len(names):
        raise InputError(path, f"malformed ASCII vertex data (not {len(names)} values per line)")
    return dict(zip(names, values.reshape(count, len(names)).T))


def _to_model(path, cols, names: list[str]) -> GaussianModel:
    """The model from the columns `names` (model order), refusing NaN and Inf (also doubles that
    overflow float32)."""
    with np.errstate(over="ignore"):
        v = np.stack([np.asarray(cols[name], dtype=np.float32) for name in names], axis=1)
    bad = (~np.isfinite(v)).sum(axis=0)
    if bad.any():
        where = ", ".join(f"{c} in {name}" for name, c in zip(names, bad) if c)
        raise InputError(path, f"{bad.sum()} NaN or Inf values ({where})")
    n, rest = len(v), (len(names) - len(_FIXED)) // 3  # columns as in _FIXED, then f_rest
    sh = np.concatenate([v[:, None, 3:6], v[:, 14:].reshape(n, 3, rest).transpose(0, 2, 1)], axis=1)
    model = GaussianModel(means=v[:, 0:3], log_scales=v[:, 7:10], quats=v[:, 10:14], opacity_logits=v[:, 6],
                          sh=sh)
    check_ranges(path, model)
    return model


def check_ranges(path, model: GaussianModel) -> None:
    """InputError naming the first Gaussian whose mean or log scale lies beyond what the kernels and the exports
    keep finite (constants.MAX_ABS_MEAN, MAX_ABS_LOG_SCALE)."""
    for what, values, limit in (("mean", model.means, MAX_ABS_MEAN),
                                ("log scale", model.log_scales, MAX_ABS_LOG_SCALE)):
        beyond = np.flatnonzero((np.abs(values) > limit).any(axis=1))
        if len(beyond):
            i = int(beyond[0])
            raise InputError(path, f"{len(beyond)} Gaussians with a {what} beyond +-{limit:g} (Gaussian {i}: "
                                   f"{', '.join(f'{x:g}' for x in values[i])})")
