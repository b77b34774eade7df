"""NeRF scenes: Blender transforms_{train,test}.json or instant-ngp transforms.json.

transform_matrix is camera-to-world in OpenGL axes (x right, y up, z back); intrinsics come from
camera_angle_x (Blender) or fl_x, fl_y, cx, cy, w, h and OpenCV distortion (instant-ngp), given at the
top level or per frame (per frame wins).
"""
from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pycolmap

from ..errors import InputError
from .camera import Camera, split_train_test
from .images import image_size
from .undistort import check_size, make_camera

# Tried in this order when file_path has no extension (Blender writes "./train/r_0").
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".exr")
GL_TO_CV = np.diag([1.0, -1.0, -1.0])  # flips the camera's y and z axes: OpenGL -> OpenCV


def transforms_files(path: Path) -> list[Path]:
    """The JSON files of a NeRF scene (a folder, or one of its JSON files): [train, test] for Blender
    (test only if present), [transforms.json] for instant-ngp, [] when there are none."""
    if path.is_file():
        if path.suffix.lower() != ".json":
            return []
        folder, first = path.parent, path
    else:
        folder = path
        first = next((f for f in (path / "transforms_train.json", path / "transforms.json") if f.is_file()), None)
        if first is None:
            return []
    test = folder / "transforms_test.json"
    return [first, test] if first.name == "transforms_train.json" and test.is_file() else [first]


def read_nerf(files: list[Path], test_every: int, test_split: str = "llff", undistort: bool = False
              ) -> tuple[list[Camera], list[Camera], dict[str, pycolmap.Camera]]:
    """Train and test cameras (full size, with their lens model or, undistort, PINHOLE) and the distorted cameras
    by name. Blender files carry their own split (transforms_val.json is ignored); transforms.json is split by
    split_train_test."""
    distorted: dict[str, pycolmap.Camera] = {}
    if files[0].name == "transforms_train.json":
        train = _read_transforms(files[0], distorted, undistort)
        test = _read_transforms(files[1], distorted, undistort) if len(files) > 1 else []
    else:
        train, test = split_train_test(_read_transforms(files[0], distorted, undistort), test_every, test_split)
    return train, test, distorted


def _read_transforms(path: Path, distorted: dict[str, pycolmap.Camera], undistort: bool) -> list[Camera]:
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise InputError(path, f"cannot read transforms JSON ({e})") from None
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list) or not frames:
        raise InputError(path, "no frames listed")
    cameras = []
    for i, frame in enumerate(frames):
        try:
            info = {**meta, **frame}  # per-frame intrinsics override the top level
            name = frame["file_path"]
            if not isinstance(name, str):
                raise TypeError(f"file_path must be a string, not {json.dumps(name)[:40]}")
            image = _image_file(path, name)
            header = image_size(image)
            size = (round(_number(info, "w")), round(_number(info, "h"))) if "w" in info and "h" in info else header
            check_size(image, header, size, path)
            R, t = _world_to_camera(_numbers(frame["transform_matrix"], "transform_matrix"), path, i)
            camera, dist = make_camera(name, image, _colmap_camera(info, size, path), R, t, path, undistort=undistort)
            if "mask_path" in frame:   # nerfstudio's per-frame mask (scene/masks.py)
                if not isinstance(frame["mask_path"], str):
                    raise TypeError(f"mask_path must be a string, not {json.dumps(frame['mask_path'])[:40]}")
                mask = path.parent / frame["mask_path"]
                if not mask.is_file():
                    raise InputError(path, f"frame {i}: mask {mask} not found")
                camera = replace(camera, mask_path=mask)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(path, f"frame {i}: malformed entry ({type(e).__name__}: {e})") from None
        cameras.append(camera)
        if dist is not None:
            distorted[name] = dist
    return cameras


def _number(info: dict, key: str) -> float:
    """A JSON number (not a bool, a string or null), finite."""
    value = info[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{key} must be a finite number, not {json.dumps(value)[:40]}")
    return float(value)


def _numbers(value, key: str) -> np.ndarray:
    """A nested list of JSON numbers as float64 (bools, strings and nulls refused, as NaN and Inf)."""
    def ok(v):
        return all(ok(x) for x in v) if isinstance(v, list) else isinstance(v, (int, float)) and not isinstance(v, bool)
    array = np.asarray(value, dtype=np.float64) if isinstance(value, list) and ok(value) else None
    if array is None or not np.isfinite(array).all():
        raise ValueError(f"{key} must be a matrix of finite numbers")
    return array


def _image_file(transforms: Path, file_path: str) -> Path:
    base = transforms.parent / file_path
    for candidate in (base, *(base.with_name(base.name + ext) for ext in IMAGE_EXTENSIONS)):
        if candidate.is_file():
            return candidate
    raise InputError(transforms, f"image {base} not found (also tried the extensions {', '.join(IMAGE_EXTENSIONS)})")


def _world_to_camera(c2w: np.ndarray, path: Path, i: int) -> tuple[np.ndarray, np.ndarray]:
    if c2w.shape not in ((4, 4), (3, 4)):
        raise InputError(path, f"frame {i}: transform_matrix must be 4x4 or 3x4, not {c2w.shape}")
    rot = c2w[:3, :3] @ GL_TO_CV
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-3):  # a scaled or sheared matrix is no camera pose
        raise InputError(path, f"frame {i}: transform_matrix's rotation part is not orthonormal")
    R = rot.T
    return R, -R @ c2w[:3, 3]


def _colmap_camera(info: dict, size: tuple[int, int], path: Path) -> pycolmap.Camera:
    """The camera as COLMAP would model it: PINHOLE, or OPENCV / FULL_OPENCV / OPENCV_FISHEYE with distortion."""
    w, h = size
    if "fl_x" in info:
        fx = _number(info, "fl_x")
        fy = _number(info, "fl_y") if "fl_y" in info else fx
    elif "camera_angle_x" in info:
        fx = 0.5 * w / math.tan(0.5 * _number(info, "camera_angle_x"))
        fy = 0.5 * h / math.tan(0.5 * _number(info, "camera_angle_y")) if "camera_angle_y" in info else fx
    else:
        raise InputError(path, "no focal length: expected fl_x or camera_angle_x")
    cx = _number(info, "cx") if "cx" in info else w / 2
    cy = _number(info, "cy") if "cy" in info else h / 2
    k1, k2, k3, k4, p1, p2 = (_number(info, k) if k in info else 0.0 for k in ("k1", "k2", "k3", "k4", "p1", "p2"))
    # nerfstudio writes camera_model instead of instant-ngp's is_fisheye
    if info.get("is_fisheye") or info.get("camera_model") == "OPENCV_FISHEYE":
        model, params = "OPENCV_FISHEYE", [fx, fy, cx, cy, k1, k2, k3, k4]
    elif k3 or k4:
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, 0.0, 0.0]
    elif k1 or k2 or p1 or p2:
        model, params = "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
    else:
        model, params = "PINHOLE", [fx, fy, cx, cy]
    cam = pycolmap.Camera.create_from_model_name(0, model, fx, w, h)
    cam.params = params
    return cam
