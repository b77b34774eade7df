"""The built-in scene: deterministic, non-trivial images, and cameras, images and points that agree."""
from __future__ import annotations

import numpy as np
import pytest

from dc4gs_cl.errors import InputError
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.builtin import BUILTIN_SCENE, builtin_scene, cast_rays
from dc4gs_cl.scene.camera import Camera, split_train_test


@pytest.fixture(scope="module")
def scene():
    return builtin_scene()


def all_cameras(scene):
    return sorted(scene.train + scene.test, key=lambda c: c.name)


def test_deterministic(scene):
    again = builtin_scene()
    np.testing.assert_array_equal(again.points, scene.points)
    np.testing.assert_array_equal(again.colors, scene.colors)
    for a, b in zip(all_cameras(again)[:3], all_cameras(scene)[:3]):
        np.testing.assert_array_equal(again.image(a), scene.image(b))


def test_contents(scene):
    assert scene.root.name == BUILTIN_SCENE and len(scene.train) + len(scene.test) == 32
    assert scene.points.dtype == np.float64 and scene.points.shape[1] == 3
    assert scene.colors.dtype == np.float32 and scene.colors.shape == scene.points.shape
    assert 3000 <= len(scene.points) <= 6000
    assert np.isfinite(scene.points).all() and 0 <= scene.colors.min() and scene.colors.max() <= 1
    for cam in all_cameras(scene)[::5]:
        image = scene.image(cam)
        assert image.shape == (144, 192, 3) and image.dtype == np.float32
        assert np.isfinite(image).all() and 0 <= image.min() and image.max() <= 1
        assert image.std() > 0.1
        assert len(np.unique((image * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 500   # plain sky: ~900
        gradient = np.maximum(np.abs(np.diff(image, axis=0))[:, :-1], np.abs(np.diff(image, axis=1))[:-1]).max(axis=2)
        assert (gradient > 0.1).mean() > 0.05        # many edges (found: 14-22 % of the pixels)


def projection_errors(scene, mirror: bool = False):
    """Per camera: the fraction of points that project into the image in front of the camera, and the colour
    errors (max over channels) at the pixels of the points that camera sees (not occluded)."""
    inside, errors = [], []
    for cam in all_cameras(scene):
        x = scene.points @ cam.R.T + cam.t
        z = x[:, 2]
        front = z > 0
        z = np.where(front, z, 1.0)
        u, v = cam.fx * x[:, 0] / z + cam.cx, cam.fy * x[:, 1] / z + cam.cy
        if mirror:
            u = cam.width - u
        ok = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        inside.append(ok)
        # occlusion: cast a ray from the camera centre to the point itself (no intrinsics involved)
        offset = scene.points[ok] - cam.center
        dist = np.linalg.norm(offset, axis=1)
        _, hit = cast_rays(cam.center.astype(np.float32)[:, None], (offset / dist[:, None]).T.astype(np.float32))
        seen = np.abs(hit - dist) < 0.015 * scene.extent        # 5 sigma of the position noise
        pixels = scene.image(cam)[v[ok][seen].astype(int), u[ok][seen].astype(int)]  # pixel (i, j) spans [i, i+1)
        errors.append(np.abs(pixels - scene.colors[ok][seen]).max(axis=1))
    return np.array(inside), errors


def test_cameras_images_and_points_agree(scene):
    inside, errors = projection_errors(scene)
    assert inside.mean() > 0.7                        # most points in view of each camera
    assert inside.any(axis=0).mean() > 0.99           # every point (but a few outliers) seen somewhere
    assert sum(len(e) for e in errors) > 10 * len(scene.points)
    assert np.median(np.concatenate(errors)) < 0.06
    assert max(np.median(e) for e in errors) < 0.1
    # the check has power: a mirrored projection fails it
    _, mirrored = projection_errors(scene, mirror=True)
    assert np.median(np.concatenate(mirrored)) > 0.15


def test_resolution(scene):
    half = builtin_scene(resolution=2)
    for full_cam, half_cam in zip(all_cameras(scene)[:4], all_cameras(half)[:4]):
        assert (half_cam.width, half_cam.height) == (96, 72)
        assert half_cam.fx == pytest.approx(full_cam.fx / 2) and half_cam.cy == pytest.approx(full_cam.cy / 2)
        np.testing.assert_array_equal(half_cam.R, full_cam.R)
        image = half.image(half_cam)
        assert image.shape == (72, 96, 3)
        # the half-size render is the full-size one box-filtered: intrinsics scale with the size
        pooled = scene.image(full_cam).reshape(72, 2, 96, 2, 3).mean(axis=(1, 3))
        assert np.abs(image - pooled).mean() < 0.02
    np.testing.assert_array_equal(half.points, scene.points)
    assert builtin_scene(resolution=1).train[0].width == 192
    assert builtin_scene(resolution=3).train[0].width == 64
    with pytest.raises(InputError):
        builtin_scene(resolution=1000)
    with pytest.raises(InputError):
        builtin_scene(resolution=0)


def test_split(scene):
    train, test = split_train_test(all_cameras(scene), 8)
    assert [c.name for c in scene.test] == [c.name for c in test] == ["view_000", "view_008", "view_016", "view_024"]
    assert [c.name for c in scene.train] == [c.name for c in train]
    azimuths = sorted(np.degrees(np.arctan2(c.center[1], c.center[0])) % 360 for c in scene.test)
    assert np.diff(azimuths).min() > 60                # spread around the ring
    assert len(builtin_scene(test_every=4).test) == 8
    assert builtin_scene(test_every=0).test == []


def test_interpolated_split_holds_out_views_inside_the_path():
    """As many test views as the llff rule, spread evenly, none at either end of the path and none beside
    another (each has a training view on both sides), on fresh random path lengths."""
    rng = np.random.default_rng()
    for every, n in zip(rng.integers(3, 12, 40), rng.integers(30, 200, 40)):
        n = max(int(n), 2 * int(every))
        cams = [Camera(name=f"{i:05d}", width=8, height=8, fx=8, fy=8, cx=4, cy=4, R=np.eye(3), t=np.zeros(3))
                for i in rng.permutation(n)]
        train, test = split_train_test(cams, int(every), "interpolated")
        held = sorted(int(c.name) for c in test)
        assert len(held) == len(split_train_test(cams, int(every))[1]) == -(-n // every)
        assert sorted(int(c.name) for c in train + test) == list(range(n))
        assert 0 < held[0] and held[-1] < n - 1 and min(np.diff(held), default=2) >= 2
        assert np.ptp(np.diff([0, *held, n - 1])) <= every       # spread evenly along the path
    scene = builtin_scene(test_split="interpolated")
    assert [c.name for c in scene.test] == ["view_004", "view_012", "view_020", "view_028"]
    with pytest.raises(ValueError, match="test split 'middle'"):
        split_train_test(cams, 8, "middle")


def test_load_scene_dispatch(scene):
    loaded = load_scene("builtin", resolution=2, test_every=4)
    assert loaded.root.name == BUILTIN_SCENE and len(loaded.test) == 8 and loaded.train[0].width == 96
    assert loaded.extent > 0 and len(loaded.points) > 0
