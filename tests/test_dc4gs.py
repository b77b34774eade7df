"""DC4GS on the device: the split candidates' geometry and the per-view split sums against a direct float64
implementation of the paper's algorithms 2 and 3."""
from dataclasses import replace

import numpy as np
import pytest

from dc4gs_cl.reference.dc4gs import split_costs_from_sums, split_geometry_reference
from dc4gs_cl.reference.rasterize import rasterize_backward_reference
from dc4gs_cl.render import DeviceGaussians, Renderer
from dc4gs_cl.render.backward import SumsLayout, rasterize_backward, split_geometry, split_geometry_width
from helpers import SHAPES, random_camera, random_model


def axis_towards_camera(model, idx, cam):
    """Make the first scale the largest and rotate that axis onto the viewing direction."""
    v = cam.center - model.means[idx]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    half = v + np.array([1.0, 0.0, 0.0])                  # quaternion taking e_x onto v
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    model.quats[idx] = np.concatenate([half[:, :1], np.cross([1.0, 0.0, 0.0], half)], 1)
    model.log_scales[idx] = np.log([0.2, 0.02, 0.02])


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("pair_sums", [False, True], ids=["atomics", "pair_sums"])
@pytest.mark.parametrize("candidates", [5, 3])
def test_split_sums_match_the_papers_algorithm(rt, rng, shape, pair_sums, candidates):
    model = random_model(rng, 1200, spread=1.0, scale_range=(0.01, 0.12))
    cam = random_camera(rng, int(rng.integers(80, 130)), int(rng.integers(60, 100)))
    axis_towards_camera(model, np.arange(10), cam)           # the projected axis shrinks to a point
    bg = rng.uniform(0, 1, 3)
    renderer = Renderer(rt, replace(SHAPES[shape], pair_sums=pair_sums), poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 3, bg)
    geometry = split_geometry(rt, renderer.ws, g, cam, res, candidates)
    layout = SumsLayout(stats=True, dc_stats=True, split_candidates=candidates)
    dL_dimage = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
    sums = rasterize_backward(rt, renderer.ws, renderer.tuning, renderer.defines, layout, res,
                              rt.to_device(dL_dimage), bg, geometry)
    n = len(model)
    got = layout.split(rt.to_host(sums, (n, layout.width)).astype(np.float64))
    radius = rt.to_host(res.proj.radius, n, np.int32)
    cand_px, end_px, valid = split_geometry_reference(model.means, model.log_scales, model.quats, cam, radius > 0,
                                                      candidates)
    geo = rt.to_host(geometry, (n, split_geometry_width(candidates)))
    device_valid = (geo[:, 2] != 0) | (geo[:, 3] != 0)
    assert np.array_equal(device_valid, valid)
    assert valid.sum() > 500 and not valid[:10].any()
    co = rt.to_host(res.proj.conic_opacity, (n, 4)).astype(np.float64)
    ref = rasterize_backward_reference(
        rt.to_host(res.proj.mean2d, (n, 2)).astype(np.float64), co[:, :3], co[:, 3],
        rt.to_host(res.proj.rgb, (n, 3)).astype(np.float64),
        rt.to_host(res.isect.gaussian_of_pair, res.isect.n_pairs, np.uint32),
        rt.to_host(res.isect.ranges, (res.tiles_x * res.tiles_y, 2), np.uint32),
        cam.width, cam.height, res.tiles_x, bg, dL_dimage, split=(cand_px, end_px, valid))
    left = got["split"].reshape(n, candidates, 5)
    assert np.isfinite(left).all()
    err = np.linalg.norm(left - ref["split"]) / np.linalg.norm(ref["split"])
    assert err < 2e-3, err           # float32 sums; a pixel within rounding of a split line may change side
    total = np.concatenate([ref["dc"], ref["abs"]], 1)
    J_device = split_costs_from_sums(left, np.concatenate([got["dc"], got["abs"]], 1))
    J_reference = split_costs_from_sums(ref["split"], total)
    sel = valid & (ref["dc"][:, 2] > 0)
    assert np.linalg.norm(J_device[sel] - J_reference[sel]) / np.linalg.norm(J_reference[sel]) < 5e-3


def one_view_window(rt, model, cam, target, background, strategy):
    """The window statistics of one view (the device path training takes) for a hand-built model."""
    from dc4gs_cl.host.stats import WindowStats
    from dc4gs_cl.loss import Loss
    from dc4gs_cl.render.workspace import POISON
    renderer = Renderer(rt, poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 0, background)
    grad = rt.to_device(np.full(target.size, POISON, np.uint32))
    Loss(rt)(res.raster.image, rt.to_device(target.astype(np.float32)), cam.width, cam.height, grad)
    layout = strategy.sums_layout()
    geometry = split_geometry(rt, renderer.ws, g, cam, res, layout.split_candidates) if layout.split_candidates else None
    sums = rasterize_backward(rt, renderer.ws, renderer.tuning, renderer.defines, layout, res, grad, background, geometry)
    window = WindowStats(rt, layout, 1.0, strategy.window_layout())
    window.reset(len(model))
    window.accumulate(res, sums, geometry)
    return window.download(), layout.split(rt.to_host(sums, (len(model), layout.width)))


def flat_scene(n):
    """A camera facing the x-z plane from -y: world x is image x, world z image up."""
    from dc4gs_cl.model import GaussianModel, logit, rgb_to_sh_dc
    from dc4gs_cl.scene.camera import Camera
    cam = Camera.look_at("front", (0.0, -4.0, 0.0), (0.0, 0.0, 0.0), 160, 96, fov_x=1.2)
    model = GaussianModel(means=np.zeros((n, 3)), log_scales=np.zeros((n, 3)), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                          opacity_logits=np.full(n, logit(0.9)), sh=np.zeros((n, 1, 3)))
    return cam, model, rgb_to_sh_dc


def pixel_x(cam, world_x):
    return cam.fx * world_x / 4.0 + cam.cx


def bright_blob(cam, centre_x, sigma_x, sigma_y, height=0.9):
    xs = np.arange(cam.width) + 0.5
    ys = np.arange(cam.height)[:, None] + 0.5
    g = np.exp(-0.5 * (((xs - pixel_x(cam, centre_x)) / sigma_x) ** 2 + ((ys - cam.cy) / sigma_y) ** 2))
    return height * np.repeat(g[..., None], 3, axis=2)


def two_objects(cam, sigma, boundary, scale_y):
    """Two bright objects under one Gaussian (scales sigma along world x), meeting at normalised
    position `boundary` along its diameter: pixels over each pull the Gaussian towards their own object."""
    px = cam.fx * sigma / 4.0
    at = lambda xn: -3 * sigma + 6 * sigma * xn
    return (bright_blob(cam, at(boundary / 2), 0.6 * px * boundary * 2, scale_y)
            + bright_blob(cam, at((1 + boundary) / 2), 0.6 * px * (1 - boundary) * 2, scale_y))


def test_dc_guided_split_cuts_where_two_objects_meet(rt):
    from dc4gs_cl.host.dc4gs import DC4GSConfig, split_positions
    from dc4gs_cl.host.strategy import AbsGS
    cam, model, to_sh = flat_scene(1)
    sigma = 0.5
    model.log_scales[0] = np.log([sigma, 0.05, 0.25])          # long along x: the principal axis
    model.sh[0, 0] = to_sh([0.5, 0.5, 0.5])
    boundary = 0.35                                             # normalised position along the diameter
    target = two_objects(cam, sigma, boundary, cam.fx * 0.25 / 4.0)
    stats, _ = one_view_window(rt, model, cam, target, np.zeros(3, np.float32), AbsGS(dc4gs_config=DC4GSConfig()))
    for pick in ("poly", "argmin"):                              # measured: 0.317 and 0.333
        x = split_positions(stats["j"], pick)[0]
        assert abs(x - boundary) < 0.08, (pick, x, stats["j"])
    assert split_positions(stats["j"], "poly")[0] != 0.5      # the costs did decide


def test_directional_consistency_tells_a_shift_from_two_objects(rt):
    """Two Gaussians of one view: A's target is A itself shifted (its pixels agree: move), B covers two
    objects (its pixels disagree: split). DCC weights B's gradient by far more than A's."""
    from dc4gs_cl.host.dc4gs import DC4GSConfig
    from dc4gs_cl.host.strategy import AbsGS
    from dc4gs_cl.host.strategy.base import mean_per_view
    from dc4gs_cl.model import GaussianModel
    cam, model, to_sh = flat_scene(2)
    sigma = 0.35
    model.log_scales[:] = np.log([sigma, 0.05, 0.2])
    model.means[:, 0] = [-1.3, 1.3]
    model.sh[:, 0] = to_sh(np.array([[0.7, 0.7, 0.7], [0.5, 0.5, 0.5]]))
    shifted_a = GaussianModel(model.means[:1] + [0.3 * sigma, 0, 0], model.log_scales[:1], model.quats[:1],
                              model.opacity_logits[:1], model.sh[:1])
    target = Renderer(rt).render(DeviceGaussians(rt, shifted_a), cam, 0, np.zeros(3, np.float32)).image(rt)
    target = target + np.roll(two_objects(cam, sigma, 0.5, cam.fx * 0.2 / 4.0), int(pixel_x(cam, 1.3) - cam.cx), axis=1)
    strategy = AbsGS(dc4gs_config=DC4GSConfig(dcs=False))
    stats, sums = one_view_window(rt, model, cam, target, np.zeros(3, np.float32), strategy)
    kappa = np.linalg.norm(sums["dc"][:, :2], axis=1) / sums["dc"][:, 2]
    assert kappa[0] > 0.5 and kappa[1] < 0.3, kappa             # measured: 0.59 and 0.17
    weight = strategy.split_criterion(stats) / mean_per_view(stats["abs"], stats["views"])
    np.testing.assert_allclose(weight, 1 - kappa, rtol=1e-5)    # one view: DCC = (1 - kappa) |ghat|
    assert weight[1] > 1.4 * weight[0]


@pytest.mark.parametrize("pooling", ["view", "window"])
def test_window_statistics_follow_the_spec(rt, rng, pooling):
    """Random per-view sums through the device's window accumulation against the spec written in NumPy."""
    from types import SimpleNamespace
    from dc4gs_cl.host.stats import PIXELGS_DEPTH_FRACTION, WindowLayout, WindowStats
    from dc4gs_cl.reference.dc4gs import side_cost
    n, views, candidates, extent, width, height = 300, 6, 5, 3.0, 120, 80
    layout = SumsLayout(stats=True, dc_stats=True, split_candidates=candidates)
    window = WindowStats(rt, layout, extent, WindowLayout(dc=True, split_candidates=candidates,
                                                          window_pooling=pooling == "window"))
    window.reset(n)
    f = layout.fields
    acc = {k: np.zeros(n) for k in ("grad", "abs", "views", "pix_grad", "pix", "dcc_abs", "dcc_grad", "dcc_pix")}
    acc["max_radius"], acc["j"] = np.zeros(n), np.zeros((n, candidates))
    win_u, win_total, win_left = np.zeros((n, 3)), np.zeros((n, 5)), np.zeros((n, candidates, 5))
    for _ in range(views):
        sums = rng.normal(size=(n, layout.width)).astype(np.float32)
        count = rng.integers(0, 40, n).astype(np.float32)
        count[rng.random(n) < 0.1] = 0                                  # some see no pixel
        sums[:, f["dc"][0] + 2] = count
        sums[:, f["pixels"][0]] = count + rng.integers(0, 5, n)
        left = rng.uniform(0, 1, (n, candidates, 5)).astype(np.float32)  # left sums within the totals
        total = np.concatenate([sums[:, f["dc"][0]:f["dc"][0] + 3], sums[:, f["abs"][0]:f["abs"][0] + 2]], 1)
        left = left * total[:, None, :]
        sums[:, f["split"][0]:f["split"][0] + 5 * candidates] = left.reshape(n, -1)
        radius = rng.integers(0, 3, n).astype(np.int32) * rng.integers(1, 30, n).astype(np.int32)
        depth = rng.uniform(0.5, 3.0, n).astype(np.float32)
        geometry = np.zeros((n, split_geometry_width(candidates)), np.float32)
        line = rng.random(n) < 0.8
        geometry[line, 2] = 1.0
        res = SimpleNamespace(width=width, height=height, proj=SimpleNamespace(radius=rt.to_device(radius),
                                                                                depth=rt.to_device(depth)))
        window.accumulate(res, rt.to_device(sums), rt.to_device(geometry))
        # the spec, in NumPy
        vis = radius > 0
        s = sums.astype(np.float64)
        g = np.hypot(s[:, 0] * width / 2, s[:, 1] * height / 2)
        ghat = np.hypot(s[:, f["abs"][0]], s[:, f["abs"][0] + 1])
        pix = s[:, f["pixels"][0]]
        fac = np.minimum(1, (depth / (PIXELGS_DEPTH_FRACTION * extent)) ** 2)
        u = s[:, f["dc"][0]:f["dc"][0] + 3]
        if pooling == "window":
            win_u[vis] += u[vis]
            u = win_u
        kappa_weight = np.where(u[:, 2] > 0, 1 - np.hypot(u[:, 0], u[:, 1]) / np.where(u[:, 2] > 0, u[:, 2], 1), 0)
        for key, value in (("grad", g), ("abs", ghat), ("views", 1.0), ("pix_grad", fac * g * pix), ("pix", pix),
                           ("dcc_abs", kappa_weight * ghat), ("dcc_grad", kappa_weight * g),
                           ("dcc_pix", kappa_weight * fac * g * pix)):
            acc[key] += np.where(vis, value, 0)
        acc["max_radius"] = np.maximum(acc["max_radius"], radius)
        if pooling == "window":
            add = vis & line
            win_total[add] += total[add]
            win_left[add] += left[add]
            cost = side_cost(win_left) + side_cost(win_total[:, None] - win_left)
            acc["j"] += np.where(vis[:, None], cost, 0)
        else:
            cost = side_cost(left) + side_cost(total[:, None] - left)
            acc["j"] += np.where((vis & line)[:, None], cost, 0)
    got = window.download()
    for key, want in acc.items():
        np.testing.assert_allclose(got[key], want, rtol=2e-4, atol=1e-4, err_msg=key)


def test_poly_split_position_is_the_exact_minimum_of_the_interpolating_quartic(rng):
    from dc4gs_cl.host.dc4gs import interpolating_polynomials, split_positions
    costs = rng.uniform(0, 1, (500, 5)) * 10.0 ** rng.uniform(-6, 2, (500, 1))
    x = split_positions(costs, "poly")
    coeffs = interpolating_polynomials(costs)
    grid = np.linspace(1 / 12, 11 / 12, 400_001)
    values = np.polynomial.polynomial.polyval(grid, coeffs.T)
    ours = np.array([np.polynomial.polynomial.polyval(xi, c) for xi, c in zip(x, coeffs)])
    scale = np.abs(values).max(axis=1)
    assert np.all(ours <= values.min(axis=1) + 1e-12 * scale)    # never worse than a dense grid
    assert np.all((x >= 1 / 12) & (x <= 11 / 12))
    # and the polynomial is the interpolant: it goes through the candidates' costs (float64 rounding scales
    # with the row's largest cost, so a cost far below it is compared at that scale: seed 2380669922)
    row = costs.max(axis=1, keepdims=True)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(np.arange(1, 6) / 6, coeffs.T) / row, costs / row,
                               rtol=1e-9, atol=1e-12)


def test_poly_finds_a_minimum_within_one_grid_cell_of_either_end():
    """A quartic's minimum 1e-4 inside an end of [1/12, 11/12], closer than the search grid's spacing: the
    grid's best point is the end itself, and the exact minimum must still be found."""
    from dc4gs_cl.host.dc4gs import split_positions
    candidates = np.arange(1, 6) / 6
    ends = np.array([1 / 12 + 1e-4, 11 / 12 - 1e-4])
    costs = (candidates[None, :] - ends[:, None]) ** 2 + 0.3          # parabolas: the quartic through them
    np.testing.assert_allclose(split_positions(costs, "poly"), ends, atol=1e-9)


def test_argmin_dense_and_constant_costs():
    from dc4gs_cl.host.dc4gs import split_positions
    costs = np.array([[3.0, 1.0, 2.0, 5.0, 4.0], [0.0] * 5, [2.0] * 5, [1.0, np.nan, 1.0, 1.0, 1.0]])
    np.testing.assert_allclose(split_positions(costs, "argmin"), [2 / 6, 0.5, 0.5, 0.5])
    dense = np.abs(np.linspace(0, 1, 61)[1:-1] - 0.7)[None]       # 59 candidates, minimum nearest 0.7
    assert abs(split_positions(dense, "dense")[0] - 0.7) < 1 / 60
    np.testing.assert_allclose(split_positions(costs[1:3], "poly"), 0.5)


def test_dc_guided_split_children(rng):
    from dc4gs_cl.host.dc4gs import split_at
    from dc4gs_cl.host.ops import GaussianSet
    from dc4gs_cl.reference.project import quat_to_rotmat
    n = 3
    q = rng.normal(size=(n, 4))
    params = {"means": rng.normal(size=(n, 3)), "log_scales": np.log([[0.2, 0.5, 0.1], [0.3, 0.3, 0.3], [0.1, 0.1, 0.4]]),
              "quats": q, "opacity_logits": np.array([[0.4], [1.0], [-0.5]]), "sh": rng.normal(size=(n, 12))}
    params = {k: v.astype(np.float32) for k, v in params.items()}
    gs = GaussianSet(dict(params), {k: np.ones_like(v) for k, v in params.items()},
                     {k: np.ones_like(v) for k, v in params.items()})
    x = np.array([0.3, 0.6])
    assert split_at(gs, np.array([0, 1]), x) == 2
    assert gs.n == 5
    np.testing.assert_array_equal(gs.params["sh"][0], params["sh"][2])          # the unsplit one stays first
    for parent, xi, (left, right), axis in ((0, 0.3, (1, 2), 1), (1, 0.6, (3, 4), 0)):   # isotropic: first axis
        s = np.exp(params["log_scales"][parent].astype(np.float64))
        sigma = s[axis]
        p = quat_to_rotmat(params["quats"][parent][None])[0][:, axis]
        mu = params["means"][parent]
        np.testing.assert_allclose(gs.params["means"][left], mu - 3 * sigma * (1 - xi) * p, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(gs.params["means"][right], mu + 3 * sigma * xi * p, rtol=1e-5, atol=1e-6)
        for child, fraction in ((left, xi), (right, 1 - xi)):
            want = s.copy()
            want[axis] = sigma * fraction
            np.testing.assert_allclose(np.exp(gs.params["log_scales"][child]), want, rtol=1e-5)
            o = 1 / (1 + np.exp(-params["opacity_logits"][parent, 0]))
            np.testing.assert_allclose(1 / (1 + np.exp(-gs.params["opacity_logits"][child, 0])), o * fraction, rtol=1e-5)
            np.testing.assert_array_equal(gs.params["quats"][child], params["quats"][parent])
            np.testing.assert_array_equal(gs.params["sh"][child], params["sh"][parent])
            for moments in (gs.m, gs.v):
                assert all(np.all(moments[k][child] == 0) for k in moments)


def test_noise_sized_costs_split_in_the_middle(rng):
    from dc4gs_cl.host.dc4gs import split_positions
    noise = rng.normal(0, 1e-16, (4, 5))         # vanishing gradients leave only rounding noise
    np.testing.assert_array_equal(split_positions(np.abs(noise), "poly"), 0.5)


def test_split_costs_stop_for_gaussians_whose_criterion_stays_low(rt, rng):
    """With tracking, a Gaussian whose running split criterion stays under track x threshold after its
    first views gets no split line (no costs); one above it keeps its line."""
    from types import SimpleNamespace
    from dc4gs_cl.host.stats import TRACK_MIN_VIEWS, WindowLayout, WindowStats
    n, candidates = 4, 5
    layout = SumsLayout(stats=True, dc_stats=True, split_candidates=candidates)
    wl = WindowLayout(dc=True, split_candidates=candidates, criterion=("abs", "views"))
    window = WindowStats(rt, layout, 1.0, wl, track_threshold=1.0)
    window.reset(n)
    sums = np.zeros((n, layout.width), np.float32)
    sums[:, layout.fields["abs"][0]] = [0.1, 5.0, 0.1, 5.0]          # per-view |ghat| below / above 1
    res = SimpleNamespace(width=10, height=10, proj=SimpleNamespace(radius=rt.to_device(np.full(n, 3, np.int32)),
                                                                     depth=rt.to_device(np.ones(n, np.float32))))
    for view in range(TRACK_MIN_VIEWS + 1):
        assert np.array_equal(window.download()["skip_split"], [0, 0, 0, 0] if view < TRACK_MIN_VIEWS else [1, 0, 1, 0])
        window.accumulate(res, rt.to_device(sums), rt.to_device(np.zeros((n, split_geometry_width(candidates)), np.float32)))

    # split_geometry then gives the skipped Gaussians no line, and the others theirs
    cam, model, _ = flat_scene(n)
    model.means[:, 0] = [-1.5, -0.5, 0.5, 1.5]
    model.log_scales[:] = np.log([0.3, 0.05, 0.1])     # longest along world x = image x
    renderer = Renderer(rt, poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 0)
    assert (rt.to_host(res.proj.radius, n, np.int32) > 0).all()
    geometry = split_geometry(rt, renderer.ws, g, cam, res, candidates, window=(window.buffer, wl.defines()))
    geo = rt.to_host(geometry, (n, split_geometry_width(candidates)))
    np.testing.assert_array_equal(np.abs(geo[:, 2:4]).sum(1) > 0, [False, True, False, True])
