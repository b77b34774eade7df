"""Scene loading: real COLMAP / NeRF scenes, undistortion, NeRF conversion, and bad input."""
from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pycolmap
import pytest

from dc4gs_cl import constants as K
from dc4gs_cl.errors import InputError
from dc4gs_cl.scene.distortion import FISHEYE
from conftest import DATA_DIR
from dc4gs_cl.scene.loader import load_scene



# ---------------------------------------------------------------------------------------------- helpers

def write_image(path: Path, pixels: np.ndarray) -> Path:
    """Write (H, W, C) float in [0, 1] as 8-bit; the format follows the extension."""
    path.parent.mkdir(parents=True, exist_ok=True)
    data = (np.clip(pixels, 0, 1) * 255 + 0.5).astype(np.uint8)
    if data.ndim == 2:
        data = data[..., None]
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.UINT8))
    assert out.write_image(data)
    out.close()
    return path


def write_colmap(root: Path, camera: str = "PINHOLE 64 48 50 50 32 24",
                 images: tuple = (("a.png", (1, 0, 0, 0), (0, 0, 0)),),
                 points: tuple = ((0, 0, 5),), size: tuple[int, int] | None = (64, 48)) -> Path:
    """A COLMAP text model in root/sparse/0 with one camera; images of `size` (None: none written)."""
    model = root / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text(f"1 {camera}\n")
    (model / "images.txt").write_text("".join(
        f"{i + 1} {' '.join(map(str, q))} {' '.join(map(str, t))} 1 {name}\n\n"
        for i, (name, q, t) in enumerate(images)))
    (model / "points3D.txt").write_text("".join(
        f"{i + 1} {x} {y} {z} 128 128 128 0\n" for i, (x, y, z) in enumerate(points)))
    if size is not None:
        for name, _, _ in images:
            write_image(root / "images" / name, np.full((size[1], size[0], 3), 0.5))
    return root


def files_under(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*")}


def rotation(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def gl_c2w(R: np.ndarray, t: np.ndarray) -> list:
    """NeRF transform_matrix (camera-to-world, OpenGL axes) of the OpenCV world-to-camera (R, t)."""
    c2w = np.eye(4)
    c2w[:3, :3] = R.T @ np.diag([1.0, -1.0, -1.0])
    c2w[:3, 3] = -R.T @ t
    return c2w.tolist()


# ---------------------------------------------------------------------------------------------- real scenes

@pytest.fixture(scope="module")
def data() -> Path:
    if not DATA_DIR.is_dir():
        pytest.skip(f"real test scenes not available: {DATA_DIR} not found")
    return DATA_DIR


# scene -> (path under the data folder, train count, test count); test = every 8th image by name
SCENES = {
    "beer": ("beer", 62, 9),
    "fountain_p11": ("fountain_p11", 9, 2),
    "sceaux_castle": ("sceaux_castle", 9, 2),
    "temple_sparse_ring": ("temple_sparse_ring", 14, 2),
    "fox_colmap": ("fox", 43, 7),
    "fox_nerf": ("fox/transforms.json", 43, 7),
    "lego_subset": ("lego_subset", 25, 5),
}
# Intrinsics from the READMEs: (width, height, fx, fy, cx, cy) of the PINHOLE camera at full size.
PINHOLE_INTRINSICS = {
    "fountain_p11": (768, 512, 689.87, 691.04, 380.2975, 251.8275),
    "sceaux_castle": (1471, 1085, 1484.760, 1484.760, 735.5, 542.5),
    "temple_sparse_ring": (640, 480, 1520.4, 1525.9, 302.82, 247.37),
    "lego_subset": (400, 400, 555.56, 555.56, 200.0, 200.0),
}


@pytest.mark.parametrize("scene", SCENES)
def test_real_scene_loads_and_reads(data, scene, tmp_path):
    rel, n_train, n_test = SCENES[scene]
    s = load_scene(data / rel, cache_dir=tmp_path)
    assert (len(s.train), len(s.test)) == (n_train, n_test)
    assert s.extent > 0
    if scene in PINHOLE_INTRINSICS:
        w, h, fx, fy, cx, cy = PINHOLE_INTRINSICS[scene]
        for c in s.train + s.test:
            assert (c.width, c.height) == (w, h) == c.source_size
            assert np.allclose([c.fx, c.fy, c.cx, c.cy], [fx, fy, cx, cy], atol=0.01)
    if s.points is not None:
        assert s.points.dtype == np.float64 and s.points.shape[1] == 3
        assert s.colors.dtype == np.float32 and s.colors.shape == s.points.shape
        assert 0 <= s.colors.min() and s.colors.max() <= 1 and s.colors.max() > 0.5

    r = 8 if scene.startswith("fox") else 4
    small = load_scene(data / rel, resolution=r, cache_dir=tmp_path)
    cam = small.train[0]
    full = s.train[0]
    assert (cam.width, cam.height) == (round(full.width / r), round(full.height / r))
    assert cam.fx == pytest.approx(full.fx * cam.width / full.width)
    img = small.read_image(cam)
    assert img.shape == (cam.height, cam.width, 3) and img.dtype == np.float32
    assert 0 <= img.min() and img.max() <= 1 and img.std() > 0.02


@pytest.mark.parametrize("scene", ["beer", "fox_colmap"])
def test_distorted_colmap_scenes_are_undistorted(data, scene, tmp_path):
    """--undistort: SIMPLE_RADIAL (beer) and OPENCV (fox) become PINHOLE cameras of the undistorted size, same
    focal; without it they keep their lens model and the photo's whole size."""
    rec = pycolmap.Reconstruction(str(data / SCENES[scene][0] / "sparse" / "0"))
    direct = load_scene(data / SCENES[scene][0], cache_dir=tmp_path)
    for c in direct.train[:5]:
        src = rec.cameras[rec.find_image_with_name(c.name).camera_id]
        assert c.distortion.model == src.model.name and c.source_size == (src.width, src.height)
        assert c.fx == pytest.approx(src.focal_length_x * c.width / src.width)
    s = load_scene(data / SCENES[scene][0], cache_dir=tmp_path, undistort=True)
    for c in s.train[:5]:
        src = rec.cameras[rec.find_image_with_name(c.name).camera_id]
        assert src.model.name in ("SIMPLE_RADIAL", "OPENCV")
        assert c.fx == pytest.approx(src.focal_length_x) and c.fy == pytest.approx(src.focal_length_y)
        assert c.source_size == (c.width, c.height) != (src.width, src.height)
        assert abs(c.width - src.width) < 0.05 * src.width and abs(c.cx - c.width / 2) < 0.05 * c.width
        assert c.image_path == data / SCENES[scene][0] / "images" / c.name
    if scene == "fox_colmap":
        assert (s.train[0].width, s.train[0].height) == (1067, 1897)
        assert s.train[0].fx == pytest.approx(1375.52) and s.train[0].fy == pytest.approx(1374.49)


@pytest.mark.parametrize("scene", ["fountain_p11", "sceaux_castle", "temple_sparse_ring", "beer", "fox_colmap"])
def test_sfm_points_project_into_their_images(data, scene):
    """World-to-camera convention: each image's observed points land in front of it, inside the frame;
    for PINHOLE scenes they reproject onto the observed keypoints."""
    root = data / SCENES[scene][0]
    rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    s = load_scene(root)
    for c in (s.train + s.test)[::4]:
        obs = [(p.xy, rec.points3D[p.point3D_id].xyz) for p in rec.find_image_with_name(c.name).points2D
               if p.has_point3D()]
        xy = np.array([o[0] for o in obs])
        X = np.array([o[1] for o in obs]) @ c.R.T + c.t
        assert (X[:, 2] > 0).all()
        uv = np.stack([c.fx * X[:, 0] / X[:, 2] + c.cx, c.fy * X[:, 1] / X[:, 2] + c.cy], axis=1)
        inside = (uv >= 0).all(axis=1) & (uv[:, 0] <= c.width) & (uv[:, 1] <= c.height)
        assert inside.mean() > 0.95
        if scene in PINHOLE_INTRINSICS:
            assert np.median(np.linalg.norm(uv - xy, axis=1)) < 1.0


def test_fox_colmap_and_nerf_agree(data):
    colmap_scene = load_scene(data / "fox")
    nerf_scene = load_scene(data / "fox" / "transforms.json")
    assert nerf_scene.points is None and nerf_scene.colors is None
    by_name = {c.name: c for c in colmap_scene.train + colmap_scene.test}
    nerf_cams = nerf_scene.train + nerf_scene.test
    assert len(nerf_cams) == len(by_name) == 50
    for n in nerf_cams:
        c = by_name[Path(n.name).name]
        assert np.allclose(n.center, c.center, atol=1e-5) and np.allclose(n.R, c.R, atol=1e-6)
        assert (n.width, n.height, n.source_size) == (c.width, c.height, c.source_size)
        assert np.allclose([n.fx, n.fy, n.cx, n.cy], [c.fx, c.fy, c.cx, c.cy])
    # Same sort order and split rule: the same images are held out.
    assert [Path(n.name).name for n in nerf_scene.test] == [c.name for c in colmap_scene.test]


def test_lego_blender_split_and_background(data):
    s = load_scene(data / "lego_subset", resolution=4)
    assert [c.name for c in s.test] == ["./test/r_2", "./test/r_22", "./test/r_42", "./test/r_62", "./test/r_82"]
    assert s.train[0].image_path == data / "lego_subset" / "train" / "r_0.png"
    for c in s.train:  # Blender cameras on a sphere look at the origin
        assert c.R[2] @ (-c.center / np.linalg.norm(c.center)) > 0.95
    cam = s.train[0]
    assert np.allclose(s.background, 0) and np.allclose(s.read_image(cam)[0, 0], 0)
    white = load_scene(data / "lego_subset", resolution=4, white_background=True)
    assert np.allclose(white.background, 1) and np.allclose(white.read_image(cam)[0, 0], 1)


# ---------------------------------------------------------------------------------------------- undistortion

# OPENCV camera with strong distortion: fx, fy, cx, cy, k1, k2, p1, p2
DISTORTED = (160, 120, [110.0, 105.0, 81.0, 59.0, -0.25, 0.06, 0.002, -0.003])


def blob_scene(root: Path, fmt: str) -> np.ndarray:
    """A distorted camera at the origin (world = camera axes) seeing a grid of 3D points drawn as small
    Gaussian blobs at their distorted pixels. Returns the points."""
    w, h, params = DISTORTED
    cam = pycolmap.Camera.create_from_model_name(1, "OPENCV", params[0], w, h)
    cam.params = params
    pts = np.array([[x, y, 1.0] for x in (-0.55, 0.0, 0.55) for y in (-0.4, 0.0, 0.4)])
    d = cam.img_from_cam(pts)
    ii, jj = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)  # pixel centres
    img = sum(np.exp(-((ii - u) ** 2 + (jj - v) ** 2) / (2 * 1.5 ** 2)) for u, v in d)
    write_image(root / "images" / "a.png", np.repeat(img[..., None], 3, axis=2))
    if fmt == "colmap":
        write_colmap(root, f"OPENCV {w} {h} {' '.join(map(str, params))}", size=None)
    else:
        fx, fy, cx, cy, k1, k2, p1, p2 = params
        (root / "transforms.json").write_text(json.dumps({
            "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": w, "h": h, "k1": k1, "k2": k2, "p1": p1, "p2": p2,
            "frames": [{"file_path": "images/a.png", "transform_matrix": gl_c2w(np.eye(3), np.zeros(3))}]}))
    return pts


@pytest.mark.parametrize("fmt", ["colmap", "nerf"])
def test_undistorted_points_land_on_pinhole_projection(tmp_path, fmt):
    root, cache = tmp_path / "scene", tmp_path / "cache"
    pts = blob_scene(root, fmt)
    s = load_scene(root, resolution=1, cache_dir=cache, test_every=0, undistort=True)
    cam = s.train[0]
    img = s.read_image(cam)[..., 0]
    assert img.shape == (cam.height, cam.width)
    ii, jj = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    w, h, params = DISTORTED
    for X in pts:
        u, v = cam.fx * X[0] / X[2] + cam.cx, cam.fy * X[1] / X[2] + cam.cy
        near = (ii - u) ** 2 + (jj - v) ** 2 < 5 ** 2
        centroid = np.array([(ii * img)[near].sum(), (jj * img)[near].sum()]) / img[near].sum()
        assert np.linalg.norm(centroid - [u, v]) < 0.5
    # Not a trivial pass: the corner points moved by several pixels.
    dist = pycolmap.Camera.create_from_model_name(1, "OPENCV", params[0], w, h)
    dist.params = params
    corner = pts[0]
    pinhole = [cam.fx * corner[0] + cam.cx, cam.fy * corner[1] + cam.cy]
    assert np.linalg.norm(dist.img_from_cam(corner[None])[0] - pinhole) > 3


@pytest.mark.parametrize("fmt", ["colmap", "nerf"])
def test_distorted_cameras_keep_their_lens_model_and_whole_photo(tmp_path, fmt):
    """Read directly, the camera keeps the OPENCV model: the points project (the kernels' float64 reference) onto the
    blobs' centres in the photo as it is, at every -r."""
    from dc4gs_cl.reference.project import project_reference
    root = tmp_path / "scene"
    pts = blob_scene(root, fmt)
    w, h, _ = DISTORTED
    for r in (1, 2):
        s = load_scene(root, resolution=r, cache_dir=tmp_path / "cache", test_every=0)
        cam = s.train[0]
        assert cam.distortion.model == "OPENCV" and (cam.width, cam.height) == (w // r, h // r)
        assert not (tmp_path / "cache").exists()   # nothing undistorted
        img = s.read_image(cam)[..., 0]
        n = len(pts)
        proj = project_reference(pts, np.full((n, 3), -5.0), np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros(n),
                                 np.zeros((n, 1, 3)), cam, 0, *K.tile_grid(cam.width, cam.height))
        ii, jj = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
        for u, v in proj["mean2d"]:
            near = (ii - u) ** 2 + (jj - v) ** 2 < (5 / r) ** 2
            centroid = np.array([(ii * img)[near].sum(), (jj * img)[near].sum()]) / img[near].sum()
            assert np.linalg.norm(centroid - [u, v]) < 0.5 / r


def test_unsupported_and_non_invertible_lens_models_are_refused(tmp_path):
    # FOV is not rendered directly: one line naming it and the models that are; --undistort takes it
    write_colmap(tmp_path / "fov", "FOV 64 48 50 50 32 24 0.3", size=(64, 48))
    err = raises_naming("cameras.txt", tmp_path / "fov")
    assert "camera model FOV is not rendered directly" in str(err) and "OPENCV_FISHEYE" in str(err)
    assert "\n" not in str(err)
    assert load_scene(tmp_path / "fov", undistort=True, test_every=0).train[0].distortion is None
    # k1 = -0.5 at f = 40 on 64x48: the radial map turns back (at 44 deg) before the image's corner (50 deg)
    write_colmap(tmp_path / "fold", "SIMPLE_RADIAL 64 48 40 32 24 -0.5", size=(64, 48))
    err = raises_naming("cameras.txt", tmp_path / "fold")
    assert "image 'a.png': the SIMPLE_RADIAL distortion (k1=-0.5)" in str(err) and "turns back" in str(err)


def test_undistortion_cache_reused_invalidated_and_outside_input(tmp_path, monkeypatch):
    root, cache = tmp_path / "scene", tmp_path / "cache"
    blob_scene(root, "colmap")
    before = files_under(root)
    first = load_scene(root, cache_dir=cache, test_every=0, undistort=True)
    img = first.read_image(first.train[0])
    cached = list(cache.iterdir())
    assert len(cached) == 1 and cached[0].suffix == ".png"
    assert first.read_image(first.train[0]) is img  # in-memory cache

    # A new scene reads the cached file instead of undistorting again.
    def no_undistort(*args):
        raise AssertionError("undistorted again instead of using the cache")
    with monkeypatch.context() as m:
        m.setattr(pycolmap, "undistort_image", no_undistort)
        again = load_scene(root, cache_dir=cache, test_every=0, undistort=True)
        assert np.array_equal(again.read_image(again.train[0]), img)

    # A changed source file gets a new cache entry.
    src = root / "images" / "a.png"
    os.utime(src, ns=(src.stat().st_atime_ns, src.stat().st_mtime_ns + 10**9))
    changed = load_scene(root, cache_dir=cache, test_every=0, undistort=True)
    changed.read_image(changed.train[0])
    assert len(list(cache.iterdir())) == 2
    assert not [p for p in cache.iterdir() if p.name.startswith(".")]   # no temporary file left

    # Without cache_dir the cache goes to a temporary folder; the input folder is never written.
    default = load_scene(root, test_every=0, undistort=True)
    default.read_image(default.train[0])
    after = files_under(root)
    assert set(after) == set(before) and after["images/a.png"] != before["images/a.png"]  # only the utime


def test_rgba_distorted_image_keeps_alpha(tmp_path):
    w, h, params = DISTORTED
    rgba = np.zeros((h, w, 4))
    rgba[..., 0] = 1.0
    rgba[h // 4:3 * h // 4, w // 4:3 * w // 4, 3] = 1.0  # opaque red centre, transparent border
    write_image(tmp_path / "s" / "images" / "a.png", rgba)
    write_colmap(tmp_path / "s", f"OPENCV {w} {h} {' '.join(map(str, params))}", size=None)
    for bg in (0.0, 1.0):
        s = load_scene(tmp_path / "s", cache_dir=tmp_path / "c", test_every=0, white_background=bool(bg),
                       undistort=True)
        c = s.train[0]
        img = s.read_image(c)
        assert np.allclose(img[c.height // 2, c.width // 2], [1, 0, 0], atol=0.01)
        assert np.allclose(img[2, 2], bg, atol=0.01)


# ---------------------------------------------------------------------------------------------- NeRF conversion

R_TRUE = rotation([0.3, -1.0, 0.5], 0.7)
C_TRUE = np.array([1.0, 2.0, -3.0])
T_TRUE = -R_TRUE @ C_TRUE


def nerf_scene(root: Path, meta: dict, frames: list[dict], name: str = "transforms.json",
               size=(8, 6), rgba: bool = False) -> Path:
    """transforms JSON with the given frames (each gets the known pose unless it has its own);
    an image is written for every file_path (.png where it has no extension)."""
    for f in frames:
        f.setdefault("transform_matrix", gl_c2w(R_TRUE, T_TRUE))
        p = root / f["file_path"]
        if not p.suffix:
            p = p.with_name(p.name + ".png")
        if not p.exists():
            px = np.zeros((size[1], size[0], 4 if rgba else 3))
            px[..., :3] = 0.5
            if rgba:
                px[:, : size[0] // 2, 3] = 1.0  # left half opaque grey, right half transparent
            write_image(p, px)
    (root / name).write_text(json.dumps({**meta, "frames": frames}))
    return root


def test_nerf_pose_and_camera_angle(tmp_path):
    angle = 0.9
    s = load_scene(nerf_scene(tmp_path, {"camera_angle_x": angle}, [{"file_path": "./a"}]), test_every=0)
    c = s.train[0]
    assert c.name == "./a" and c.image_path == tmp_path / "a.png"
    assert np.allclose(c.R, R_TRUE) and np.allclose(c.t, T_TRUE) and np.allclose(c.center, C_TRUE)
    fx = 0.5 * 8 / math.tan(0.5 * angle)
    assert (c.width, c.height) == (8, 6) == c.source_size
    assert np.allclose([c.fx, c.fy, c.cx, c.cy], [fx, fx, 4, 3])

    s = load_scene(nerf_scene(tmp_path / "y", {"camera_angle_x": angle, "camera_angle_y": 0.8},
                              [{"file_path": "a"}]), test_every=0)
    assert s.train[0].fy == pytest.approx(0.5 * 6 / math.tan(0.4))


def test_nerf_intrinsics_top_level_and_per_frame(tmp_path):
    meta = {"fl_x": 20.0, "fl_y": 21.0, "cx": 3.5, "cy": 2.5, "w": 8, "h": 6}
    frames = [{"file_path": "a.png"}, {"file_path": "b", "fl_x": 30.0, "cx": 4.5}]
    s = load_scene(nerf_scene(tmp_path, meta, frames), test_every=0)
    a, b = sorted(s.train, key=lambda c: c.name)
    assert np.allclose([a.fx, a.fy, a.cx, a.cy], [20, 21, 3.5, 2.5])
    assert np.allclose([b.fx, b.fy, b.cx, b.cy], [30, 21, 4.5, 2.5])
    assert b.image_path == tmp_path / "b.png"


def test_nerf_extension_order_and_jpg(tmp_path):
    write_image(tmp_path / "img" / "x.jpg", np.full((6, 8, 3), 0.25))
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 1.0, "frames": [
        {"file_path": "./img/x", "transform_matrix": gl_c2w(R_TRUE, T_TRUE)}]}))
    s = load_scene(tmp_path, test_every=0)
    assert s.train[0].image_path == tmp_path / "img" / "x.jpg"
    assert np.allclose(s.read_image(s.train[0]), 0.25, atol=0.02)
    write_image(tmp_path / "img" / "x.png", np.zeros((6, 8, 3)))  # .png comes first in the search order
    assert load_scene(tmp_path, test_every=0).train[0].image_path == tmp_path / "img" / "x.png"


def test_nerf_rgba_composited_on_background(tmp_path):
    nerf_scene(tmp_path, {"camera_angle_x": 1.0}, [{"file_path": "a"}], rgba=True)
    for white, bg in ((False, 0.0), (True, 1.0)):
        s = load_scene(tmp_path, test_every=0, white_background=white)
        img = s.read_image(s.train[0])
        assert np.allclose(img[:, :4], 0.5, atol=0.01) and np.allclose(img[:, 4:], bg)


def test_blender_split_files_and_instant_ngp_split(tmp_path):
    frames = lambda n, d: [{"file_path": f"./{d}/r_{i}"} for i in range(n)]
    blender = tmp_path / "blender"
    nerf_scene(blender, {"camera_angle_x": 1.0}, frames(3, "train"), "transforms_train.json")
    nerf_scene(blender, {"camera_angle_x": 1.0}, frames(2, "test"), "transforms_test.json")
    nerf_scene(blender, {"camera_angle_x": 1.0}, frames(4, "val"), "transforms_val.json")
    s = load_scene(blender)
    assert [c.name for c in s.train] == ["./train/r_0", "./train/r_1", "./train/r_2"]
    assert [c.name for c in s.test] == ["./test/r_0", "./test/r_1"]

    ngp = nerf_scene(tmp_path / "ngp", {"camera_angle_x": 1.0}, frames(10, "im")[::-1])
    s = load_scene(ngp, test_every=4)
    assert [c.name for c in s.test] == ["./im/r_0", "./im/r_4", "./im/r_8"]  # sorted by name, not file order
    assert len(s.train) == 7


def test_nerf_fisheye_and_full_opencv_are_undistorted(tmp_path):
    meta = {"fl_x": 6.0, "cx": 4, "cy": 3, "w": 8, "h": 6, "k1": 0.01, "k2": 0.0, "k3": 0.02, "k4": 0.0}
    a, b = nerf_scene(tmp_path / "a", meta, [{"file_path": "a"}]), nerf_scene(
        tmp_path / "b", {**meta, "is_fisheye": True}, [{"file_path": "a"}])
    full = load_scene(a, cache_dir=tmp_path / "c", test_every=0, undistort=True)
    fish = load_scene(b, cache_dir=tmp_path / "c", test_every=0, undistort=True)
    # rendered directly (the default), each keeps its model
    assert load_scene(a, test_every=0).train[0].distortion.model == "FULL_OPENCV"
    assert load_scene(b, test_every=0).train[0].distortion.kind == FISHEYE
    for s in (full, fish):
        c = s.train[0]
        assert c.source_size == (c.width, c.height) and s.read_image(c).shape == (c.height, c.width, 3)
    # an equidistant fisheye widens the pinhole image that keeps its field of view
    assert fish.train[0].width > full.train[0].width


# ---------------------------------------------------------------------------------------------- resolution

def test_resolution_default_and_divisor(tmp_path):
    write_colmap(tmp_path, "PINHOLE 2001 999 1000 1000 1000.5 499.5", size=(2001, 999))
    s = load_scene(tmp_path, test_every=0)
    c = s.train[0]
    assert (c.width, c.height) == (1600, 799) and c.source_size == (2001, 999)
    assert c.fx == pytest.approx(1000 * 1600 / 2001) and c.cy == pytest.approx(499.5 * 799 / 999)
    assert s.read_image(c).shape == (799, 1600, 3)
    for r, size in ((1, (2001, 999)), (2, (1000, 500)), (3, (667, 333)), (8, (250, 125))):
        c = load_scene(tmp_path, resolution=r, test_every=0).train[0]
        assert (c.width, c.height) == size


# ---------------------------------------------------------------------------------------------- bad input

def raises_naming(name, *args, **kwargs) -> InputError:
    with pytest.raises(InputError) as e:
        load_scene(*args, **kwargs)
    assert str(name) in str(e.value), str(e.value)
    return e.value


def test_missing_folder(tmp_path):
    raises_naming(tmp_path / "nope", tmp_path / "nope")


def test_neither_format(tmp_path):
    (tmp_path / "images").mkdir()
    err = raises_naming(tmp_path, tmp_path)
    assert "not a COLMAP or NeRF scene" in str(err)
    (tmp_path / "notes.txt").write_text("hello")
    raises_naming("notes.txt", tmp_path / "notes.txt")


def test_corrupt_image(tmp_path):
    write_colmap(tmp_path, images=(("bad.jpg", (1, 0, 0, 0), (0, 0, 0)),), size=None)
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "bad.jpg").write_bytes(b"\x00garbage, not a JPEG" * 10)
    raises_naming("bad.jpg", tmp_path)

    nerf = tmp_path / "nerf"
    nerf.mkdir()
    (nerf / "x.jpg").write_bytes(b"\x00garbage, not a JPEG" * 10)
    (nerf / "transforms.json").write_text(json.dumps({"camera_angle_x": 1.0, "frames": [
        {"file_path": "x.jpg", "transform_matrix": gl_c2w(R_TRUE, T_TRUE)}]}))
    raises_naming("x.jpg", nerf)


def test_colmap_image_missing_on_disk(tmp_path):
    write_colmap(tmp_path, images=(("a.png", (1, 0, 0, 0), (0, 0, 0)), ("b.png", (1, 0, 0, 0), (1, 0, 0))))
    (tmp_path / "images" / "b.png").unlink()
    raises_naming(Path("images") / "b.png", tmp_path)


def test_nerf_image_missing_on_disk(tmp_path):
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 1.0, "frames": [
        {"file_path": "./train/r_9", "transform_matrix": gl_c2w(R_TRUE, T_TRUE)}]}))
    raises_naming("r_9", tmp_path)


def test_camera_model_pycolmap_cannot_undistort(tmp_path):
    write_colmap(tmp_path, "EQUIRECTANGULAR 64 32 64 32", size=(64, 32))
    err = raises_naming("cameras.txt", tmp_path)
    assert "EQUIRECTANGULAR" in str(err)
    err = raises_naming("cameras.txt", tmp_path, undistort=True)
    assert "EQUIRECTANGULAR cannot be undistorted" in str(err)


def test_malformed_cameras_txt(tmp_path):
    write_colmap(tmp_path, "NO_SUCH_MODEL 64 48 50 32 24")
    raises_naming(Path("sparse") / "0", tmp_path)


def test_image_size_disagrees_with_camera(tmp_path):
    write_colmap(tmp_path, "PINHOLE 64 48 50 50 32 24", size=(32, 24))
    err = raises_naming("a.png", tmp_path)
    assert "32x24" in str(err) and "64x48" in str(err)

    meta = {"camera_angle_x": 1.0, "w": 10, "h": 6}
    err = raises_naming("a.png", nerf_scene(tmp_path / "n", meta, [{"file_path": "a"}]))
    assert "8x6" in str(err) and "10x6" in str(err)


def test_no_images(tmp_path):
    write_colmap(tmp_path, images=())
    raises_naming("images.txt", tmp_path)


def test_empty_point_cloud(tmp_path):
    write_colmap(tmp_path, points=())
    err = raises_naming("points3D.txt", tmp_path)
    assert "no 3D points" in str(err)


def test_resolution_makes_image_vanish(tmp_path):
    write_colmap(tmp_path, "PINHOLE 4 3 5 5 2 1.5", size=(4, 3))
    err = raises_naming("a.png", tmp_path, resolution=8)
    assert "-r 8 makes a 4x3 image vanish" in str(err)
    with pytest.raises(InputError):
        load_scene(tmp_path, resolution=0)


def test_malformed_transforms(tmp_path):
    (tmp_path / "transforms.json").write_text("{not json")
    raises_naming("transforms.json", tmp_path)
    nerf_scene(tmp_path, {}, [{"file_path": "a"}])  # no focal length
    raises_naming("transforms.json", tmp_path)
    nerf_scene(tmp_path, {"camera_angle_x": 1.0}, [{"file_path": "a", "transform_matrix": [[1, 0], [0, 1]]}])
    raises_naming("transforms.json", tmp_path)


def test_output_names_stay_inside_the_output_folder_and_clashes_are_refused(tmp_path, rt):
    """Views named by an absolute path or with ".." write their renders inside the folder given (their names made
    the evaluation write at the filesystem root); an image listed twice, or two names that would write one file,
    are refused naming both."""
    from dc4gs_cl.evaluation.evaluate import evaluate
    from dc4gs_cl.model import initial_model
    from dc4gs_cl.render import DeviceGaussians, Renderer
    from dc4gs_cl.scene.builtin import builtin_scene
    outside = tmp_path / "outside"
    names = [f"{outside}/secret.png", "../../up.png", "..png", "a/../b.png"]
    scene = builtin_scene(resolution=8)
    cams = [replace(c, name=n) for c, n in zip(scene.train, names)]
    assert len(cams) == len(names) and all("/" not in c.file_stem and c.file_stem.strip(".") for c in cams)
    gaussians = DeviceGaussians(rt, initial_model(scene.points, scene.colors, np.random.default_rng(0), 0))
    evaluate(rt, Renderer(rt), gaussians, scene, cams, 0, tmp_path / "out" / "renders")
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*.png"))
    assert len(written) == 2 * len(cams) and all(p.parts[0] == "out" for p in written), written
    assert not outside.exists()

    frames = [{"file_path": "a"}, {"file_path": "b"}, {"file_path": "a"}]
    with pytest.raises(InputError, match="'a' is listed twice") as e:   # named: the file listing the views
        load_scene(nerf_scene(tmp_path / "twice", {"camera_angle_x": 1.0}, frames), test_every=0)
    assert e.value.path == str(tmp_path / "twice" / "transforms.json")
    frames = [{"file_path": "x/y"}, {"file_path": "x_y"}]
    with pytest.raises(InputError, match="'x/y' and 'x_y' would write one output file"):
        load_scene(nerf_scene(tmp_path / "clash", {"camera_angle_x": 1.0}, frames), test_every=0)


def test_the_scene_line_states_mixed_view_sizes(tmp_path, capsys):
    """A scene whose views differ in size says so on train's scene line (it showed the first view's size alone,
    as if a 16x12 scene held a 1x1 view)."""
    from dc4gs_cl.cli import main
    root = tmp_path / "scene"
    root.mkdir()
    write_image(root / "odd.png", np.full((1, 1, 3), 0.5))      # a 1x1 view among 16x12 ones
    nerf_scene(root, {"camera_angle_x": 0.9}, [{"file_path": f"./v{i}"} for i in range(3)] + [{"file_path": "./odd"}],
               size=(16, 12))
    assert main(["train", "--scene", str(root), "--iterations", "1", "--test-every", "0",
                 "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    line = next(entry for entry in capsys.readouterr().err.splitlines() if entry.startswith("scene:"))
    assert "16x12 x 3, 1x1 x 1" in line, line
