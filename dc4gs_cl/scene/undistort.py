"""Cameras from any perspective camera model, with their lens model (scene/distortion.py) or made pinholes, and the
pixels to match (shared by every loader).

Intrinsics of the undistorted camera come from pycolmap at load time (cheap); pixels are undistorted
lazily, the first time an image is read, and cached as lossless PNG outside the input folder.
"""
from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path

import numpy as np
import pycolmap

from ..errors import InputError
from .camera import Camera
from .distortion import DIRECT_MODELS, from_colmap
from .images import MAX_IMAGE_SIDE, read_image, write_png

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")


def make_camera(name: str, image_path: Path, cam: pycolmap.Camera, R: np.ndarray, t: np.ndarray,
                where: str | os.PathLike, pose_where: str | os.PathLike | None = None, undistort: bool = False
                ) -> tuple[Camera, pycolmap.Camera | None]:
    """A full-size Camera for an image taken with `cam`: with its lens model (distortion.DIRECT_MODELS) rendered
    directly, or (undistort) a PINHOLE, with `cam` itself returned when its pixels need undistorting (else None).
    `where` is the file named when the camera is unusable, cannot be rendered or undistorted, `pose_where` (default
    `where`) the file named for a bad pose."""
    check_camera(where, pose_where or where, name, cam, R, t)
    distorted, lens, model = None, None, cam.model.name
    if model not in PINHOLE_MODELS and not undistort:
        if model not in DIRECT_MODELS:
            raise InputError(where, f"image {name!r}: camera model {model} is not rendered directly (supported: "
                                    f"{', '.join(PINHOLE_MODELS + tuple(DIRECT_MODELS))}); --undistort trains it "
                                    "undistorted to a pinhole")
        intrinsics, lens = from_colmap(model, cam.params, int(cam.width), int(cam.height), where, name)
    else:
        if model not in PINHOLE_MODELS:
            try:
                pinhole = pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), cam)
            except ValueError as e:  # non-perspective models (EQUIRECTANGULAR) fail pycolmap's check
                raise InputError(where, f"camera model {model} cannot be undistorted ({e})") from None
            cam, distorted = pinhole, cam
            if not (np.isfinite(cam.params).all() and cam.focal_length_x > 0 and cam.focal_length_y > 0):
                raise InputError(where, f"image {name!r}: the camera's distortion cannot be undone (undistorted "
                                        f"intrinsics {np.round(cam.params, 4).tolist()})")
        intrinsics = (cam.focal_length_x, cam.focal_length_y, cam.principal_point_x, cam.principal_point_y)
    size = (int(cam.width), int(cam.height))
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    return Camera(name=name, width=size[0], height=size[1], fx=fx, fy=fy, cx=cx, cy=cy,
                  R=np.asarray(R, dtype=np.float64), t=np.asarray(t, dtype=np.float64),
                  image_path=Path(image_path), source_size=size, distortion=lens), distorted


def check_camera(where, pose_where, name: str, cam: pycolmap.Camera, R: np.ndarray, t: np.ndarray) -> None:
    """A camera that could not have taken a picture (a size or focal length <= 0, a NaN anywhere, a rotation
    that is none) stops here, naming the file and the image, rather than as NaN in training (and before
    pycolmap's undistortion walks an absurd image border)."""
    if not (1 <= cam.width <= MAX_IMAGE_SIDE and 1 <= cam.height <= MAX_IMAGE_SIDE):
        raise InputError(where, f"image {name!r}: camera size {cam.width}x{cam.height} out of range")
    focal = np.asarray(cam.params)[list(cam.focal_length_idxs())]   # none for EQUIRECTANGULAR (refused below)
    if not (np.isfinite(cam.params).all() and (focal > 0).all()):
        raise InputError(where, f"image {name!r}: intrinsics must be finite with focal lengths > 0 "
                                f"(got {np.round(cam.params, 4).tolist()})")
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise InputError(pose_where, f"image {name!r}: the pose holds NaN or infinite values")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        raise InputError(pose_where, f"image {name!r}: the pose's rotation is not a rotation")


def check_size(path: str | os.PathLike, actual: tuple[int, int], expected: tuple[int, int],
               camera_where: str | os.PathLike | None = None) -> None:
    """The image at `path` must have its camera's size; `camera_where` is the file the camera came from,
    named beside the image since either may be the one at fault."""
    if tuple(actual) != tuple(expected):
        of = f" (in {camera_where})" if camera_where is not None else ""
        raise InputError(path, f"image is {actual[0]}x{actual[1]} but its camera{of} is {expected[0]}x{expected[1]}")


def cache_file(path: Path, name: str, cam: pycolmap.Camera, cache_dir: Path) -> Path:
    """Cache file for an undistorted image: a changed source file (size, mtime) or camera gives a new key;
    the absolute path keeps scenes sharing one cache folder apart."""
    st = path.stat()
    key = (f"{path.resolve()}|{name}|{st.st_size}|{st.st_mtime_ns}|"
           f"{cam.model.name}|{cam.width}x{cam.height}|{cam.params.tolist()}")
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(name).stem)
    return cache_dir / f"{stem}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.png"


def undistorted_pixels(path: Path, name: str, cam: pycolmap.Camera, cache_dir: Path) -> np.ndarray:
    """(H, W, C) float32 in [0, 1] of the source image undistorted to PINHOLE, from the cache if there."""
    cached = cache_file(path, name, cam, cache_dir)
    if cached.is_file():
        return read_image(cached)
    pixels = read_image(path)
    check_size(path, (pixels.shape[1], pixels.shape[0]), (cam.width, cam.height))
    # pycolmap undistorts 8-bit RGB or grey bitmaps only: RGB together, any other channel (alpha) alone.
    data = (np.clip(pixels, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    c = data.shape[2]
    groups = ([data[..., :3]] if c >= 3 else []) + [data[..., i] for i in range(3 if c >= 3 else 0, c)]
    options = pycolmap.UndistortCameraOptions()
    out = [pycolmap.undistort_image(options, pycolmap.Bitmap.from_array(np.ascontiguousarray(g)), cam)[0].to_array()
           for g in groups]
    write_png(cached, np.concatenate([o.reshape(o.shape[0], o.shape[1], -1) for o in out], axis=2) / 255.0)
    return read_image(cached)  # the first read gives exactly what every later (cached) read will give
