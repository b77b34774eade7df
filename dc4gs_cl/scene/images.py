"""Image files through OpenImageIO: read as float RGB in [0, 1], resize, write PNG atomically."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..errors import InputError
from ..files import write_atomic

# The resize filter for -r downscaling. The Inria code resizes with PIL's bicubic (antialiased on
# downscaling); OIIO's "cubic" scales its support with the factor in the same way.
RESIZE_FILTER = "cubic"


def read_image(path: str | os.PathLike) -> np.ndarray:
    """(H, W, C) float32 in [0, 1], C = 1..4 as stored. Raises InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(path, f"cannot read image ({oiio.geterror().strip() or 'unknown format'})")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    finally:
        inp.close()
    if pixels is None or getattr(pixels, "size", 0) == 0:
        raise InputError(path, f"cannot decode image ({oiio.geterror().strip() or 'no pixels'})")
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    if not np.isfinite(pixels).all():
        raise InputError(path, "image holds NaN or infinite values")
    return pixels


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from the file header, without decoding pixels."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(path, f"cannot read image ({oiio.geterror().strip() or 'unknown format'})")
    spec = inp.spec()
    inp.close()
    return spec.width, spec.height


def to_rgb(pixels: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(H, W, C) -> (H, W, 3): grey is repeated, alpha composites onto the background colour.
    OpenImageIO hands out associated (premultiplied) alpha, so the colour is already weighted by alpha."""
    c = pixels.shape[2]
    if c == 1:
        return np.repeat(pixels, 3, axis=2)
    if c == 2:  # grey + alpha
        rgb, a = np.repeat(pixels[..., :1], 3, axis=2), pixels[..., 1:2]
    elif c == 3:
        return pixels
    else:
        rgb, a = pixels[..., :3], pixels[..., 3:4]
    return (rgb + background.reshape(1, 1, 3) * (1.0 - a)).astype(np.float32)


def resize(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resample (H, W, C) float32 to (height, width, C)."""
    h, w, c = pixels.shape
    if (w, h) == (width, height):
        return pixels
    src = oiio.ImageBuf(oiio.ImageSpec(w, h, c, oiio.FLOAT))
    src.set_pixels(oiio.ROI(), np.ascontiguousarray(pixels, dtype=np.float32))
    dst = oiio.ImageBufAlgo.resize(src, filtername=RESIZE_FILTER, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, c))
    out = np.asarray(dst.get_pixels(oiio.FLOAT), dtype=np.float32).reshape(height, width, c)
    return np.clip(out, 0.0, 1.0)


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write (H, W, C) float in [0, 1] as an 8-bit PNG; the file appears complete or not at all."""
    data = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)

    def write(tmp: Path) -> None:
        out = oiio.ImageOutput.create(str(tmp))
        spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.UINT8)
        spec.attribute("png:compressionLevel", 1)   # 3.5x faster than the default for 17% more bytes
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"{path}: cannot write PNG ({oiio.geterror().strip()})")
        ok = out.write_image(data)
        out.close()
        if not ok:
            raise OSError(f"{path}: cannot write PNG ({oiio.geterror().strip()})")
    write_atomic(path, write)
