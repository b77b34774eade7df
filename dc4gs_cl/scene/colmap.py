"""COLMAP scenes: sparse/0/{cameras,images,points3D}.{bin,txt} (or sparse/) and images/, read with pycolmap."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap

from ..errors import InputError
from .camera import Camera
from .images import image_size
from .undistort import check_size, make_camera


def model_dir(root: Path) -> Path | None:
    """The folder holding the COLMAP model, or None when `root` is not a COLMAP scene."""
    for d in (root / "sparse" / "0", root / "sparse"):
        if any((d / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return d
    return None


def _model_file(d: Path, stem: str) -> Path:
    """The file of the model named in errors: .bin if present, else .txt."""
    return d / f"{stem}.bin" if (d / f"{stem}.bin").is_file() else d / f"{stem}.txt"


def read_colmap(root: Path) -> tuple[list[Camera], dict[str, pycolmap.Camera], np.ndarray, np.ndarray]:
    """Full-size PINHOLE cameras of the registered images, the distorted cameras of the images whose
    pixels need undistorting (by name), and the SfM points (P, 3) float64 with colours (P, 3) float32."""
    d = model_dir(root)
    try:
        rec = pycolmap.Reconstruction(str(d))
    except ValueError as e:
        raise InputError(d, f"cannot read COLMAP model ({e})") from None
    if rec.num_points3D() == 0:
        raise InputError(_model_file(d, "points3D"), "no 3D points (nothing to initialise training from)")

    cameras_file = _model_file(d, "cameras")
    cameras, distorted = [], {}
    for img in rec.images.values():
        if not img.has_pose:  # an image COLMAP could not register has no pose to train with
            continue
        cam = rec.cameras[img.camera_id]
        path = root / "images" / img.name
        if not path.is_file():
            raise InputError(path, f"image listed in the COLMAP model {d} not found")
        check_size(path, image_size(path), (cam.width, cam.height))
        pose = img.cam_from_world()
        camera, dist = make_camera(img.name, path, cam, pose.rotation.matrix(), pose.translation, cameras_file)
        cameras.append(camera)
        if dist is not None:
            distorted[img.name] = dist
    if not cameras:
        raise InputError(_model_file(d, "images"), "no registered images")

    points = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in points], dtype=np.float32).reshape(-1, 3) / 255.0
    return cameras, distorted, xyz, colors
