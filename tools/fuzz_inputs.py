"""Fuzz every file dc4gs-cl reads: mutate a valid input, read it the way the commands do, and check that
each case ends one of the allowed ways.

    python tools/fuzz_inputs.py [--cases N] [--seed S] [--format NAME ...] [--cli]

Formats: images (PNG 8 and 16 bit, JPEG, EXR, with and without alpha, read through a scene), the 3DGS PLY,
COLMAP binary and text (cameras, images, points3D), the formats `export` writes (.splat, .spz, compressed
PLY, as `render` and `view` read them), transforms.json (Blender and instant-ngp), a folder of photos and a
video as `sfm` reads them before SfM runs (SfM itself is not run: seconds a case), checkpoints and a run's
config.json. Every input lives under a folder whose name holds spaces and non-ASCII letters,
and image names hold non-ASCII letters (and spaces where the format allows them).

Outcomes of a case:
  same     read exactly as the unmutated input (the mutation hit bytes that do not matter)
  error    InputError: one line naming the mutated file (or, for a COLMAP model that pycolmap refuses as a
           whole, its folder)
  changed  read, with other values that pass every check the reader makes (finite, in range, consistent):
           allowed only where a mutation changes value bytes in a format without a checksum (a flipped bit
           in a PLY float or a JPEG coefficient), which no reader can tell from the real thing
Anything else is a finding: another exception (a traceback for the user), a message of several lines or
naming no file, a truncated or emptied file read without error, a non-finite value read, and a bomb (a .spz
inflating past its data, a header promising more than the file holds) whose read takes more than
READ_MEMORY_BOUND. With --cli the
first error case of each format is also run through the command line (exit 2, one line on stderr, no
output folder).
"""
from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import math
import re
import shutil
import sys
import tempfile
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from dc4gs_cl.apps.export import FORMATS as EXPORT_FORMATS
from dc4gs_cl.apps.export import export_model, read_model_file
from dc4gs_cl.apps.export.splat import SPLAT_RECORD
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.errors import InputError
from dc4gs_cl.files import write_json
from dc4gs_cl.ply import read_ply, write_ply
from dc4gs_cl.run_folder import RunFolder
from dc4gs_cl.scene.images import read_image
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.sfm import check_photos, find_photos
from dc4gs_cl.scene.sfm_settings import SfMSettings
from dc4gs_cl.scene.video_frames import frames_from_video
from dc4gs_cl.reference.testing import random_model

FOLDER = "fuzz scène ü"     # every input lives under a name with a space and non-ASCII letters
W, H = 24, 16               # image size


# ------------------------------------------------------------------------------------------------ inputs

def write_image(path: Path, pixels: np.ndarray, dtype: str) -> None:
    """Write (H, W, C) float pixels as 8- or 16-bit integers or half floats (EXR)."""
    import OpenImageIO as oiio
    path.parent.mkdir(parents=True, exist_ok=True)
    if dtype == "half":
        kind, data = oiio.HALF, np.ascontiguousarray(pixels, np.float32)
    else:
        top = np.iinfo(dtype).max
        kind, data = ({"uint8": oiio.UINT8, "uint16": oiio.UINT16}[dtype],
                      (np.clip(pixels, 0, 1) * top + 0.5).astype(dtype))
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], kind)), oiio.geterror()
    assert out.write_image(data), oiio.geterror()
    out.close()


def image_pixels(rng, channels: int) -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W] / np.array([H, W]).reshape(2, 1, 1)
    base = np.stack([x, y, 0.5 + 0.4 * np.sin(6 * x * y)] + [0.3 + 0.7 * x] * (channels - 3), axis=2)
    return np.clip(base + rng.normal(0, 0.02, base.shape), 0, 1).astype(np.float32)


def look_at_c2w(center, target=(0.0, 0.0, 0.0)) -> list:
    """A NeRF transform_matrix (camera-to-world, OpenGL axes) looking from center at target."""
    center = np.asarray(center, float)
    back = center - np.asarray(target, float)
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, center
    return m.tolist()


def nerf_scene(root: Path, rng, ext: str = ".png", dtype: str = "uint8", channels: int = 3,
               style: str = "instant-ngp") -> Path:
    """A 3-frame NeRF scene; returns its first image (instant-ngp style) or its JSON file."""
    names = [f"vue {i} é{ext}" for i in range(3)]
    for name in names:
        write_image(root / "images" / name, image_pixels(rng, channels), dtype)
    frames = [{"file_path": f"images/{n}", "transform_matrix": look_at_c2w((3 * math.cos(a), 3 * math.sin(a), 1.0))}
              for n, a in zip(names, (0.0, 0.6, 1.2))]
    if style == "blender":
        write_json(root / "transforms_train.json", {"camera_angle_x": 0.8, "frames": frames})
        return root / "transforms_train.json"
    write_json(root / "transforms.json", {"fl_x": 20.0, "fl_y": 21.0, "cx": W / 2, "cy": H / 2, "w": W, "h": H,
                                          "frames": frames})
    return root / "images" / names[0] if style == "image" else root / "transforms.json"


def colmap_scene(root: Path, rng, kind: str) -> Path:
    """A COLMAP model (2 cameras, 3 images, 40 points seen by 2-3 images each) as pycolmap writes it."""
    import pycolmap
    names = [f"vue_{i}_é.png" for i in range(3)]
    for name in names:
        write_image(root / "images" / name, image_pixels(rng, 3), "uint8")
    points = rng.uniform(-1, 1, (40, 3))
    text = root / "text"
    text.mkdir()
    # camera 2 a lens model rendered directly (scene/distortion.py reads its coefficients)
    (text / "cameras.txt").write_text(f"1 PINHOLE {W} {H} 20 21 12 8\n2 {LENS} {W} {H} 19 19 12 8 {LENS_K}\n")
    observations: list[list] = [[] for _ in names]
    tracks = []
    lines = []
    for i, name in enumerate(names):
        angle = 0.5 * i
        R = np.array([[math.cos(angle), 0, -math.sin(angle)], [0, 1, 0], [math.sin(angle), 0, math.cos(angle)]])
        t = np.array([0.0, 0.0, 4.0])
        q = np.array([math.cos(-angle / 2), 0.0, math.sin(-angle / 2), 0.0])   # COLMAP (w, x, y, z) of R
        for p_id, xyz in enumerate(points, start=1):
            if (p_id + i) % 4 == 0:                  # every point seen by 2 or 3 of the images
                continue
            c = R @ xyz + t
            observations[i].append((20 * c[0] / c[2] + 12, 21 * c[1] / c[2] + 8, p_id))
        lines.append(f"{i + 1} {' '.join(map(str, q))} {' '.join(map(str, t))} {1 + i % 2} {name}\n"
                     + " ".join(f"{x} {y} {p}" for x, y, p in observations[i]) + "\n")
    (text / "images.txt").write_text("".join(lines))
    for p_id, xyz in enumerate(points, start=1):
        track = [(i + 1, k) for i in range(3) for k, o in enumerate(observations[i]) if o[2] == p_id]
        tracks.append(f"{p_id} {xyz[0]} {xyz[1]} {xyz[2]} 200 120 40 0.5 " + " ".join(f"{a} {b}" for a, b in track))
    (text / "points3D.txt").write_text("\n".join(tracks) + "\n")
    model = root / "sparse" / "0"
    model.mkdir(parents=True)
    rec = pycolmap.Reconstruction(str(text))
    (rec.write_binary if kind == "bin" else rec.write_text)(str(model))
    shutil.rmtree(text)
    for extra in ("rigs", "frames"):                 # as in models from COLMAP before 3.12 (the shared scenes)
        for p in model.glob(f"{extra}.*"):
            p.unlink()
    return model


LENS, LENS_K = "OPENCV", "-0.05 0.01 0.001 -0.001"   # colmap_scene's second camera: k1 k2 p1 p2


def text_folding_lens(data: bytes, rng, path) -> bytes:
    """The lens camera's k1 made so strong that its radial map turns back inside the image (a polynomial folding
    far-off points into the picture): refused when the scene is read."""
    k1 = float(rng.uniform(-40.0, -5.0))
    return data.replace(f"{LENS} {W} {H} 19 19 12 8 -0.05".encode(), f"{LENS} {W} {H} 19 19 12 8 {k1}".encode())


def read_scene(root: Path):
    scene = load_scene(root, test_every=0)
    scene.read_all_images()
    for c in scene.train:   # every view's outputs named inside the folder they go to
        stem = c.file_stem
        if "/" in stem or "\\" in stem or stem in ("", ".", ".."):
            raise AssertionError(f"view {c.name!r}: output name {stem!r} leaves its folder")
    cams = [(c.name, c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.R, c.t) for c in scene.train]
    return {"cameras": cams, "points": scene.points, "colors": scene.colors,
            "images": [scene.image(c) for c in scene.train]}


def photo_folder(root: Path, rng) -> Path:
    """The folder of photos `sfm` and `train --scene PHOTOS` read (no sparse model); returns its first photo."""
    for i in range(3):
        write_image(root / "photos" / f"photo {i} é.jpg", image_pixels(rng, 3), "uint8")
    return root / "photos" / "photo 0 é.jpg"


def read_photo_folder(path: Path):
    """The photos as SfM's check reads them before anything is written (each decoded whole, one size)."""
    root = path.parent
    names = find_photos(root)
    check_photos(root, names, SfMSettings())
    return {n: read_image(root / n) for n in names}


def video_input(root: Path, rng) -> Path:
    """A short clip (MPEG-4 part 2, as PyAV writes it) for `sfm VIDEO` / `train --scene VIDEO`."""
    import av
    path = root / "clip é.mp4"
    root.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 4 * W, 4 * H, "yuv420p"
        for _ in range(8):
            pixels = np.repeat(np.repeat(image_pixels(rng, 3), 4, 0), 4, 1)
            frame = av.VideoFrame.from_ndarray((pixels * 255 + 0.5).astype(np.uint8), format="rgb24")
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    return path


def read_video(path: Path):
    """The frames a video's scene keeps (frames_from_video into a fresh folder), as their JPEGs' pixels."""
    with tempfile.TemporaryDirectory() as scene:
        names = frames_from_video(path, Path(scene), target=3)
        return {n: read_image(Path(scene) / "images" / n) for n in names}


def sfm_cli(path: Path, out: Path) -> list[str]:
    return ["sfm", str(path if path.suffix == ".mp4" else path.parent), "--no-progress", "--out", str(out)]


def ply_input(root: Path, rng) -> Path:
    path = root / "modèle un.ply"
    write_ply(path, random_model(rng, 12, sh_degree=1))
    return path


def export_input(fmt: str):
    """A random model exported in `fmt` (apps/export), as `render --ply` and `view` read it."""
    def build(root: Path, rng) -> Path:
        path = root / f"modèle un{EXPORT_FORMATS[fmt][0]}"
        root.mkdir(parents=True, exist_ok=True)
        export_model(random_model(rng, 300, sh_degree=1), path)   # compressed PLY: two chunks
        return path
    return build


def read_ply_values(path: Path, read=read_ply):
    m = read(path)
    return {"means": m.means, "scales": m.log_scales, "quats": m.quats, "opacity": m.opacity_logits,
            "sh": m.sh, "degree": m.sh_degree}


def checkpoint_input(root: Path, rng) -> Path:
    run = RunFolder(root)
    arrays = {"param/means": rng.normal(size=(6, 3)).astype(np.float32),
              "m/means": rng.normal(size=(6, 3)).astype(np.float32),
              "window/count": rng.integers(0, 5, 6).astype(np.float32)}
    run.write_checkpoint(arrays, {"iteration": 40, "config": TrainConfig(scene="builtin").to_json(),
                                  "camera_stack": [3, 1, 2], "gaussians": 6})
    return run.checkpoint_path


def read_checkpoint(path: Path):
    checkpoint = RunFolder(path.parent).read_checkpoint()
    return {"arrays": checkpoint.arrays, "meta": checkpoint.meta}


def config_input(root: Path, rng) -> Path:
    run = RunFolder(root)
    cfg = TrainConfig(scene=str(root / "scène"), iterations=700, strategy="absgs", save_at=(100, 200))
    write_json(run.config_path, cfg.to_json())
    return run.config_path


# ------------------------------------------------------------------------------------------------ mutations

def truncate(data: bytes, rng, path) -> bytes:
    return data[: int(rng.integers(0, len(data)))]


def truncate_off_records(width: int):
    """Truncation inside a record: a format without a count (.splat) cut at a record boundary is a smaller valid
    file, which no reader can tell from the real thing."""
    def mutate(data: bytes, rng, path) -> bytes:
        cut = int(rng.integers(0, len(data)))
        return data[:cut + 1 if cut % width == 0 else cut]
    return mutate


def flip(data: bytes, rng, path) -> bytes:
    out = bytearray(data)
    for at in rng.integers(0, len(data), int(rng.integers(1, 5))):
        out[at] ^= int(rng.integers(1, 256))
    return bytes(out)


def empty(data: bytes, rng, path) -> bytes:
    return b""


NON_FINITE = [float("nan"), float("inf"), -float("inf")]


def binary_non_finite(width: int, start: Callable[[bytes], int]):
    """Write NaN or +-Inf (float32 or float64) at an aligned offset after `start(data)`."""
    def mutate(data: bytes, rng, path) -> bytes:
        first = start(data)
        slots = (len(data) - first) // width
        at = first + width * int(rng.integers(0, slots))
        value = np.array([rng.choice(NON_FINITE)], "<f4" if width == 4 else "<f8").tobytes()
        return data[:at] + value + data[at + width:]
    return mutate


def ply_body(data: bytes) -> int:
    return data.index(b"end_header\n") + len(b"end_header\n")


def ply_huge_count(data: bytes, rng, path) -> bytes:
    return re.sub(rb"element vertex \d+", b"element vertex %d" % int(rng.choice([2**31, 2**40, 10**15])), data)


def bin_huge_count(data: bytes, rng, path) -> bytes:
    """The record count at the start of a COLMAP binary file, or (images.bin) an image's point count."""
    value = np.array([rng.choice([2**32, 2**40, 2**63 - 1])], "<u8").tobytes()
    if path.name == "images.bin" and rng.random() < 0.5:
        at = data.index(b"\0", 8 + 64) + 1          # the first image's number of 2D points
        return data[:at] + value + data[at + 8:]
    return value + data[8:]


NUMBER = re.compile(rb"(?<![\w.])-?\d+(\.\d+)?(e[-+]?\d+)?(?![\w.])")


def text_non_finite(data: bytes, rng, path) -> bytes:
    """A number token (not in a # comment) replaced by nan, inf, -inf or 1e999."""
    body = data.index(b"\n", data.rfind(b"\n#")) + 1 if b"\n#" in data or data.startswith(b"#") else 0
    spans = [m.span() for m in NUMBER.finditer(data, body)]
    a, b = spans[int(rng.integers(len(spans)))]
    return data[:a] + rng.choice([b"nan", b"inf", b"-inf", b"1e999"]) + data[b:]


def text_huge_count(data: bytes, rng, path) -> bytes:
    return re.sub(rb"(# Number of \w+: )\d+", lambda m: m.group(1) + b"%d" % (10**12), data, count=1)


def json_paths(value, prefix=()):
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from json_paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from json_paths(v, prefix + (i,))


def json_get(doc, where):
    for k in where:
        doc = doc[k]
    return doc


def json_replace(doc, where, value):
    if not where:
        return value
    parent = doc
    for k in where[:-1]:
        parent = parent[k]
    parent[where[-1]] = value
    return doc


def json_type(value) -> str:
    """The JSON type of a value: an int and a float are both numbers."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "bool"
    return "number" if isinstance(value, (int, float)) else type(value).__name__


def json_wrong_type(data: bytes, rng, path) -> bytes:
    doc = json.loads(data)
    paths = [where for where in json_paths(doc) if json_get(doc, where) is not None]   # null often means
    where = paths[int(rng.integers(len(paths)))]                                     # "unset": any type fits
    current = json_get(doc, where)
    others = [v for v in ("text", [], {}, None, True, 7, 2.5, [1, 2]) if json_type(v) != json_type(current)]
    return json.dumps(json_replace(doc, where, others[int(rng.integers(len(others)))])).encode()


def json_non_finite(data: bytes, rng, path) -> bytes:
    doc = json.loads(data)
    numbers = [where for where in json_paths(doc) if json_type(json_get(doc, where)) == "number"]
    return json.dumps(json_replace(doc, numbers[int(rng.integers(len(numbers)))], rng.choice(NON_FINITE))).encode()


def image_wrong_size(data: bytes, rng, path) -> bytes:
    """The same image format at another size (the camera still says W x H)."""
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    inp.close()
    w, h = (W + int(rng.integers(1, 9)), H) if rng.random() < 0.5 else (W, H - int(rng.integers(1, 9)))
    tmp = path.with_name("resized" + path.suffix)
    dtype = {"uint8": "uint8", "uint16": "uint16", "half": "half"}[str(spec.format)]
    y = np.linspace(0, 1, h * w * spec.nchannels, dtype=np.float32).reshape(h, w, spec.nchannels)
    write_image(tmp, y, dtype)
    out = tmp.read_bytes()
    tmp.unlink()
    return out


def png_bomb(data: bytes, rng, path) -> bytes:
    """The PNG header claiming a size at or near the pixel cap (16384 x 16384: a small file that decodes to 2^28
    pixels), its CRC made to match: refused from the header (the size, or the memory its decoding needs)."""
    import struct
    import zlib
    side = int(rng.choice([1 << 14, (1 << 14) - 1, 1 << 15]))
    out = bytearray(data)
    out[16:24] = struct.pack(">II", side, side)
    out[29:33] = struct.pack(">I", zlib.crc32(bytes(out[12:29])))
    return bytes(out)


def spz_bomb(data: bytes, rng, path) -> bytes:
    """A .spz whose gzip stream carries 64 MiB past the Gaussians its header promises (a file of 2 MB inflated to
    2 GiB took 4.3 GB), or a second gzip member after it."""
    import gzip
    if rng.random() < 0.5:
        return data + gzip.compress(b"more", mtime=0)
    return gzip.compress(gzip.decompress(data) + bytes(1 << 26), compresslevel=1, mtime=0)


def spz_huge_count(data: bytes, rng, path) -> bytes:
    """A .spz header promising 20 million Gaussians or more (one with 20 million zeros took 7.7 GB)."""
    import gzip
    inner = bytearray(gzip.decompress(data))
    inner[8:12] = int(rng.choice([20_000_001, 2**31, 2**32 - 1])).to_bytes(4, "little")
    return gzip.compress(bytes(inner), compresslevel=1, mtime=0)


def spz_fractional_bits(data: bytes, rng, path) -> bytes:
    """Fractional bits no writer uses (255 put every Gaussian at the origin, unsaid)."""
    import gzip
    inner = bytearray(gzip.decompress(data))
    inner[13] = int(rng.integers(24, 256))
    return gzip.compress(bytes(inner), compresslevel=1, mtime=0)


def element_huge_count(data: bytes, rng, path) -> bytes:
    """One element of a PLY header (a compressed PLY's chunk, vertex or sh) promising far more rows than the file
    holds (10^12 chunks ended in MemoryError, 20 digits in OverflowError)."""
    names = re.findall(rb"element (\w+) \d+", data[:data.index(b"end_header")])
    name = names[int(rng.integers(len(names)))]
    count = int(rng.choice([2**32, 10**12, 10**20]))
    return re.sub(rb"element %s \d+" % name, b"element %s %d" % (name, count), data, count=1)


# the mutations a reader must refuse within READ_MEMORY_BOUND bytes of Python memory (tracemalloc: NumPy's arrays
# and zlib's output count), whatever they promise
BOUNDED = {"bomb", "huge count"}
READ_MEMORY_BOUND = 64 * 2**20
EXPORT_BOMBS = {"spz": {"bomb": spz_bomb, "huge count": spz_huge_count, "fractional bits": spz_fractional_bits},
                "compressed-ply": {"huge count": element_huge_count}}


def json_hostile_name(data: bytes, rng, path) -> bytes:
    """A frame's image named by an absolute path or through ".." (the same image, reached another way): read,
    its outputs must still be named inside the run folder (Camera.file_stem, checked by read_scene)."""
    doc = json.loads(data)
    frame = doc["frames"][int(rng.integers(len(doc["frames"])))]
    image = (path.parent / frame["file_path"]).resolve()
    frame["file_path"] = str(image) if rng.random() < 0.5 else f"images/../images/{image.name}"
    return json.dumps(doc).encode()


def json_duplicate_frame(data: bytes, rng, path) -> bytes:
    """A frame listed twice: refused naming the image (one view's outputs would overwrite the other's)."""
    doc = json.loads(data)
    doc["frames"].append(dict(doc["frames"][int(rng.integers(len(doc["frames"])))]))
    return json.dumps(doc).encode()


def exr_nan_pixels(data: bytes, rng, path) -> bytes:
    tmp = path.with_name("nan.exr")
    pixels = image_pixels(rng, 4 if "rgba" in path.parent.parent.name else 3)
    pixels[int(rng.integers(H)), int(rng.integers(W)), int(rng.integers(3))] = rng.choice(NON_FINITE)
    write_image(tmp, pixels, "half")
    out = tmp.read_bytes()
    tmp.unlink()
    return out


# Mutations that must never be read silently (truncation and emptiness are always detectable: each format
# either states its length or ends in a recognisable way), and those that may change values undetectably.
MUST_FAIL = {"truncate", "empty", "huge count", "wrong size", "non-finite pixels", "bomb", "duplicate frame",
             "fractional bits", "folding lens"}


@dataclass
class Format:
    name: str
    build: Callable[[Path, np.random.Generator], Path]   # writes a valid input under a folder,
                                                         # returns the file to mutate
    read: Callable[[Path], object]                        # reads it (given that file) as the commands do
    mutations: dict[str, Callable]
    checksum: bool = False                                # a changed read is a finding too
    cli: Callable[[Path, Path], list[str]] | None = field(default=None)   # (file, out) -> command line


def scene_root(path: Path) -> Path:
    """The scene folder holding a mutated file (images/x, sparse/0/x or transforms.json)."""
    for parent in path.parents:
        if parent.name == FOLDER:
            return parent
    raise AssertionError(path)


def read_from_scene(path: Path):
    return read_scene(scene_root(path))


def train_cli(path: Path, out: Path) -> list[str]:
    return ["train", "--scene", str(scene_root(path)), "--iterations", "1", "--test-every", "0", "--no-progress",
            "--out", str(out)]


BASIC = {"truncate": truncate, "flip": flip, "empty": empty}
IMAGE = {**BASIC, "wrong size": image_wrong_size}
JSON = {**BASIC, "wrong type": json_wrong_type, "non-finite": json_non_finite}
SCENE_JSON = {**JSON, "hostile name": json_hostile_name, "duplicate frame": json_duplicate_frame}


def _formats() -> list[Format]:
    images = [
        Format(f"image {label}", lambda root, rng, e=ext, d=dtype, c=ch: nerf_scene(root, rng, e, d, c, "image"),
               read_from_scene, dict(IMAGE, **extra), cli=train_cli)
        for label, ext, dtype, ch, extra in (
            ("png", ".png", "uint8", 3, {"bomb": png_bomb}), ("png rgba", ".png", "uint8", 4, {"bomb": png_bomb}),
            ("png 16-bit", ".png", "uint16", 3, {"bomb": png_bomb}),
            ("jpeg", ".jpg", "uint8", 3, {}), ("exr", ".exr", "half", 3, {"non-finite pixels": exr_nan_pixels}),
            ("exr rgba", ".exr", "half", 4, {"non-finite pixels": exr_nan_pixels}))]
    colmap = [
        Format(f"colmap {kind} {stem}", lambda root, rng, k=kind, s=stem: colmap_scene(root, rng, k) / f"{s}.{k}",
               read_from_scene,
               {**BASIC, "huge count": bin_huge_count, "non-finite": binary_non_finite(8, lambda d: 8)} if kind == "bin"
               else {**BASIC, "huge count": text_huge_count, "non-finite": text_non_finite,
                     **({"folding lens": text_folding_lens} if stem == "cameras" else {})}, cli=train_cli)
        for kind in ("bin", "txt") for stem in ("cameras", "images", "points3D")]
    return images + colmap + [
        Format("ply", ply_input, read_ply_values,
               {**BASIC, "huge count": ply_huge_count, "non-finite": binary_non_finite(4, ply_body)},
               cli=lambda path, out: ["render", "--ply", str(path), "--scene", "builtin", "-r", "8",
                                      "--out", str(out)]),
        *(Format(f"export {fmt}", export_input(fmt), lambda path: read_ply_values(path, read_model_file),
                 {**BASIC, **({"truncate": truncate_off_records(SPLAT_RECORD.itemsize),
                               "non-finite": binary_non_finite(4, lambda data: 0)} if fmt == "splat" else {}),
                  **EXPORT_BOMBS.get(fmt, {})},
                 cli=lambda path, out: ["render", "--ply", str(path), "--scene", "builtin", "-r", "8",
                                        "--out", str(out)])
          for fmt in ("splat", "spz", "compressed-ply")),
        Format("transforms.json (instant-ngp)", lambda root, rng: nerf_scene(root, rng), read_from_scene, SCENE_JSON,
               cli=train_cli),
        Format("transforms_train.json (Blender)", lambda root, rng: nerf_scene(root, rng, style="blender"),
               read_from_scene, SCENE_JSON, cli=train_cli),
        Format("photos (sfm)", photo_folder, read_photo_folder, IMAGE, cli=sfm_cli),
        *([Format("video (sfm)", video_input, read_video, BASIC, cli=sfm_cli)] if importlib.util.find_spec("av")
          else []),
        Format("checkpoint", checkpoint_input, read_checkpoint, BASIC, checksum=True),
        Format("config.json", config_input, lambda path: RunFolder(path.parent).read_config().to_json(), JSON,
               cli=lambda path, out: ["eval", "--model", str(path.parent)]),
    ]


FORMATS = {f.name: f for f in _formats()}


# ------------------------------------------------------------------------------------------------ checking

def same(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.shape(a) == np.shape(b) and np.array_equal(a, b, equal_nan=True)
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def non_finite(value) -> bool:
    if isinstance(value, dict):
        return any(non_finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(non_finite(v) for v in value)
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        return not np.isfinite(value).all()
    return isinstance(value, float) and not math.isfinite(value)


@dataclass
class Case:
    format: str
    mutation: str
    seed: int
    outcome: str = ""
    finding: str = ""     # empty: the case ended an allowed way
    message: str = ""


def run_case(fmt: Format, mutation: str, seed: int, template: Path, target: Path, baseline, work: Path) -> Case:
    case = Case(fmt.name, mutation, seed)
    rng = np.random.default_rng(seed)
    folder = work / f"case-{seed}" / FOLDER
    shutil.copytree(template, folder)
    path = folder / target.relative_to(template)
    path.write_bytes(fmt.mutations[mutation](path.read_bytes(), rng, path))
    quiet = io.StringIO()
    bounded = mutation in BOUNDED
    if bounded:
        tracemalloc.start()
    try:
        with contextlib.redirect_stderr(quiet):
            value = fmt.read(path)
    except InputError as e:
        case.outcome, case.message = "error", str(e)
        named = str(path) in case.message or (fmt.name.startswith("colmap") and str(path.parent) in case.message)
        if "\n" in case.message:
            case.finding = "the error takes several lines"
        elif not named:
            case.finding = "the error does not name the file"
    except Exception as e:   # anything but InputError reaches the user as a traceback
        case.outcome, case.message = "exception", f"{e.__class__.__name__}: {e}"
        case.finding = "not an InputError (the user would see a traceback)"
    else:
        case.outcome = "same" if same(value, baseline) else "changed"
        if non_finite(value):
            case.finding = "a non-finite value was read"
        elif case.outcome == "changed" and (mutation in MUST_FAIL or fmt.checksum or mutation == "wrong type"):
            case.finding = f"{mutation} read without error"
    finally:
        if bounded:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            if peak > READ_MEMORY_BOUND and not case.finding:
                case.finding = f"the read took {peak / 2**20:.0f} MB (at most {READ_MEMORY_BOUND / 2**20:.0f})"
    shutil.rmtree(folder.parent)
    return case


def run_cli_case(fmt: Format, case: Case, template: Path, target: Path, work: Path) -> str:
    """Run one error case through the command line: '' when it exits 2 with one line and writes nothing."""
    from dc4gs_cl.cli import main
    rng = np.random.default_rng(case.seed)
    folder = work / "cli" / FOLDER
    shutil.copytree(template, folder)
    path = folder / target.relative_to(template)
    path.write_bytes(fmt.mutations[case.mutation](path.read_bytes(), rng, path))
    out = work / "cli" / "out folder"
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(fmt.cli(path, out))
    lines = err.getvalue().strip().splitlines()
    shutil.rmtree(work / "cli")
    if code != 2 or len(lines) != 1 or "Traceback" in err.getvalue():
        return f"exit {code}, stderr: {err.getvalue()!r}"
    if out.exists():
        return f"exit 2 but {out} was written"
    return ""


def fuzz(cases: int, seed: int, formats: list[str] | None = None, cli: bool = False,
         log: Callable[[str], None] = print) -> list[Case]:
    """Run `cases` cases per format (mutations in turn), seeds seed, seed + 1, ...; returns every case."""
    results = []
    with tempfile.TemporaryDirectory(prefix="dc4gs-fuzz-") as tmp:
        work = Path(tmp)
        for fmt in (FORMATS[name] for name in (formats or FORMATS)):
            template = work / "template" / FOLDER
            target = fmt.build(template, np.random.default_rng(seed))
            baseline = fmt.read(target)
            names = list(fmt.mutations)
            checked_cli = not (cli and fmt.cli)
            for i in range(cases):
                case = run_case(fmt, names[i % len(names)], seed + i, template, target, baseline, work)
                if not checked_cli and case.outcome == "error" and not case.finding:
                    case.finding, checked_cli = run_cli_case(fmt, case, template, target, work), True
                results.append(case)
                if case.finding:
                    log(f"FINDING {case.format} / {case.mutation} (seed {case.seed}): {case.finding}: {case.message}")
            shutil.rmtree(work / "template")
    return results


def summary(results: list[Case]) -> str:
    rows = {}
    for c in results:
        row = rows.setdefault(c.format, {"cases": 0, "same": 0, "error": 0, "changed": 0, "findings": 0})
        row["cases"] += 1
        if c.outcome in ("same", "error", "changed"):
            row[c.outcome] += 1
        row["findings"] += bool(c.finding)
    lines = ["| format | cases | same | error | changed | findings |", "|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {name} | {r['cases']} | {r['same']} | {r['error']} | {r['changed']} | {r['findings']} |"
              for name, r in rows.items()]
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=200, help="cases per format (default 200)")
    p.add_argument("--seed", type=int, default=None, help="first seed (default: a fresh one, printed)")
    p.add_argument("--format", action="append", choices=list(FORMATS), help="only these formats (repeatable)")
    p.add_argument("--cli", action="store_true", help="also run each format's first error case through the CLI")
    args = p.parse_args()
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**31)
    print(f"seed {seed}, {args.cases} cases per format")
    results = fuzz(args.cases, seed, args.format, args.cli)
    print(summary(results))
    findings = [c for c in results if c.finding]
    print(f"{len(results)} cases, {len(findings)} findings")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
