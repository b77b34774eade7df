"""Float64 reference of kernels/position_noise.cl and its random numbers (kernels/philox.h), computed in NumPy."""
from __future__ import annotations

import numpy as np

from ..constants import MAX_ABS_MEAN
from ..geometry import quat_to_rotmat

PHILOX_M = (0xD2511F53, 0xCD9E8D57)
PHILOX_W = (0x9E3779B9, 0xBB67AE85)
MASK32 = 0xFFFFFFFF


def philox4x32_10(counter: np.ndarray, key: tuple[int, int]) -> np.ndarray:
    """(N, 4) uint32 counters -> (N, 4) uint32 words, under the key (k0, k1)."""
    c = [counter[:, j].astype(np.uint64) for j in range(4)]
    k0, k1 = np.uint64(key[0]), np.uint64(key[1])
    m0, m1 = np.uint64(PHILOX_M[0]), np.uint64(PHILOX_M[1])
    for _ in range(10):
        p0, p1 = m0 * c[0], m1 * c[2]   # < 2^64: exact in uint64
        hi0, lo0 = p0 >> np.uint64(32), p0 & np.uint64(MASK32)
        hi1, lo1 = p1 >> np.uint64(32), p1 & np.uint64(MASK32)
        c = [hi1 ^ c[1] ^ k0, lo1, hi0 ^ c[3] ^ k1, lo0]
        k0, k1 = (k0 + np.uint64(PHILOX_W[0])) & np.uint64(MASK32), (k1 + np.uint64(PHILOX_W[1])) & np.uint64(MASK32)
    return np.stack(c, axis=1).astype(np.uint32)


def philox_normals(counter: np.ndarray, key: tuple[int, int]) -> np.ndarray:
    """(N, 4) standard normals: Box-Muller on each draw's word pairs, uniforms in (0, 1] from their top 24 bits."""
    w = philox4x32_10(counter, key)
    u = ((w >> 8).astype(np.float64) + 1.0) / 2.0 ** 24
    r0, r1 = np.sqrt(-2 * np.log(u[:, 0])), np.sqrt(-2 * np.log(u[:, 2]))
    t0, t1 = 2 * np.pi * u[:, 1], 2 * np.pi * u[:, 3]
    return np.stack([r0 * np.cos(t0), r0 * np.sin(t0), r1 * np.cos(t1), r1 * np.sin(t1)], axis=1)


def noise_counters(n: int, iteration: int) -> np.ndarray:
    return np.stack([np.arange(n), np.full(n, iteration), np.zeros(n), np.zeros(n)], axis=1).astype(np.uint32)


def position_noise_reference(means, log_scales, quats, opacity_logits, iteration: int, seed: tuple[int, int],
                         scaler: float, k: float, x0: float) -> np.ndarray:
    """The means after position_noise.cl's step: means + Sigma z f scaler (the kernel's docstring; a step beyond
    float32's range not taken, the means clamped to +-MAX_ABS_MEAN)."""
    means = np.asarray(means, np.float64)
    opacity = 1 / (1 + np.exp(-np.asarray(opacity_logits, np.float64).reshape(-1)))
    f = 1 / (1 + np.exp(-k * ((1 - opacity) - x0)))
    z = philox_normals(noise_counters(len(means), iteration), seed)[:, :3] * (f * scaler)[:, None]
    M = quat_to_rotmat(quats) * np.exp(np.asarray(log_scales, np.float64))[:, None, :]
    moved = means + np.einsum("nij,nkj,nk->ni", M, M, z)
    finite = (np.abs(moved) < np.finfo(np.float32).max).all(axis=1, keepdims=True)
    return np.clip(np.where(finite, moved, means), -MAX_ABS_MEAN, MAX_ABS_MEAN)
