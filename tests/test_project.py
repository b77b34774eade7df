import numpy as np
import pytest

from dc4gs_cl.reference import project_reference
from dc4gs_cl.reference.project import rect_area, tile_rect_reference
from dc4gs_cl.constants import tile_grid
from dc4gs_cl.render import DeviceGaussians
from dc4gs_cl.render.options import RenderOptions
from dc4gs_cl.render.project import Project
from dc4gs_cl.render.stage import StageContext
from helpers import distorted_camera, random_camera, random_model


def rel_l2(a, b):
    return np.linalg.norm(np.asarray(a, np.float64) - b) / max(np.linalg.norm(b), 1e-30)


def run_projection(rt, model, cam, sh_degree, antialiased=False):
    tiles_x, tiles_y = tile_grid(cam.width, cam.height)
    g = DeviceGaussians(rt, model)
    ctx = StageContext(rt, options=RenderOptions(antialiased=antialiased), poison=True)
    p = Project(ctx)(g, cam, sh_degree, tiles_x, tiles_y)
    n = len(model)
    got = {"mean2d": rt.to_host(p.mean2d, (n, 2)), "conic_opacity": rt.to_host(p.conic_opacity, (n, 4)),
           "rgb": rt.to_host(p.rgb, (n, 3)), "depth": rt.to_host(p.depth, n),
           "radius": rt.to_host(p.radius, n, np.int32), "tiles_touched": rt.to_host(p.tiles_touched, n, np.uint32),
           "alpha_extent": rt.to_host(p.alpha_extent, (n, 2))}
    ref = project_reference(model.means, model.log_scales, model.quats, model.opacity_logits, model.sh, cam,
                            sh_degree, tiles_x, tiles_y, antialiased)
    return got, ref


@pytest.mark.parametrize("sh_degree,antialiased,lens", [(0, False, None), (1, False, None), (2, False, None),
                                                        (3, False, None), (3, True, None), (3, False, "opencv"),
                                                        (3, False, "full_opencv"), (3, False, "fisheye"),
                                                        (3, True, "fisheye")])
def test_projection_matches_float64_reference(rt, rng, sh_degree, antialiased, lens):
    model = random_model(rng, 5000, sh_degree=3, spread=2.0)
    width = int(rng.integers(90, 200))   # a lens' images wider than high: the fisheye's corners within its field
    cam = random_camera(rng, width, int(rng.integers(60, 150 if lens is None else 0.9 * width)), distance=3.5)
    if lens is not None:   # a lens model; a tenth of the centres past its field (culled however far they reach)
        cam = distorted_camera(cam, lens)
        u = np.sqrt(cam.distortion.r2_max) * rng.uniform(1.05, 2.0, 500)
        model.means[-500:] = cam.center + rng.uniform(1, 4, (500, 1)) * (cam.R[2] + u[:, None] * cam.R[0])
        model.log_scales[-500:] = np.log(rng.uniform(0.1, 1.0, (500, 1)))
    if antialiased:
        model.log_scales[:500] = np.log(rng.uniform(0.002, 0.02, (500, 1)))   # sub-pixel ones too
    got, ref = run_projection(rt, model, cam, sh_degree, antialiased)
    tiles_x, tiles_y = tile_grid(cam.width, cam.height)
    np.testing.assert_allclose(got["depth"], ref["depth"], rtol=1e-5, atol=1e-5)
    # Radius is a ceil() of a float: it may differ by one where the float32 value sits on an integer.
    vis = ref["radius"] > 0
    assert vis.sum() > 500 and (~vis).sum() > 100, "the draw should hold visible and culled Gaussians"
    assert np.mean(got["radius"] != ref["radius"]) < 2e-3
    assert np.all(np.abs(got["radius"].astype(np.int64) - ref["radius"])[vis & (got["radius"] > 0)] <= 1)
    both = vis & (got["radius"] > 0)
    assert both.sum() >= 0.995 * vis.sum()
    assert np.all(got["tiles_touched"][got["radius"] == 0] == 0)
    # Tiles come from the 3-sigma box cut to where alpha can reach 1/255: low opacities touch fewer.
    assert np.mean(got["tiles_touched"].astype(np.int64) != ref["tiles_touched"]) < 2e-3
    box = tile_rect_reference(got["mean2d"][both], np.repeat(got["radius"][both, None], 2, 1), tiles_x, tiles_y)
    assert np.all(got["tiles_touched"][both] <= rect_area(box))
    faint = ref["opacity"][both] < 0.1
    assert faint.sum() > 20 and np.mean(got["tiles_touched"][both][faint] < rect_area(box)[faint]) > 0.3
    assert rel_l2(got["alpha_extent"][both], ref["alpha_extent"][both]) < 1e-5
    for key, r in [("mean2d", ref["mean2d"]), ("rgb", ref["rgb"])]:
        assert np.isfinite(got[key][both]).all()
        assert rel_l2(got[key][both], r[both]) < 1e-5, key
    assert rel_l2(got["conic_opacity"][both, :3], ref["conic"][both]) < 1e-4
    assert rel_l2(got["conic_opacity"][both, 3], ref["opacity"][both]) < 1e-6
    if antialiased:   # the compensation spans its range: sub-pixel Gaussians far below 1, large ones near it
        ratio = ref["opacity"][both] * (1 + np.exp(-model.opacity_logits[both].astype(np.float64)))
        assert ratio.min() < 0.2 and ratio.max() > 0.95, (ratio.min(), ratio.max())
        # each Gaussian's, not only in the mean: a faint one's error is its alpha extent's, amplified
        # 1 / ln(opacity / ALPHA_MIN) times (formed from the dilated covariance, det(Sigma) cancelled to 1e-3)
        opacity = got["conic_opacity"][both, 3].astype(np.float64)
        assert np.max(np.abs(opacity - ref["opacity"][both]) / ref["opacity"][both]) < 5e-5


@pytest.mark.parametrize("antialiased", [False, True], ids=["classic", "antialiased"])
def test_projection_of_degenerate_gaussians_is_finite_or_culled(rt, rng, antialiased):
    model = random_model(rng, 400, spread=1.0)
    cam = random_camera(rng, 120, 90)
    n = len(model)
    idx = rng.permutation(n)
    model.quats[idx[:40]] = 0.0                                    # zero-norm quaternions
    model.log_scales[idx[40:80]] = rng.choice([-30.0, 20.0], (40, 3))   # vanishing and huge scales
    model.log_scales[idx[80:120], 0] = -25.0                         # needle-thin
    model.opacity_logits[idx[120:160]] = rng.choice([-30.0, 30.0], 40)
    model.means[idx[160:200]] = cam.center + rng.normal(0, 1e-3, (40, 3))   # on or behind the near plane
    model.means[idx[200:240]] = model.means[idx[200]]                # coincident
    got, ref = run_projection(rt, model, cam, 3, antialiased)
    vis = got["radius"] > 0
    for key in ("mean2d", "conic_opacity", "rgb"):
        assert np.isfinite(got[key][vis]).all(), key
    assert not vis[idx[160:200]].any()
    # Zero-norm quaternions project as the identity rotation, as the reference does.
    z = idx[:40][vis[idx[:40]] & (ref["radius"][idx[:40]] > 0)]
    assert len(z) and rel_l2(got["conic_opacity"][z, :3], ref["conic"][z]) < 1e-4
    assert (got["conic_opacity"][vis, 3] >= 0).all() and (got["conic_opacity"][vis, 3] <= 1).all()
