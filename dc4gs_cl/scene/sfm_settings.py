"""SfM's settings (scene/sfm.py), without pycolmap: the command line builds them and checks them before any
library is loaded."""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError

CAMERA_MODES = ("shared", "per-folder", "per-photo")   # one camera for every photo, one per folder, one per photo
CAMERA_MODELS = ("OPENCV", "SIMPLE_RADIAL", "RADIAL", "FULL_OPENCV", "PINHOLE", "SIMPLE_PINHOLE")   # the loader's
MAPPERS = ("incremental", "global")


@dataclass(frozen=True)
class SfMSettings:
    camera: str = "shared"            # one of CAMERA_MODES
    camera_model: str = "OPENCV"
    max_image_size: int = 3200        # SIFT on photos scaled to at most this side (px)
    max_features: int = 8192          # SIFT features per photo
    affine_shape: bool = False        # SIFT's affine shapes: matches across wider changes of view, slower features
    exhaustive_up_to: int = 100       # every pair matched up to this many photos, sequential pairs past it
    overlap: int = 10                 # sequential matching: each photo with the next `overlap` ones
    mapper: str = "incremental"       # one of MAPPERS

    def __post_init__(self):
        if self.camera_model not in CAMERA_MODELS:
            raise InputError(None, f"--camera-model {self.camera_model!r}: one of {', '.join(CAMERA_MODELS)}")
        if self.camera not in CAMERA_MODES:
            raise InputError(None, f"--camera {self.camera!r}: one of {', '.join(CAMERA_MODES)}")
        if self.mapper not in MAPPERS:
            raise InputError(None, f"--mapper {self.mapper!r}: one of {', '.join(MAPPERS)}")
        for name, least in (("max_image_size", 16), ("max_features", 16), ("exhaustive_up_to", 0), ("overlap", 1)):
            if getattr(self, name) < least:
                raise InputError(None, f"--{name.replace('_', '-')} {getattr(self, name)} must be at least {least}")

    def sequential(self, photos: int) -> bool:
        return photos > self.exhaustive_up_to
