"""Masks: the pixels of a view that carry no loss and no densification statistics (moving people, the
photographer's shadow, a sky with no geometry).

Where a view's mask comes from (the COLMAP and nerfstudio conventions):
  - a masks/ folder in the scene folder: for an image listed as NAME, the first of masks/NAME.png (COLMAP's
    naming), masks/NAME and masks/<NAME less its extension>.png; once masks/ exists every view needs one;
  - nerfstudio's per-frame "mask_path" in transforms.json (relative to that file), which comes first;
  - with --alpha-mask, an image's own alpha channel (instead of compositing it onto the background).
A mask file is any image of its view's source size; its first channel below MASK_THRESHOLD (black) masks
the pixel out. It is undistorted and scaled with its image, then thresholded again.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from .camera import Camera

MASKS_DIR = "masks"
MASK_THRESHOLD = 0.5


def mask_candidates(masks: Path, name: str) -> list[Path]:
    return [masks / f"{name}.png", masks / name, (masks / name).with_suffix(".png")]


def with_masks(root: Path, cameras: list[Camera]) -> list[Camera]:
    """The cameras with mask_path set from root/masks/ where it exists (views that name their own mask,
    nerfstudio's mask_path, keep it); InputError naming the file a view's mask was looked for in."""
    masks = root / MASKS_DIR
    if not masks.is_dir():
        return cameras
    out = []
    for cam in cameras:
        if cam.mask_path is None:
            found = next((p for p in mask_candidates(masks, cam.name) if p.is_file()), None)
            if found is None:
                raise InputError(mask_candidates(masks, cam.name)[0],
                                 f"no mask for image {cam.name!r} (with a {MASKS_DIR}/ folder, every view needs one)")
            cam = replace(cam, mask_path=found)
        out.append(cam)
    return out


def keep_from(pixels: np.ndarray) -> np.ndarray:
    """(H, W, C) mask pixels in [0, 1] -> (H, W) bool, True where kept."""
    return pixels[..., 0] >= MASK_THRESHOLD
