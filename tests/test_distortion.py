"""The lens models rendered directly (scene/distortion.py): the float64 maps against COLMAP's, their Jacobians against
finite differences, the local Jacobian's error and the tile box at the field's edge, and the models refused."""
import numpy as np
import pycolmap
import pytest
from helpers import load_tool

from dc4gs_cl import constants as K
from dc4gs_cl.errors import InputError
from dc4gs_cl.reference.testing import LENSES, distorted_camera
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.scene.distortion import (DIRECT_MODELS, FISHEYE, distort, distort_hessian, distort_jacobian,
                                       from_colmap, radial_profile, undistort)

# coefficients after the intrinsics, in COLMAP's order, moderate enough for a 320x240 image at these focal lengths
COEFFICIENTS = {"SIMPLE_RADIAL": [-0.1], "RADIAL": [-0.1, 0.02], "OPENCV": [-0.1, 0.02, 0.001, -0.002],
                "FULL_OPENCV": [-0.1, 0.02, 0.001, -0.002, 0.003, 0.05, 0.01, 0.001],
                "OPENCV_FISHEYE": [0.05, -0.01, 0.002, -0.001], "RADIAL_FISHEYE": [0.05, -0.01],
                "SIMPLE_RADIAL_FISHEYE": [0.05]}


def colmap_params(model: str, rng) -> list[float]:
    f = rng.uniform(280, 320) if DIRECT_MODELS[model][1] != FISHEYE else rng.uniform(140, 160)
    names = DIRECT_MODELS[model][0]
    given = {"f": f, "fx": f, "fy": f * rng.uniform(0.95, 1.05), "cx": rng.uniform(150, 170),
             "cy": rng.uniform(110, 130)}
    scale = rng.uniform(0.5, 1.5)
    return [given[n] for n in names if n in given] + [c * scale for c in COEFFICIENTS[model]]


@pytest.mark.parametrize("model", DIRECT_MODELS)
def test_lens_models_match_colmap_and_finite_differences(rng, model):
    params = colmap_params(model, rng)
    cam = pycolmap.Camera.create_from_model_name(0, model, 100.0, 320, 240)
    cam.params = params
    (fx, fy, cx, cy), dist = from_colmap(model, params, 320, 240, "cameras.txt", "x.png")
    assert dist is not None and dist.kind == DIRECT_MODELS[model][1]
    u = rng.uniform(-0.6, 0.6, (500, 2))
    u[:20] *= 1e-3                                    # near the axis: the fisheye's series
    colmap = np.asarray(cam.img_from_cam(np.concatenate([u, np.ones((500, 1))], 1)))[:, :2]
    ours = distort(dist, u) * [fx, fy] + [cx, cy]
    assert np.abs(ours - colmap).max() < 1e-9
    h = 1e-6
    steps = np.eye(2) * h
    fd_j = np.stack([(distort(dist, u + e) - distort(dist, u - e)) / (2 * h) for e in steps], -1)
    fd_h = np.stack([(distort_jacobian(dist, u + e) - distort_jacobian(dist, u - e)) / (2 * h) for e in steps], -1)
    assert np.abs(distort_jacobian(dist, u) - fd_j).max() < 1e-8
    assert np.abs(distort_hessian(dist, u) - fd_h).max() < 1e-6
    d = distort(dist, u)
    np.testing.assert_allclose(undistort(dist, d, d), u, atol=1e-10)


def test_fisheye_series_meets_the_closed_form(rng):
    """Below its threshold the profile is a series; on either side of both thresholds (the reference's, the kernel's)
    the two agree to the series' truncation."""
    k = (0.05, -0.02, 0.004, -0.001, 0.0, 0.0)
    for s, tol in ((1e-4, (1e-15, 1e-11, 1e-7)), (K.FISHEYE_SERIES_R2, (1e-8, 1e-6, 1e-4))):
        series = radial_profile(FISHEYE, k, np.array([s]), series_below=1.0)
        closed = radial_profile(FISHEYE, k, np.array([s]), series_below=0.0)
        for a, b, t in zip(series, closed, tol):
            assert abs(a[0] - b[0]) < t, (s, a, b)


@pytest.mark.parametrize("lens", LENSES)
def test_local_jacobian_error_and_tile_box_at_the_field_edge(rng, lens):
    """tools/distortion_error.py's study: Gaussians of 2 and 8 px at the image's corner and 90% of the way to it,
    against the exact model's moments; every sample within 3 sigma of the true footprint lies in the tile box."""
    tool = load_tool("distortion_error")
    cam = distorted_camera(Camera.look_at("edge", (0.0, -4.0, 0.0), (0.0, 0.0, 0.0), 640, 480, fov_x=1.2), lens)
    for fraction in (0.9, 1.0):
        for size, cov_tol in ((2.0, 3e-3), (8.0, 3e-2)):   # the tool's worst of 8 orientations: 1.1e-3, 1.6e-2
            res = tool.study(cam, fraction, size, rng)
            assert res["box miss"] == 0.0, (fraction, size, res)
            assert res["cov rel"] < cov_tol and res["mean px"] < 0.05 * size, (fraction, size, res)


def test_a_radial_map_turning_back_inside_the_image_is_refused():
    # k1 = -0.5: d(r rho)/dr = 1 - 1.5 r^2 turns negative at r = 0.82, short of the corner at f = 300 on 640x480
    with pytest.raises(InputError, match=r"cameras.txt: image 'a.png': the SIMPLE_RADIAL distortion \(k1=-0.5\).*"
                                         r"turns back"):
        from_colmap("SIMPLE_RADIAL", [300.0, 320.0, 240.0, -0.5], 640, 480, "cameras.txt", "a.png")
    # a fisheye whose corners lie past 89 deg
    with pytest.raises(InputError, match="more than 89 deg from the axis"):
        from_colmap("OPENCV_FISHEYE", [100.0, 100.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0001], 640, 480, "c", "b.png")
    # no distortion at all: a pinhole
    assert from_colmap("OPENCV", [300.0, 300.0, 320.0, 240.0, 0, 0, 0, 0], 640, 480, "c", "c.png")[1] is None


def test_a_fisheye_capture_of_the_builtin_scene_trains_the_scene_itself(rt):
    """The built-in scene's views through a fisheye (ground truth ray cast through the lens model) train a model that
    renders the scene's pinhole test views about as well as a run on the pinhole photos does, same seed and
    iterations (measured: 24.27 against 24.36 dB; trained as if the photos were pinholes: 21.06)."""
    from dataclasses import replace

    from dc4gs_cl.config import TrainConfig
    from dc4gs_cl.evaluation.metrics import psnr
    from dc4gs_cl.scene.loader import load_scene
    from dc4gs_cl.train.trainer import Trainer

    pinhole = load_scene("builtin", resolution=2)
    fisheye = replace(pinhole, train=[distorted_camera(c, "fisheye") for c in pinhole.train],
                      test=[distorted_camera(c, "fisheye") for c in pinhole.test])
    assert fisheye.train[0].distortion.kind == FISHEYE and fisheye.train[0].fx < pinhole.train[0].fx
    scores = []
    for scene in (pinhole, fisheye):
        trainer = Trainer(TrainConfig(scene="builtin", iterations=300, resolution=2), scene, rt)
        for _ in range(300):
            trainer.step()
        scores.append(np.mean([psnr(trainer.renderer.render(trainer.params, c, trainer.sh_degree,
                                                            pinhole.background).image(rt), pinhole.image(c))
                               for c in pinhole.test]))
    assert scores[1] > scores[0] - 0.5, scores


def test_a_run_through_a_lens_resumes_to_the_same_model(rt, tmp_path):
    """With DC4GS (the split candidates through the lens too): an interrupted run resumed from its checkpoint ends
    bit for bit where the straight run does."""
    from dataclasses import replace

    from helpers import straight_and_resumed

    from dc4gs_cl.config import DC4GSConfig, TrainConfig
    from dc4gs_cl.scene.loader import load_scene

    scene = load_scene("builtin", resolution=4)
    scene = replace(scene, train=[distorted_camera(c, "opencv") for c in scene.train],
                    test=[distorted_camera(c, "opencv") for c in scene.test])
    cfg = TrainConfig(scene="builtin", iterations=120, resolution=4, densify_from=20, densify_every=20,
                      dc4gs=DC4GSConfig(dcc=True, dcs=True))
    straight, resumed = straight_and_resumed(cfg, scene, rt, tmp_path, 50)
    a, b = straight.model.download(), resumed.model.download()
    assert a.n > len(scene.points)   # densified, DCS' split positions from the view through the lens
    assert all(np.array_equal(a.params[k], b.params[k]) and np.array_equal(a.m[k], b.m[k]) for k in a.params)
