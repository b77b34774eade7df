"""Niantic's .spz, version 3: the last gzip version (their reader reads versions 1 to 4; their writer now
defaults to 4, zstd streams). A gzip stream of a 16-byte header:

    magic 0x5053474e ("NGSP"), version, Gaussians (uint32 each); SH degree, fractional bits F,
    flags (bit 0: antialiased, the model trained with its 2D filter's compensation), reserved (uint8 each)

then each attribute for all Gaussians in turn:

    positions  3 x 24-bit two's complement round(x * 2^F): F = 12 (1/4096 unit), fewer only when a
               coordinate reaches 2048 units (their reader takes F from the header)
    alphas     uint8 round(255 * opacity)
    colours    3 x uint8 round(255 * (0.15 * f_dc + 0.5))     (f_dc within +-3.33)
    scales     3 x uint8 round(16 * (log scale + 10))         (log scale within [-10, 5.94])
    rotations  uint32, "smallest three" of (x, y, z, w): bits 30-31 the index of the largest |component|,
               then the others (the first in the highest bits), 10 bits each: a sign bit (relative to the
               largest's sign) and round(511 * |c| / sqrt(1/2))
    SH         (K - 1) x 3 x uint8 round(128 * c) + 128, coefficient-major, RGB innermost, then rounded to
               multiples of 8 (degree 1) and 16 (degrees 2, 3): their writer's default 5 and 4 bits
               (c within [-1, 127/128])

spz is stored right-up-back (RUB, three.js); the model's PLY axes are right-down-front (RDF). The writer
turns the scene half a turn about x (y and z of positions and of the quaternion negated, SH coefficients
odd in y, z change sign), which their reader undoes when asked for RDF, as splat-transform and their
spz_to_ply do.
"""
from __future__ import annotations

import gzip
import os
import zlib

import numpy as np

from ...errors import InputError
from ...model import GaussianModel
from .common import (SMALLEST_THREE_BITS, SQRT_HALF, check_gaussian_count, from_smallest_three, pack_bits, read_bytes,
                     read_model, smallest_three, to_bytes, unit_quats, unpack_bits, write_bytes)

SPZ_MAGIC, SPZ_VERSION = 0x5053474E, 3
SPZ_HEADER = np.dtype([("magic", "<u4"), ("version", "<u4"), ("count", "<u4"), ("sh_degree", "u1"),
                       ("fractional_bits", "u1"), ("flags", "u1"), ("reserved", "u1")])
SPZ_FRACTIONAL_BITS = 12
SPZ_MAX_FRACTIONAL_BITS = 23   # a 24-bit signed coordinate holds at most this many (Niantic's writer: 12)
SPZ_POSITION_MAX = (1 << 23) - 1
SPZ_COLOR_SCALE = 0.15         # f_dc scale: wider than SH_C0, so colours a little outside [0, 1] survive
SPZ_SCALE_OFFSET, SPZ_SCALE_STEPS = 10.0, 16.0
SPZ_SH_STEPS = 128.0
SPZ_SH_BUCKETS = (8, 16)       # degree 1, degrees 2+: 2^(8 - bits) for their writer's default 5 and 4 bits
SPZ_ROTATION_MAX = 511         # 9-bit magnitudes
SPZ_AXIS_SIGNS = np.array([1.0, -1.0, -1.0])   # RDF <-> RUB on x, y, z: a half turn about x
# The sign each SH rest coefficient (degrees 1..3, 3DGS order) takes under (x, y, z) -> (x, -y, -z).
SPZ_SH_SIGNS = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], np.float64)
GZIP_LEVEL = 6                 # zlib's default, as their writer uses


SPZ_ANTIALIASED = 0x1         # the header's flag bit


def write_spz(path: str | os.PathLike, model: GaussianModel, antialiased: bool = False) -> None:
    """The version 3 .spz file of `model`, as Niantic's writer makes it from the PLY (from RDF); antialiased sets
    the header's flag (render and view then rasterize it so)."""
    n, rest = len(model), model.sh.shape[1] - 1
    means = model.means.astype(np.float64) * SPZ_AXIS_SIGNS
    bits = spz_fractional_bits(path, means)
    fixed = np.rint(means * 2.0 ** bits).astype("<i4")
    q = unit_quats(model.quats)[:, [1, 2, 3, 0]]            # (x, y, z, w), as spz orders them
    q[:, :3] *= SPZ_AXIS_SIGNS
    largest, others = smallest_three(q)
    magnitudes = np.minimum(np.rint(SPZ_ROTATION_MAX * np.abs(others) / SQRT_HALF), SPZ_ROTATION_MAX)
    fields = (others < 0) * (SPZ_ROTATION_MAX + 1) + magnitudes
    bucket = np.where(np.arange(rest) < 3, *SPZ_SH_BUCKETS)[None, :, None]
    sh = np.rint(model.sh[:, 1:] * SPZ_SH_SIGNS[:rest, None] * SPZ_SH_STEPS) + SPZ_SH_STEPS
    header = np.array([(SPZ_MAGIC, SPZ_VERSION, n, model.sh_degree, bits, SPZ_ANTIALIASED if antialiased else 0, 0)],
                      SPZ_HEADER)
    parts = [header, fixed.view(np.uint8).reshape(n, 3, 4)[:, :, :3],   # the low three bytes of each
             to_bytes(255 * model.opacities),
             to_bytes(255 * (SPZ_COLOR_SCALE * model.sh[:, 0].astype(np.float64) + 0.5)),
             to_bytes(SPZ_SCALE_STEPS * (model.log_scales.astype(np.float64) + SPZ_SCALE_OFFSET)),
             pack_bits([largest, *fields.T], SMALLEST_THREE_BITS).astype("<u4"),
             to_bytes(np.floor((sh + bucket // 2) / bucket) * bucket)]
    data = b"".join(np.ascontiguousarray(p).tobytes() for p in parts)
    write_bytes(path, gzip.compress(data, GZIP_LEVEL, mtime=0))


def spz_fractional_bits(path, means: np.ndarray) -> int:
    """SPZ_FRACTIONAL_BITS, or fewer where the largest coordinate would overflow 24 bits."""
    largest = float(np.abs(means).max(initial=0.0))
    for bits in range(SPZ_FRACTIONAL_BITS, -1, -1):
        if np.rint(largest * 2.0 ** bits) <= SPZ_POSITION_MAX:
            return bits
    raise InputError(path, f"a coordinate of {largest:g} is beyond the {SPZ_POSITION_MAX:,} units .spz can store")


def spz_antialiased(path: str | os.PathLike) -> bool:
    """Whether a .spz file's header says antialiased (False for a file too short or not gzip: read_spz says why)."""
    try:
        with gzip.open(path, "rb") as f:
            head = f.read(SPZ_HEADER.itemsize)
    except (OSError, EOFError, zlib.error):
        return False
    return len(head) == SPZ_HEADER.itemsize and bool(np.frombuffer(head, SPZ_HEADER)[0]["flags"] & SPZ_ANTIALIASED)


def read_spz(path: str | os.PathLike) -> GaussianModel:
    """A version 3 .spz file as Niantic's reader decodes it to RDF (the PLY's axes). The gzip stream is inflated
    only as far as its header says the data reaches (a 2 MB file can inflate to gigabytes): data past that, a count
    past check_gaussian_count's and fractional bits no writer uses are refused."""
    stream = zlib.decompressobj(16 + zlib.MAX_WBITS)   # gzip
    compressed = read_bytes(path)
    try:
        data = stream.decompress(compressed, SPZ_HEADER.itemsize)
        if len(data) < SPZ_HEADER.itemsize:
            raise InputError(path, "not a .spz file (shorter than its header)")
        h = np.frombuffer(data, SPZ_HEADER, count=1)[0]
        if h["magic"] != SPZ_MAGIC or h["version"] != SPZ_VERSION or h["sh_degree"] > 3:
            raise InputError(path, f"not a version {SPZ_VERSION} .spz file of SH degree 0..3 (magic "
                                   f"{h['magic']:#x}, version {h['version']}, SH degree {h['sh_degree']})")
        if h["fractional_bits"] > SPZ_MAX_FRACTIONAL_BITS:
            raise InputError(path, f"fractional bits {h['fractional_bits']} in the header: writers use 0.."
                                   f"{SPZ_MAX_FRACTIONAL_BITS} (24-bit coordinates)")
        n, rest = int(h["count"]), (int(h["sh_degree"]) + 1) ** 2 - 1
        check_gaussian_count(path, n)
        sizes = [9 * n, n, 3 * n, 3 * n, 4 * n, 3 * rest * n]
        data += stream.decompress(stream.unconsumed_tail, sum(sizes))
        if len(data) < SPZ_HEADER.itemsize + sum(sizes):
            raise InputError(path, f"truncated: the header promises {n} Gaussians")
        if stream.decompress(stream.unconsumed_tail, 1) or stream.unused_data:
            raise InputError(path, f"data past the {n:,} Gaussians its header promises")
    except zlib.error as e:
        raise InputError(path, f"not a .spz file (not gzip data: {e})") from None
    ends = SPZ_HEADER.itemsize + np.cumsum(sizes)
    raw = [np.frombuffer(data[e - s:e], np.uint8) for s, e in zip(sizes, ends)]
    b = raw[0].reshape(n, 3, 3).astype(np.int32)
    fixed = ((b[..., 0] | b[..., 1] << 8 | b[..., 2] << 16) ^ 0x800000) - 0x800000   # sign-extend 24 bits
    largest, *fields = unpack_bits(raw[4].view("<u4"), SMALLEST_THREE_BITS)
    fields = np.stack(fields, axis=1)
    sign = 1 - 2 * (fields > SPZ_ROTATION_MAX).astype(np.float64)
    q = from_smallest_three(largest, sign * SQRT_HALF * (fields & SPZ_ROTATION_MAX) / SPZ_ROTATION_MAX)
    q[:, :3] *= SPZ_AXIS_SIGNS
    dc = (raw[2].reshape(n, 1, 3) / 255.0 - 0.5) / SPZ_COLOR_SCALE
    sh_rest = (raw[5].reshape(n, rest, 3) - SPZ_SH_STEPS) / SPZ_SH_STEPS * SPZ_SH_SIGNS[:rest, None]
    return read_model(fixed * SPZ_AXIS_SIGNS / 2.0 ** int(h["fractional_bits"]),
                      raw[3].reshape(n, 3) / SPZ_SCALE_STEPS - SPZ_SCALE_OFFSET,
                      q[:, [3, 0, 1, 2]], raw[1] / 255.0, np.concatenate([dc, sh_rest], axis=1))
