"""Image files through OpenImageIO: read as float RGB in [0, 1], resize, write PNG atomically."""
from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..errors import InputError
from ..files import write_atomic

# The resize filter for -r downscaling. The Inria code resizes with PIL's bicubic (antialiased on
# downscaling); OIIO's "cubic" scales its support with the factor in the same way.
RESIZE_FILTER = "cubic"
MAX_IMAGE_SIDE = 1 << 16      # pixels: a larger side in an image or a camera is a damaged file, not a photo
MAX_IMAGE_PIXELS = 1 << 28    # 268 Mpixel (16k x 16k): more is a damaged header, refused before decoding
DECODE_COPIES = 2             # float32 copies of an image alive while it is read (decoded, then converted / resized)
DECODE_MEMORY_SHARE = 0.5     # an image whose decoding needs more than this share of the memory available is refused


def read_image(path: str | os.PathLike) -> np.ndarray:
    """(H, W, C) float32 in [0, 1], C = 1..4 as stored. Raises InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found")
    with _decoder_messages_silenced(), _decoder_failures(path):
        inp = _open(path)
        try:
            spec = inp.spec()
            _check_header(path, spec)
            pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
            # A damaged file may still hand out pixels (a truncated JPEG's missing rows come back grey): the
            # decoder's error, not the pixels, says whether the read is whole.
            problem = inp.geterror().strip() if inp.has_error else ""
        finally:
            inp.close()
    if pixels is None or getattr(pixels, "size", 0) == 0 or problem:
        problem = problem or oiio.geterror().strip() or "no pixels"
        raise InputError(path, f"cannot decode image ({_one_line(problem)})")
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    if not np.isfinite(pixels).all():
        raise InputError(path, "image holds NaN or infinite values")
    return pixels


def _check_header(path: Path, spec) -> None:
    """Sizes no photo has come from a damaged header, and one whose decoding the memory available cannot hold (a
    file of 818 KB can decode to 2^28 pixels): refuse them before decoding allocates for them."""
    if not (1 <= spec.width <= MAX_IMAGE_SIDE and 1 <= spec.height <= MAX_IMAGE_SIDE
            and spec.width * spec.height <= MAX_IMAGE_PIXELS and 1 <= spec.nchannels <= 4):
        raise InputError(path, f"image header says {spec.width}x{spec.height} pixels of {spec.nchannels} channels "
                               f"(at most {MAX_IMAGE_SIDE} a side, {MAX_IMAGE_PIXELS:,} pixels, 4 channels)")
    need, available = DECODE_COPIES * 4 * spec.width * spec.height * max(spec.nchannels, 3), memory_available()
    if available is not None and need > DECODE_MEMORY_SHARE * available:
        raise InputError(path, f"image of {spec.width}x{spec.height} pixels: reading it needs {need / 2**30:.1f} GiB, "
                               f"more than {DECODE_MEMORY_SHARE:.0%} of the {available / 2**30:.1f} GiB of memory "
                               "available")


def memory_available() -> int | None:
    """Bytes of memory available to a new allocation (Linux' MemAvailable, else the free pages), None unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def _open(path: Path):
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(path, f"cannot read image ({_one_line(oiio.geterror()) or 'unknown format'})")
    return inp


@contextlib.contextmanager
def _decoder_failures(path: Path):
    """Whatever a damaged file makes OpenImageIO's bindings raise (a header string that is not UTF-8 raises
    UnicodeDecodeError) is an unreadable image, named as such."""
    try:
        yield
    except InputError:
        raise
    except Exception as e:
        raise InputError(path, f"cannot read image ({e.__class__.__name__}: {_one_line(str(e))})") from None


@contextlib.contextmanager
def _decoder_messages_silenced():
    """libpng prints its errors on the process's stderr itself; OpenImageIO hands the same text to us, and we
    report it in one line, so the native stream is muted while a decoder runs."""
    sys.stderr.flush()
    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    os.close(devnull)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _one_line(message: str) -> str:
    """A decoder's message (often several lines) as one line."""
    return " ".join(message.split())


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from the file header, without decoding pixels; the header checked as read_image checks it
    (the scene readers ask this of every image before training starts)."""
    path = Path(path)
    with _decoder_messages_silenced(), _decoder_failures(path):
        inp = _open(path)
        try:
            spec = inp.spec()
        finally:
            inp.close()
        _check_header(path, spec)
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
    # compression level 1: 3.5x faster than the default for 17% more bytes
    _write_8bit(path, (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), {"png:compressionLevel": 1})


JPEG_QUALITY = 95   # the frames of a video kept for SfM (scene/video_frames.py)


def write_jpeg(path: str | os.PathLike, data: np.ndarray) -> None:
    """Write (H, W, 3) uint8 as a JPEG of JPEG_QUALITY, atomically."""
    _write_8bit(path, data, {"Compression": f"jpeg:{JPEG_QUALITY}"})


def _write_8bit(path: str | os.PathLike, data: np.ndarray, attributes: dict) -> None:
    """(H, W, C) uint8 to the format of `path`'s extension, with the writer's attributes."""
    def write(tmp: Path) -> None:
        out = oiio.ImageOutput.create(str(tmp))
        spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.UINT8)
        for name, value in attributes.items():
            spec.attribute(name, value)
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"{tmp.suffix[1:].upper()} writer: {oiio.geterror().strip()}")
        ok = out.write_image(data)
        out.close()
        if not ok:
            raise OSError(f"{tmp.suffix[1:].upper()} writer: {oiio.geterror().strip()}")
    write_atomic(path, write)
