"""PlayCanvas's compressed PLY (.compressed.ply; SuperSplat, the PlayCanvas engine). Gaussians in Morton
order, in chunks of 256 (the last one's bounds over its real members). Elements:

    chunk   18 x float32 bounds per chunk: min_x,y,z, max_x,y,z of positions; min_scale_x,y,z,
            max_scale_x,y,z of log scales (clamped to [-20, 20]); min_r,g,b, max_r,g,b of colour
    vertex  4 x uint32 per Gaussian, earlier fields in higher bits:
            packed_position  x, y, z in the chunk's bounds: 11, 10, 11 bits
            packed_rotation  smallest three of (w, x, y, z), negated so that the largest is positive:
                             2 bits its index, 3 x 10 bits round(1023 * (c * sqrt(1/2) + 0.5))
            packed_scale     log scales in the chunk's bounds: 11, 10, 11 bits
            packed_color     r, g, b in the chunk's bounds, then opacity: 4 x 8 bits
    sh      only for SH degree > 0: uchar f_rest_i in the PLY's channel-major order,
            floor(256 * (c / 8 + 0.5)) (c within [-4, 4]); read 0 -> -4, 255 -> 4, else 8 * ((u + 0.5) / 256 - 0.5)

"In bounds" with b bits: round((2^b - 1) * (v - min) / (max - min)); read min + (max - min) * u / (2^b - 1).
"""
from __future__ import annotations

import os

import numpy as np

from ...errors import InputError
from ...model import GaussianModel, rgb_to_sh_dc
from ...ply import read_header
from .common import (SMALLEST_THREE_BITS, SQRT_HALF, dc_colour, from_smallest_three, pack_bits, read_model,
                     smallest_three, to_bytes, unit_quats, unorm, unpack_bits, unpack_unorm, write_bytes)

CHUNK_SIZE = 256
CHUNK_PROPS = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
               "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z",
               "min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
VERTEX_PROPS = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]
XYZ_BITS, COLOR_BITS = (11, 10, 11), (8, 8, 8, 8)
LOG_SCALE_LIMIT = 20.0         # chunk scale bounds are clamped to +-this (PlayCanvas: guards infinities)
SH_SPAN = 8.0                  # f_rest codes cover [-SH_SPAN / 2, SH_SPAN / 2]
MORTON_BITS = 21               # per axis: three make a 63-bit code


def write_compressed_ply(path: str | os.PathLike, model: GaussianModel) -> None:
    """The compressed PLY of `model`, in Morton order."""
    n = len(model)
    chunks = -(-n // CHUNK_SIZE)
    order = morton_order(model.means)
    # The last Gaussian repeated fills the last chunk: it changes no bound, and every chunk is full.
    rows = np.concatenate([order, np.full(chunks * CHUNK_SIZE - n, order[-1])])

    def in_chunks(v):
        return v[rows].astype(np.float64).reshape(chunks, CHUNK_SIZE, -1)
    pos_lo, pos_hi, pos = _in_bounds(in_chunks(model.means), XYZ_BITS)
    scale_lo, scale_hi, scale = _in_bounds(in_chunks(model.log_scales), XYZ_BITS, LOG_SCALE_LIMIT)
    col_lo, col_hi, col = _in_bounds(dc_colour(in_chunks(model.sh[:, 0])), COLOR_BITS[:3])
    alpha = unorm(model.opacities[rows].astype(np.float64), COLOR_BITS[3])
    largest, others = smallest_three(unit_quats(model.quats[rows]))
    rotation = pack_bits([largest, *unorm(others * SQRT_HALF + 0.5, SMALLEST_THREE_BITS[1]).T], SMALLEST_THREE_BITS)
    vertex = np.stack([pack_bits(pos.T, XYZ_BITS), rotation, pack_bits(scale.T, XYZ_BITS),
                       pack_bits([*col.T, alpha], COLOR_BITS)], axis=1)[:n].astype("<u4")
    chunk = np.concatenate([pos_lo, pos_hi, scale_lo, scale_hi, col_lo, col_hi], axis=1).astype("<f4")
    rest = _channel_major(model.sh[order])
    lines = ["ply", "format binary_little_endian 1.0", "comment written by dc4gs-cl", f"element chunk {chunks}",
             *(f"property float {p}" for p in CHUNK_PROPS), f"element vertex {n}",
             *(f"property uint {p}" for p in VERTEX_PROPS)]
    if rest.shape[1]:
        lines += [f"element sh {n}", *(f"property uchar f_rest_{i}" for i in range(rest.shape[1]))]
    header = ("\n".join(lines + ["end_header"]) + "\n").encode("ascii")
    sh = to_bytes(np.floor(256 * (rest / SH_SPAN + 0.5)))
    write_bytes(path, header + chunk.tobytes() + vertex.tobytes() + sh.tobytes())


def morton_order(means: np.ndarray) -> np.ndarray:
    """The Gaussians in Morton (Z-curve) order of their cells on a 2^MORTON_BITS-per-axis grid over the
    bounding box: neighbours in the file are neighbours in space, so each chunk's bounds are tight."""
    p = means.astype(np.float64)
    lo, span = p.min(axis=0), np.ptp(p, axis=0)
    cells = np.floor((p - lo) / np.where(span > 0, span, 1) * ((1 << MORTON_BITS) - 1)).astype(np.uint64)
    code = np.zeros(len(p), np.uint64)
    for axis in range(3):   # spread each axis' bits three apart, x lowest
        v = cells[:, axis]
        for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                            (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
            v = (v | v << np.uint64(shift)) & np.uint64(mask)
        code |= v << np.uint64(axis)
    return np.argsort(code, kind="stable")


def read_compressed_ply(path: str | os.PathLike) -> GaussianModel:
    """A compressed PLY as PlayCanvas's splat-transform decompresses it (the 18-property chunk layout)."""
    try:
        with open(path, "rb") as f:
            order, elements = read_header(path, f)
            names = [e["name"] for e in elements]
            if order != "<" or names not in (["chunk", "vertex"], ["chunk", "vertex", "sh"]):
                raise InputError(path, "not a compressed PLY (binary little-endian elements chunk, vertex [, sh])")
            tables = {e["name"]: _read_table(path, f, e) for e in elements}
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None
    chunk, vertex = tables["chunk"], tables["vertex"]
    missing = (set(CHUNK_PROPS) - set(chunk.dtype.names)) | (set(VERTEX_PROPS) - set(vertex.dtype.names))
    if missing:
        raise InputError(path, f"not a compressed PLY: no {' '.join(sorted(missing))}")
    n = len(vertex)
    if len(chunk) != -(-n // CHUNK_SIZE):
        raise InputError(path, f"{len(chunk)} chunks for {n} Gaussians: expected one per {CHUNK_SIZE}")

    def in_bounds(first, word, bits):   # the 3 min and 3 max from chunk property `first` on, around word's codes
        i = CHUNK_PROPS.index(first)
        b = np.stack([chunk[name].astype(np.float64) for name in CHUNK_PROPS[i:i + 6]], axis=1)
        lo, hi = np.split(np.repeat(b, CHUNK_SIZE, axis=0)[:n], 2, axis=1)
        return lo + (hi - lo) * np.stack(unpack_unorm(word, bits)[:3], axis=1)
    largest = unpack_bits(vertex["packed_rotation"], SMALLEST_THREE_BITS)[0]
    others = np.stack(unpack_unorm(vertex["packed_rotation"], SMALLEST_THREE_BITS)[1:], axis=1)
    sh = np.zeros((n, 0))
    if "sh" in tables:
        codes = np.stack([tables["sh"][name] for name in tables["sh"].dtype.names], axis=1)
        sh = SH_SPAN * (np.where(codes == 0, 0.0, np.where(codes == 255, 1.0, (codes + 0.5) / 256)) - 0.5)
    rest = sh.shape[1] // 3
    colour = in_bounds("min_r", vertex["packed_color"], COLOR_BITS)
    return read_model(in_bounds("min_x", vertex["packed_position"], XYZ_BITS),
                      in_bounds("min_scale_x", vertex["packed_scale"], XYZ_BITS),
                      from_smallest_three(largest, (others - 0.5) / SQRT_HALF),
                      unpack_unorm(vertex["packed_color"], COLOR_BITS)[3],
                      np.concatenate([rgb_to_sh_dc(colour)[:, None],
                                      sh.reshape(n, 3, rest).transpose(0, 2, 1)], axis=1))


def _in_bounds(v: np.ndarray, bits, limit: float | None = None):
    """Per-chunk bounds (float32, as stored, clamped to +-limit) of (chunks, CHUNK_SIZE, 3) values and each
    value's code in them, (chunks * CHUNK_SIZE, 3)."""
    lo, hi = v.min(axis=1), v.max(axis=1)
    if limit is not None:
        lo, hi = np.clip(lo, -limit, limit), np.clip(hi, -limit, limit)
    lo, hi = lo.astype(np.float32), hi.astype(np.float32)
    span = hi.astype(np.float64)[:, None] - lo[:, None]   # in float64, as readers decode it
    t = np.where(span > 0, (v - lo[:, None]) / np.where(span > 0, span, 1), 0.0)
    codes = np.stack([unorm(t[..., i], width) for i, width in enumerate(bits)], axis=-1)
    return lo, hi, codes.reshape(-1, 3)


def _channel_major(sh: np.ndarray) -> np.ndarray:
    """f_rest columns in the PLY's order: channel-major (index = channel * (K - 1) + coefficient - 1)."""
    return sh[:, 1:, :].transpose(0, 2, 1).reshape(len(sh), -1).astype(np.float64)


def _read_table(path, f, element) -> np.ndarray:
    """One binary little-endian element of scalar properties, as a structured array."""
    if element["lists"]:
        raise InputError(path, f"element '{element['name']}' has list properties")
    dtype = np.dtype([(name, "<" + t) for name, t in element["props"].items()])
    data = f.read(dtype.itemsize * element["count"])
    if len(data) < dtype.itemsize * element["count"]:
        raise InputError(path, f"truncated in element '{element['name']}'")
    return np.frombuffer(data, dtype)
