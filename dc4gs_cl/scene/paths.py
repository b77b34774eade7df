"""Camera paths through a scene's training cameras, for `render --path` (a fly-through video):

    interpolated  through the training cameras in name order (the capture's order): positions on a Catmull-Rom
                  spline through the camera centres, rotations by spherical interpolation, focal lengths
                  linearly; frame 0 is the first camera and the last frame the last one
    orbit         a circle around the point the cameras look at (the least-squares nearest point to their
                  optical axes), at their mean distance from it and mean height along their mean up direction,
                  starting where the first camera is and looking at that point

Every frame has the first training camera's image size and the principal point at its centre.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..geometry import quat_to_rotmat, rotmat_to_quat, slerp
from .camera import Camera

PATH_KINDS = ("interpolated", "orbit")
MAX_PATH_FRAMES = 100_000   # about 55 minutes at 30 fps (--frames 1000000000 took 8 GB before a frame was written)


class CameraPath(Sequence):
    """A path's cameras, each made when it is asked for, so that a path's memory does not grow with its frames."""

    def __init__(self, frames: int, frame: Callable[[int], Camera]):
        self._frames, self._frame = frames, frame

    def __len__(self) -> int:
        return self._frames

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._frame(j) for j in range(*i.indices(self._frames))]
        if not -self._frames <= i < self._frames:
            raise IndexError(i)
        return self._frame(i % self._frames)


def camera_path(cams: list[Camera], kind: str, frames: int) -> CameraPath:
    """`frames` cameras along the path of `kind` through `cams` (the training cameras; at least two)."""
    if kind not in PATH_KINDS:
        raise ValueError(f"path {kind!r}: one of {', '.join(PATH_KINDS)}")
    if len(cams) < 2:
        raise InputError(None, f"--path needs at least two training cameras, the scene has {len(cams)}")
    if not 2 <= frames <= MAX_PATH_FRAMES:
        raise InputError(None, f"--frames {frames} must be at least 2" if frames < 2 else
                               f"--frames {frames:,}: at most {MAX_PATH_FRAMES:,} (a video of "
                               f"{MAX_PATH_FRAMES // 1800} minutes at 30 fps)")
    cams = sorted(cams, key=lambda c: c.name)
    return (_interpolated if kind == "interpolated" else _orbit)(cams, frames)


def _camera(name: str, like: Camera, R: np.ndarray, center: np.ndarray, fx: float, fy: float) -> Camera:
    return Camera(name, like.width, like.height, fx, fy, 0.5 * like.width, 0.5 * like.height, R, -R @ center)


def _interpolated(cams: list[Camera], frames: int) -> CameraPath:
    first = cams[0]
    centres = np.array([c.center for c in cams])
    quats = [rotmat_to_quat(c.R) for c in cams]
    # focal lengths at the first camera's size, so that frames of one size zoom as the cameras did
    focals = np.array([(c.fx * first.width / c.width, c.fy * first.height / c.height) for c in cams])
    step = (len(cams) - 1) / (frames - 1)   # np.linspace(0, len(cams) - 1, frames)'s, frame by frame

    def frame(f: int) -> Camera:
        s = float(len(cams) - 1) if f == frames - 1 else f * step
        i = min(int(s), len(cams) - 2)
        u = s - i
        p = [centres[max(i - 1, 0)], centres[i], centres[i + 1], centres[min(i + 2, len(cams) - 1)]]
        fx, fy = (1 - u) * focals[i] + u * focals[i + 1]
        return _camera(f"{f:05d}", first, quat_to_rotmat(slerp(quats[i], quats[i + 1], u)[None])[0],
                       catmull_rom(*p, u), fx, fy)
    return CameraPath(frames, frame)


def _orbit(cams: list[Camera], frames: int) -> list[Camera]:
    first = cams[0]
    target = look_at_point(cams)
    up = np.mean([-c.R[1] for c in cams], axis=0)   # image y points down: a camera's up is -R[1]
    up /= np.linalg.norm(up)
    offsets = np.array([c.center for c in cams]) - target
    height = float(np.mean(offsets @ up))
    flat = offsets - np.outer(offsets @ up, up)
    radius = float(np.mean(np.linalg.norm(flat, axis=1)))
    e1 = flat[0] / np.linalg.norm(flat[0]) if np.linalg.norm(flat[0]) > 1e-12 else _perpendicular(up)
    e2 = np.cross(up, e1)
    fov_x = 2 * np.arctan(0.5 * first.width / first.fx)
    step = 2 * np.pi / frames   # np.linspace(0, 2 pi, frames, endpoint=False)'s, frame by frame

    def frame(f: int) -> Camera:
        angle = f * step
        eye = target + height * up + radius * (np.cos(angle) * e1 + np.sin(angle) * e2)
        return Camera.look_at(f"{f:05d}", eye, target, first.width, first.height, fov_x, up=up)
    return CameraPath(frames, frame)


def look_at_point(cams: list[Camera]) -> np.ndarray:
    """The point nearest (least squares) to every camera's optical axis; for axes all parallel, the centres' mean
    pushed along them by their mean distance from it."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        P = np.eye(3) - np.outer(c.R[2], c.R[2])   # projects off the axis (R[2]: the viewing direction)
        A += P
        b += P @ c.center
    if np.linalg.cond(A) < 1e8:
        return np.linalg.solve(A, b)
    centres = np.array([c.center for c in cams])
    mean = centres.mean(axis=0)
    return mean + np.mean([c.R[2] for c in cams], axis=0) * max(np.linalg.norm(centres - mean, axis=1).mean(), 1.0)


def cameras_behind(cams: list[Camera], point: np.ndarray) -> int:
    """How many of the cameras have `point` behind them (an orbit around it shows them little or nothing)."""
    return sum(float((point - c.center) @ c.R[2]) <= 0 for c in cams)


def _perpendicular(v: np.ndarray) -> np.ndarray:
    w = np.cross(v, [1.0, 0.0, 0.0] if abs(v[0]) < 0.9 else [0.0, 1.0, 0.0])
    return w / np.linalg.norm(w)


def catmull_rom(p0, p1, p2, p3, u: float) -> np.ndarray:
    """The uniform Catmull-Rom spline from p1 (u = 0) to p2 (u = 1)."""
    return 0.5 * ((2 * p1) + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
                  + (3 * p1 - p0 - 3 * p2 + p3) * u ** 3)
