"""COLMAP scenes: sparse/0/{cameras,images,points3D}.{bin,txt} (or sparse/) and images/, read with pycolmap."""
from __future__ import annotations

import os
import re
import struct
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


MODEL_FILES = ("cameras", "images", "points3D")


class _Reader:
    """Bounds-checked reads of a little-endian binary file; every failure names the file and the offset."""

    def __init__(self, path: Path):
        self.path, self.data, self.at = path, path.read_bytes(), 0

    def fail(self, problem: str):
        raise InputError(self.path, f"damaged COLMAP binary file: {problem} (at byte {self.at} of {len(self.data)})")

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        if self.at + size > len(self.data):
            self.fail("ends early (truncated)")
        values = struct.unpack_from(fmt, self.data, self.at)
        self.at += size
        return values

    def skip(self, count: int, size: int) -> None:
        if count > (len(self.data) - self.at) // size:
            self.fail(f"{count:,} entries of {size} bytes do not fit in the rest of the file "
                      "(truncated, or a damaged count)")
        self.at += count * size

    def count(self, record_size: int) -> int:
        (n,) = self.take("<Q")
        if n > (len(self.data) - self.at) // record_size:
            self.fail(f"promises {n:,} records, more than the file can hold")
        return n

    def name(self) -> str:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            self.fail("an image name runs past the end of the file")
        raw, self.at = self.data[self.at:end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self.fail("an image name is not UTF-8")


def check_binary_model(d: Path) -> None:
    """Walk cameras.bin, images.bin and points3D.bin (the layout of COLMAP's reconstruction_io) and stop at
    the first record that does not fit, a count the file cannot hold, or a reference to nothing, naming the
    file. pycolmap trusts its input: a damaged count or id ends there in a traceback or worse."""
    r = _Reader(d / "cameras.bin")
    params_of: dict[int, int] = {}
    cameras = set()
    for _ in range(r.count(24)):
        camera_id, model_id, width, height = r.take("<iiQQ")
        if model_id not in params_of:
            try:
                params_of[model_id] = len(pycolmap.Camera.create_from_model_id(0, pycolmap.CameraModelId(model_id),
                                                                                1.0, 1, 1).params)
            except (ValueError, TypeError):
                r.fail(f"camera {camera_id} has an unknown camera model id {model_id}")
        r.skip(params_of[model_id], 8)
        cameras.add(camera_id)

    r = _Reader(d / "images.bin")
    points2d: dict[int, int] = {}
    for _ in range(r.count(64 + 1 + 8)):
        image_id, *_pose, camera_id = r.take("<I7dI")
        if camera_id not in cameras:
            r.fail(f"image {image_id} refers to camera {camera_id}, which cameras.bin does not hold")
        r.name()
        (n,) = r.take("<Q")
        r.skip(n, 24)
        points2d[image_id] = n

    r = _Reader(d / "points3D.bin")
    for _ in range(r.count(51)):
        point_id, *_xyz_rgb_error, track_length = r.take("<Q3d3BdQ")
        start = r.at
        r.skip(track_length, 8)
        track = np.frombuffer(r.data, "<i4", 2 * track_length, start).reshape(-1, 2)
        for image_id, index in track:
            if not 0 <= index < points2d.get(int(image_id), 0):
                r.fail(f"point {point_id} is seen in image {image_id} at point {index}, which images.bin does not hold")


def check_text_counts(d: Path, rec: pycolmap.Reconstruction) -> None:
    """COLMAP writes each text file's record count in its header ("# Number of images: 12, ...") and ends it
    with a newline; a file of fewer records, or cut within its last line, lost its end (truncated)."""
    found = {"cameras": rec.num_cameras(), "images": rec.num_images(), "points3D": rec.num_points3D()}
    for stem, label in (("cameras", "cameras"), ("images", "images"), ("points3D", "points")):
        path = d / f"{stem}.txt"
        if not path.is_file() or (d / f"{stem}.bin").is_file():
            continue
        with open(path, "rb") as f:
            header = b"".join(line for line, _ in zip(f, range(8)) if line.startswith(b"#")).decode("utf-8", "replace")
            f.seek(0, os.SEEK_END)
            ends_in_newline = f.tell() == 0 or (f.seek(-1, os.SEEK_END) >= 0 and f.read(1) == b"\n")
        if m := re.search(rf"# Number of {label}: (\d+)", header):
            if int(m.group(1)) != found[stem]:
                raise InputError(path, f"the header promises {int(m.group(1)):,} {label}, the file holds "
                                       f"{found[stem]:,} (truncated?)")
            if not ends_in_newline:
                raise InputError(path, "ends within a line (truncated?): COLMAP ends its files with a newline")


def read_colmap(root: Path, undistort: bool = False
                ) -> tuple[list[Camera], dict[str, pycolmap.Camera], np.ndarray, np.ndarray]:
    """Full-size cameras of the registered images (with their lens model, or undistort: PINHOLE), the distorted
    cameras of the images whose pixels need undistorting (by name), and the SfM points (P, 3) float64 with colours
    (P, 3) float32."""
    d = model_dir(root)
    if all((d / f"{stem}.bin").is_file() for stem in MODEL_FILES):
        check_binary_model(d)
    try:
        rec = pycolmap.Reconstruction(str(d))
    except Exception as e:   # pycolmap raises ValueError, IndexError, RuntimeError, ... for a damaged model
        raise InputError(d, f"cannot read COLMAP model ({e.__class__.__name__}: {' '.join(str(e).split())})") from None
    check_text_counts(d, rec)
    if rec.num_points3D() == 0:
        raise InputError(_model_file(d, "points3D"), "no 3D points (nothing to initialise training from)")

    cameras_file = _model_file(d, "cameras")
    cameras, distorted = [], {}
    for img in rec.images.values():
        if not img.has_pose:  # an image COLMAP could not register has no pose to train with
            continue
        cam = rec.cameras[img.camera_id]
        try:
            name = img.name
        except UnicodeDecodeError:   # pycolmap hands names out as UTF-8
            raise InputError(_model_file(d, "images"), f"image {img.image_id}: its name is not UTF-8") from None
        path = root / "images" / name
        if not path.is_file():
            raise InputError(path, f"image listed in the COLMAP model {d} not found")
        pose = img.cam_from_world()
        camera, dist = make_camera(name, path, cam, pose.rotation.matrix(), pose.translation, cameras_file,
                                   pose_where=_model_file(d, "images"), undistort=undistort)
        check_size(path, image_size(path), (cam.width, cam.height), cameras_file)
        cameras.append(camera)
        if dist is not None:
            distorted[name] = dist
    if not cameras:
        raise InputError(_model_file(d, "images"), "no registered images")

    points = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(xyz).all():
        raise InputError(_model_file(d, "points3D"), "3D points hold NaN or infinite coordinates")
    colors = np.array([p.color for p in points], dtype=np.float32).reshape(-1, 3) / 255.0
    return cameras, distorted, xyz, colors
