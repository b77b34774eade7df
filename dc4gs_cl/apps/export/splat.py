"""antimatter15/splat's .splat (gsplat.js, SuperSplat). No header; 32 bytes per Gaussian:

    position  3 x float32
    scale     3 x float32, linear (exp of the log scale)
    RGBA      4 x uint8: round(255 * colour), round(255 * opacity)
    rotation  4 x uint8: round(128 * q + 128) of the unit quaternion (w, x, y, z)

No SH beyond DC. Largest exp(sum of log scales) * opacity first, as antimatter15's converters sort; rounded
as the viewer's own converter (main.js) does (its convert.py truncates). Read: u / 255 and (u - 128) / 128
(then normalised).
"""
from __future__ import annotations

import os

import numpy as np

from ...errors import InputError
from ...model import GaussianModel, rgb_to_sh_dc
from .common import dc_colour, read_bytes, read_model, to_bytes, unit_quats, write_bytes

SPLAT_RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])
SPLAT_ROTATION_SCALE = 128.0   # byte = 128 * q + 128


def write_splat(path: str | os.PathLike, model: GaussianModel) -> None:
    """The .splat file of `model`, sorted by splat_order."""
    order = splat_order(model)
    rec = np.empty(len(model), SPLAT_RECORD)
    rec["position"] = model.means[order]
    rec["scale"] = np.exp(model.log_scales[order])
    rec["rgba"][:, :3] = to_bytes(255 * dc_colour(model.sh[order, 0]))
    rec["rgba"][:, 3] = to_bytes(255 * model.opacities[order])
    rec["rotation"] = to_bytes(SPLAT_ROTATION_SCALE * (unit_quats(model.quats[order]) + 1))
    write_bytes(path, rec.tobytes())


def splat_order(model: GaussianModel) -> np.ndarray:
    """The .splat order: largest exp(sum of log scales) * opacity first (ties keep the model's order)."""
    key = np.exp(model.log_scales.astype(np.float64).sum(axis=1)) * model.opacities.astype(np.float64)
    return np.argsort(-key, kind="stable")


def read_splat(path: str | os.PathLike) -> GaussianModel:
    """A .splat file as antimatter15's viewer decodes it: SH degree 0, unit quaternions."""
    data = read_bytes(path)
    if not data or len(data) % SPLAT_RECORD.itemsize:
        raise InputError(path, f"not a .splat file: {len(data)} bytes is no positive multiple "
                               f"of {SPLAT_RECORD.itemsize}")
    rec = np.frombuffer(data, SPLAT_RECORD)
    rgba = rec["rgba"] / 255.0
    with np.errstate(divide="ignore", invalid="ignore"):   # a scale of 0 reads as log scale -inf, a negative as NaN
                                                            # (read_model_file refuses both)
        log_scales = np.log(rec["scale"])
    return read_model(rec["position"], log_scales, rec["rotation"] / SPLAT_ROTATION_SCALE - 1, rgba[:, 3],
                      rgb_to_sh_dc(rgba[:, None, :3]))
