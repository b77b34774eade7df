"""Cameras and scenes as the rest of the trainer sees them.

Conventions (../shared/docs/conventions.md): world-to-camera x_cam = R x_world + t, camera axes x right,
y down, z forward (OpenCV / COLMAP); pinhole intrinsics in pixels with the image's top-left corner at
(0, 0), so the centre of pixel (i, j) is (i + 0.5, j + 0.5). A camera with a lens model (scene/distortion.py)
carries it as `distortion` and is rendered through it; with --undistort (or a model without one) its pixels were
undistorted to a PINHOLE before the Camera was made.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError
from .distortion import Distortion


@dataclass(frozen=True)
class Camera:
    name: str                      # image name as the source lists it; sorting by name gives the split
    width: int                     # size the trainer renders at (after -r downscaling)
    height: int
    fx: float                      # focal lengths and principal point, pixels, at width x height
    fy: float
    cx: float
    cy: float
    R: np.ndarray                  # (3, 3) float64 world-to-camera rotation
    t: np.ndarray                  # (3,) float64 world-to-camera translation
    image_path: Path | None = None  # file the pixels come from (None: a generated scene)
    source_size: tuple[int, int] | None = None  # (width, height) the file must have
    mask_path: Path | None = None   # its mask (scene/masks.py), of the source size; None: every pixel counts
    distortion: Distortion | None = None   # the lens model rendered through (resolution-free); None: a pinhole

    def at_resolution(self, resolution: int | None, max_width: int | None = None) -> "Camera":
        """This camera after the CLI's -r: 1/resolution of its size, or (None) its size but at most
        max_width wide. InputError if the setting makes no sense or the image vanishes."""
        w, h = self.width, self.height
        if resolution is not None and resolution < 1:
            raise InputError(None, f"-r {resolution}: the resolution divisor must be an integer >= 1")
        if resolution is None:
            scale = 1.0 if max_width is None else min(1.0, max_width / w)
            setting = f"scaling to width {max_width}"
        else:
            scale, setting = 1.0 / resolution, f"-r {resolution}"
        width, height = round(w * scale), round(h * scale)
        if width == 0 or height == 0:
            raise InputError(self.image_path, f"{setting} makes a {w}x{h} image vanish")
        return self.resized(width, height)

    @property
    def file_stem(self) -> str:
        """The image name without its extension, folders joined by "_" (a root or drive, "." and ".." left out): a
        file name for this view's outputs, inside whatever folder they go to (no separator; never hidden: no leading
        dot, so "../../x/y.png" gives "x_y", never ".._.._x_y"; never ""). No other view of a scene shares it
        (unique_file_stems)."""
        name = Path(self.name.replace("\\", "/"))
        parts = (part for part in name.with_suffix("").parts if part not in (name.anchor, "/", ".", ".."))
        return "_".join(parts).lstrip(".") or "_"

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, C = -R^T t."""
        return -self.R.T @ self.t

    @staticmethod
    def look_at(name: str, eye, target, width: int, height: int, fov_x: float, up=(0.0, 0.0, 1.0)) -> "Camera":
        """A pinhole camera at `eye` looking at `target` (world up `up`), horizontal field of view fov_x
        (radians), principal point at the image centre."""
        eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
        z = target - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9:   # looking along `up`: any perpendicular will do
            x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)             # image y points down
        R = np.stack([x, y, z])
        f = 0.5 * width / np.tan(0.5 * fov_x)
        return Camera(name, width, height, f, f, 0.5 * width, 0.5 * height, R, -R @ eye)

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera rendering at another size (intrinsics scale with the size)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=self.cx * sx, cy=self.cy * sy)


@dataclass
class Scene:
    root: Path                     # the folder the scene was read from
    train: list[Camera]
    test: list[Camera]
    points: np.ndarray | None      # (P, 3) float64 SfM points, or None (random initialisation)
    colors: np.ndarray | None      # (P, 3) float32 in [0, 1]
    background: np.ndarray         # (3,) float32 in [0, 1]; RGBA images are composited onto it
    read_image: Callable[[Camera], np.ndarray] = field(repr=False)  # -> (H, W, 3) float32 in [0, 1]
    read_mask: Callable[[Camera], np.ndarray | None] = field(repr=False, default=lambda cam: None)
    # -> (H, W) bool, True where a pixel counts (scene/masks.py), or None: all count
    extent: float = 0.0            # filled by __post_init__ from the training cameras

    def __post_init__(self):
        if not self.extent:
            self.extent = scene_extent(self.train)

    def image(self, cam: Camera) -> np.ndarray:
        return self.read_image(cam)

    def mask(self, cam: Camera) -> np.ndarray | None:
        return self.read_mask(cam)

    def read_all_images(self) -> None:
        """Decode every view's image and mask now (they are kept once decoded), so that a damaged file stops
        a command before it writes anything rather than midway."""
        for cam in self.train + self.test:
            self.read_image(cam)
            self.read_mask(cam)


def view_sizes(cameras: list[Camera], shown: int = 3) -> str:
    """The views' image sizes for a one-line summary: "WxH" where they share one, else the most common first
    with their counts ("400x400 x 5, 1x1 x 1"), at most `shown` of them and how many more."""
    counts: dict[tuple[int, int], int] = {}
    for cam in cameras:
        counts[(cam.width, cam.height)] = counts.get((cam.width, cam.height), 0) + 1
    if len(counts) <= 1:
        return "".join(f"{w}x{h}" for w, h in counts)
    common = sorted(counts.items(), key=lambda item: -item[1])
    text = ", ".join(f"{w}x{h} x {n}" for (w, h), n in common[:shown])
    return text + (f" and {len(common) - shown} more sizes" if len(common) > shown else "")


def lens_models(cameras: list[Camera]) -> str:
    """The lens models the views render through, for the scene's summary line: "" when all are pinholes, else
    ", OPENCV rendered directly" (the models, by name)."""
    models = sorted({c.distortion.model for c in cameras if c.distortion is not None})
    return f", {' and '.join(models)} rendered directly" if models else ""


def unique_file_stems(where: Path, cameras: list[Camera]) -> None:
    """InputError (about `where`: the file listing the views) naming the first two views whose outputs would share
    a file name (Camera.file_stem): an image listed twice, or names that differ only in their folders' separators or
    root."""
    seen: dict[str, str] = {}
    for cam in cameras:
        other = seen.get(cam.file_stem)
        seen[cam.file_stem] = cam.name
        if other is not None:
            problem = (f"image {cam.name!r} is listed twice" if other == cam.name else
                       f"views {other!r} and {cam.name!r} would write one output file ({cam.file_stem!r}.png)")
            raise InputError(where, f"{problem}: every view needs a name of its own")


def scene_extent(cameras: list[Camera]) -> float:
    """1.1 x the largest distance of a camera centre from the mean of the centres (the Inria rule).

    With a single camera the distance is 0; like the Inria code we then fall back to 1.0 so that
    thresholds and learning rates stay meaningful.
    """
    centers = np.array([c.center for c in cameras], dtype=np.float64).reshape(-1, 3)
    if len(centers) == 0:
        return 1.0
    radius = float(np.linalg.norm(centers - centers.mean(axis=0), axis=1).max())
    return 1.1 * radius if radius > 0 else 1.0


TEST_SPLITS = ("llff", "interpolated")


def split_train_test(cameras: list[Camera], test_every: int = 8,
                     test_split: str = "llff") -> tuple[list[Camera], list[Camera]]:
    """Hold out test cameras from the cameras sorted by name (the order along the camera path in captured scenes).

    llff: index % test_every == 0 (the field's "llffhold 8" rule). It holds out the path's first view, which
    the training views see from one side only: an extrapolated view, where a few floaters move PSNR by dBs in
    sparse scenes. interpolated: as many test cameras, ceil(n / test_every), each in the middle of one of that
    many equal runs of the path, never its first or last view, so that training views lie on both sides of
    each. test_every 0: no test cameras."""
    if test_split not in TEST_SPLITS:
        raise ValueError(f"test split {test_split!r} is not one of {', '.join(TEST_SPLITS)}")
    cams = sorted(cameras, key=lambda c: c.name)
    n = len(cams)
    if test_every <= 0:
        return cams, []
    if test_split == "llff":
        held = set(range(0, n, test_every))
    else:
        count = -(-n // test_every)
        held = {min(n - 2, max(1, int((k + 0.5) * n / count))) for k in range(count)} if n >= 3 else set()
    return [c for i, c in enumerate(cams) if i not in held], [c for i, c in enumerate(cams) if i in held]
