"""Scenes from disk: COLMAP or NeRF folders, or the built-in scene's name -> Scene with PINHOLE cameras at the
training resolution, distorted ones keeping their lens model (or, undistort=True, made pinholes). Images are read
lazily through Scene.read_image (undistorted on first use where the camera was made a pinhole) and kept in memory once
decoded."""
from __future__ import annotations

import os
import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np
import pycolmap

from ..errors import InputError
from . import colmap, nerf
from .builtin import BUILTIN_SCENE, builtin_scene
from .camera import Camera, Scene, split_train_test, unique_file_stems
from .images import read_image, resize, to_rgb
from .masks import keep_from, with_masks
from .undistort import check_size, undistorted_pixels

DEFAULT_MAX_WIDTH = 1600  # the Inria default: wider images train at this width unless -r is given


def load_scene(path: str | os.PathLike, resolution: int | None = None, cache_dir: str | os.PathLike | None = None,
               test_every: int = 8, white_background: bool = False, alpha_mask: bool = False,
               test_split: str = "llff", undistort: bool = False) -> Scene:
    """Load a COLMAP scene (sparse/0/ + images/) or a NeRF scene (transforms.json or
    transforms_train.json [+ transforms_test.json]; `path` may also be one of these files).

    resolution: the CLI's -r: None = full size but at most DEFAULT_MAX_WIDTH wide, r = 1/r of the size.
    cache_dir: where undistorted images are cached (None: a temporary folder removed at exit).
    test_every, test_split: COLMAP and transforms.json scenes hold out every test_every-th image by name (0: none),
      from the first (llff) or from the middle of the path (interpolated; camera.split_train_test).
    alpha_mask: an image's alpha channel masks pixels out (scene/masks.py) instead of being composited.
    undistort: distorted cameras become pinholes and their pixels are undistorted, instead of the camera keeping its
      lens model (scene/distortion.py) for the kernels to render through.
    """
    if str(path) == BUILTIN_SCENE:
        if white_background:
            raise InputError(None, "--white-background: the built-in scene has its own sky colour as background")
        if alpha_mask:
            raise InputError(None, "--alpha-mask: the built-in scene's images have no alpha channel")
        return builtin_scene(resolution=resolution, test_every=test_every, test_split=test_split)
    path = Path(path)
    if not path.exists():
        raise InputError(path, "scene folder not found")
    points = colors = None
    root = path if path.is_dir() else path.parent
    if path.is_dir() and (model := colmap.model_dir(path)) is not None:
        cameras, distorted, points, colors = colmap.read_colmap(path, undistort)
        train, test = split_train_test(cameras, test_every, test_split)
        listing = next((f for f in (model / "images.bin", model / "images.txt") if f.is_file()), model)
    elif files := nerf.transforms_files(path):
        train, test, distorted = nerf.read_nerf(files, test_every, test_split, undistort)
        listing = files[0] if len(files) == 1 else root
    else:
        raise InputError(path, "not a COLMAP or NeRF scene: expected sparse/0/ or transforms*.json")
    unique_file_stems(listing, train + test)   # named: the file listing the views (the folder, for several)
    train = [c.at_resolution(resolution, DEFAULT_MAX_WIDTH) for c in with_masks(root, train)]
    test = [c.at_resolution(resolution, DEFAULT_MAX_WIDTH) for c in with_masks(root, test)]
    background = np.full(3, 1.0 if white_background else 0.0, dtype=np.float32)
    reader = _ImageReader(distorted, background, cache_dir, alpha_mask)
    return Scene(root=root, train=train, test=test, points=points, colors=colors, background=background,
                 read_image=reader, read_mask=reader.mask)


class _ImageReader:
    """Scene.read_image: (H, W, 3) float32 in [0, 1] at the camera's size, decoded once per camera."""

    def __init__(self, distorted: dict[str, pycolmap.Camera], background: np.ndarray,
                 cache_dir: str | os.PathLike | None, alpha_mask: bool = False):
        self.distorted = distorted
        self.background = background
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        self.alpha_mask = alpha_mask
        self.memory: dict[tuple[str, int, int], np.ndarray] = {}
        self.alpha_keep: dict[tuple[str, int, int], np.ndarray] = {}   # --alpha-mask: from the images' alpha
        self.masks: dict[tuple[str, int, int], np.ndarray | None] = {}

    def _cache(self) -> Path:
        if self.cache_dir is None:  # made on first use: scenes without distortion never need one
            self.cache_dir = Path(tempfile.mkdtemp(prefix="dc4gs-undistorted-"))
            weakref.finalize(self, shutil.rmtree, self.cache_dir, True)
        return self.cache_dir

    def _source(self, cam: Camera, path: Path, cache_name: str) -> np.ndarray:
        """(H, W, C) pixels of an image or mask file of this view, undistorted where the camera is."""
        dist = self.distorted.get(cam.name)
        pixels = read_image(path) if dist is None else undistorted_pixels(path, cache_name, dist, self._cache())
        check_size(path, (pixels.shape[1], pixels.shape[0]), cam.source_size)
        return pixels

    def __call__(self, cam: Camera) -> np.ndarray:
        key = (cam.name, cam.width, cam.height)
        if key not in self.memory:
            pixels = self._source(cam, cam.image_path, cam.name)
            image = resize(to_rgb(pixels, self.background), cam.width, cam.height)
            image.flags.writeable = False  # shared by every caller: a stray in-place edit must fail loudly
            self.memory[key] = image
            if self.alpha_mask and pixels.shape[2] in (2, 4):
                self.alpha_keep[key] = keep_from(resize(pixels[..., -1:], cam.width, cam.height))
        return self.memory[key]

    def mask(self, cam: Camera) -> np.ndarray | None:
        """(H, W) bool, True where the pixel counts, or None (every pixel counts)."""
        key = (cam.name, cam.width, cam.height)
        if key not in self.masks:
            keep = None
            if self.alpha_mask:
                self(cam)   # decoding the image sets its alpha mask, if it has alpha
                keep = self.alpha_keep.get(key)
            if cam.mask_path is not None:
                pixels = resize(self._source(cam, cam.mask_path, cam.name + "#mask"), cam.width, cam.height)
                keep = keep_from(pixels) if keep is None else keep & keep_from(pixels)
            if keep is not None:
                keep.flags.writeable = False
            self.masks[key] = keep
        return self.masks[key]
