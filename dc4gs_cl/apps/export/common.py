"""What the export formats share: byte codes, "smallest three" quaternions, bit fields, and reading and
(atomic) writing of whole files."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...constants import QUAT_NORM_MIN, SH_C0
from ...errors import InputError
from ...files import write_atomic
from ...model import GaussianModel, logit

# Readers clamp a decoded opacity into [ALPHA_FLOOR, 1 - ALPHA_FLOOR]: a byte of 0 or 255 keeps a finite
# logit, and half a byte step stays within the quantisation error.
ALPHA_FLOOR = 0.5 / 255
SQRT_HALF = np.sqrt(0.5)       # bound of the three smaller components of a unit quaternion
SMALLEST_THREE_BITS = (2, 10, 10, 10)   # the largest component's index, then the other three


def dc_colour(f_dc: np.ndarray) -> np.ndarray:
    """The colour the SH DC band gives, 0.5 + SH_C0 * f_dc (float64; model.rgb_to_sh_dc is the inverse)."""
    return 0.5 + SH_C0 * np.asarray(f_dc, np.float64)


def unit_quats(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions at unit length in float64; one shorter than QUAT_NORM_MIN becomes the identity."""
    q = np.asarray(q, np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(norm > QUAT_NORM_MIN, q / np.maximum(norm, QUAT_NORM_MIN), np.array([1.0, 0, 0, 0]))


def smallest_three(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of each unit quaternion's largest |component| (the first of equals) and its other three
    components, negated where that component is negative (q and -q are the same rotation)."""
    largest = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[np.arange(len(q)), largest] < 0, -1.0, 1.0)[:, None]
    return largest, q[np.arange(4)[None, :] != largest[:, None]].reshape(-1, 3)


def from_smallest_three(largest: np.ndarray, others: np.ndarray) -> np.ndarray:
    """The inverse of smallest_three: the largest component is the one that makes the quaternion unit."""
    q = np.empty((len(others), 4))
    keep = np.arange(4)[None, :] != largest[:, None]
    q[keep] = others.ravel()
    q[~keep] = np.sqrt(np.maximum(0.0, 1.0 - (others ** 2).sum(axis=1)))
    return q


def pack_bits(fields, bits) -> np.ndarray:
    """uint32 words of the fields, each in its bit width, the first in the highest bits."""
    word = np.zeros(len(fields[0]), np.uint32)
    for field, width in zip(fields, bits):
        word = word << np.uint32(width) | np.asarray(field).astype(np.uint32)
    return word


def unpack_bits(word: np.ndarray, bits) -> list[np.ndarray]:
    word = word.astype(np.uint32)
    fields = []
    for width in reversed(bits):
        fields.append(word & np.uint32((1 << width) - 1))
        word = word >> np.uint32(width)
    return fields[::-1]


def unorm(t: np.ndarray, bits: int) -> np.ndarray:
    """Codes of t in [0, 1] on 2^bits - 1 steps, rounded."""
    top = (1 << bits) - 1
    return np.clip(np.floor(t * top + 0.5), 0, top).astype(np.uint32)


def unpack_unorm(word: np.ndarray, bits) -> list[np.ndarray]:
    """The inverse of unorm for each field of pack_bits words."""
    return [field / float((1 << width) - 1) for field, width in zip(unpack_bits(word, bits), bits)]


def to_bytes(x: np.ndarray) -> np.ndarray:
    """Codes 0..255, rounded to nearest."""
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def read_model(means, log_scales, quats, opacity, sh) -> GaussianModel:
    """A model as read; the opacity clamped off 0 and 1 (see ALPHA_FLOOR), quaternions normalised."""
    return GaussianModel(means=means, log_scales=log_scales, quats=unit_quats(quats),
                         opacity_logits=logit(np.clip(opacity, ALPHA_FLOOR, 1 - ALPHA_FLOOR)), sh=sh)


# the most Gaussians a model file may hold before its arrays are made (a header can promise any count: a .spz of 2 MB
# promised 20 million and took 7.7 GB); DC4GS_MAX_READ_GAUSSIANS raises it
MAX_READ_GAUSSIANS = 20_000_000
MAX_READ_GAUSSIANS_ENV = "DC4GS_MAX_READ_GAUSSIANS"


def check_gaussian_count(path, n: int) -> None:
    """InputError where a file's header promises more Gaussians than MAX_READ_GAUSSIANS (or the environment's)."""
    given = os.environ.get(MAX_READ_GAUSSIANS_ENV, "")
    if given and not given.isdigit():
        raise InputError(None, f"{MAX_READ_GAUSSIANS_ENV}={given!r}: expected a count of Gaussians")
    limit = int(given) if given else MAX_READ_GAUSSIANS
    if n > limit:
        raise InputError(path, f"the header promises {n:,} Gaussians, more than the {limit:,} read at most "
                               f"(set {MAX_READ_GAUSSIANS_ENV} to read more)")


def read_bytes(path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None


def write_bytes(path, data: bytes) -> None:
    def write(tmp: Path) -> None:
        with open(tmp, "xb") as f:   # "x": never clobber
            f.write(data)
            f.flush()
            os.fsync(f.fileno())     # the data is on disk before the name points at it
    write_atomic(path, write)
