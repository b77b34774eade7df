"""DC4GS on the device: the split candidates' geometry and the per-view split sums against a direct float64
implementation of the paper's algorithms 2 and 3."""
from dataclasses import replace

import numpy as np
import pytest
from helpers import SHAPES, distorted_camera, random_camera, random_model

from dc4gs_cl.backward import RasterizeBackward, SplitGeometry
from dc4gs_cl.backward.rasterize_backward import pair_runs
from dc4gs_cl.backward.sum_pairs import CARRY_ROWS, CARRY_TAKEN, RUN_SPANS
from dc4gs_cl.densify import AbsGS, DC4GSConfig
from dc4gs_cl.reference.dc4gs import split_costs_from_sums, split_geometry_reference
from dc4gs_cl.reference.rasterize import rasterize_backward_reference
from dc4gs_cl.render import DeviceGaussians, Renderer
from dc4gs_cl.render.isect import PAIR_TEMPORARIES
from dc4gs_cl.statistics import SPLIT_COSTS, SumsLayout, geometry_record


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
    check_split_sums(rt, rng, shape, pair_sums, candidates)


@pytest.mark.parametrize("lens", ["opencv", "fisheye"])
def test_split_sums_through_a_lens_model(rt, rng, lens):
    """The candidates' pixels go through the view's lens model, as the centres do. The kernel sides them by the chord
    from the first candidate's pixel to the axis end's (split_geometry.cl), where a lens bends the axis' image
    slightly; the paper's algorithm (the reference) sides them by the bent points: within 1%."""
    check_split_sums(rt, rng, "cpu", True, 5, lens)


def check_split_sums(rt, rng, shape, pair_sums, candidates, lens=None):
    model = random_model(rng, 1200, spread=1.0, scale_range=(0.01, 0.12))
    width = int(rng.integers(80, 130))   # a lens' images wider than high: the fisheye's corners within its field
    cam = random_camera(rng, width, int(rng.integers(60, 100 if lens is None else 0.9 * width)))
    cam = cam if lens is None else distorted_camera(cam, lens)
    axis_towards_camera(model, np.arange(10), cam)           # the projected axis shrinks to a point
    bg = rng.uniform(0, 1, 3)
    renderer = Renderer(rt, replace(SHAPES[shape], pair_sums=pair_sums), poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 3, bg)
    geometry = SplitGeometry(renderer.context)(g, cam, res, candidates)
    layout = SumsLayout(stats=True, dc_stats=True, split_candidates=candidates)
    dL_dimage = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
    sums = RasterizeBackward(renderer.context)(res, rt.to_device(dL_dimage), bg, layout, geometry)
    n = len(model)
    got = layout.views(rt.to_host(sums, (n, layout.width)).astype(np.float64))
    radius = rt.to_host(res.proj.radius, n, np.int32)
    cand_px, end_px, valid = split_geometry_reference(model.means, model.log_scales, model.quats, cam, radius > 0,
                                                      candidates)
    geo = geometry_record(candidates).views(rt.to_host(geometry, (n, geometry_record(candidates).width)))
    device_valid = (geo["dir"] != 0).any(axis=1)
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
    # float32 sums; a pixel within rounding of a split line may change side
    assert err < (2e-3 if lens is None else 1e-2), err
    if lens is not None:
        return
    # Each Gaussian's every left sum (the kernel tests per pixel only the candidates whose line crosses the pixels
    # a pair walks: the others take the pair's totals or zeros) within float32 rounding of its magnitude, past what
    # pixels within rounding of the line, or of blending at all (they move the totals too), may move.
    total = np.concatenate([ref["dc"], ref["abs"]], 1)
    moved = np.abs(np.concatenate([got["dc"], got["abs"]], 1) - total)[:, None]
    magnitude = np.concatenate([ref["dc"][:, [2, 2, 2]], ref["abs"]], 1)[:, None]     # sums of the terms' sizes
    slack = ref["split_near"] + moved + 1e-4 * magnitude + 1e-6
    assert (np.abs(left - ref["split"]) <= slack).all(), np.abs(left - ref["split"]).max()
    J_device = split_costs_from_sums(left, np.concatenate([got["dc"], got["abs"]], 1))
    J_reference = split_costs_from_sums(ref["split"], total)
    sel = valid & (ref["dc"][:, 2] > 0)
    assert np.linalg.norm(J_device[sel] - J_reference[sel]) / np.linalg.norm(J_reference[sel]) < 5e-3



def test_split_line_follows_the_first_largest_log_scale(rt, rng):
    """The device's split axis is geometry.principal_axis' (the host's, for the split itself): the largest
    scale, the first on ties, also for scales equal or one float apart (where exps rounded separately could
    reorder them)."""
    model = random_model(rng, 400, spread=0.8, scale_range=(0.02, 0.1))
    cam = random_camera(rng, 96, 72)
    logs = model.log_scales
    k = rng.integers(0, 3, 400)
    top = logs[np.arange(400), k]
    for i in range(0, 400, 4):                              # equal largest scales, in every pair of axes
        logs[i, (k[i] + 1) % 3] = top[i]
    for i in range(1, 400, 4):                              # one float apart, either way
        logs[i, (k[i] + 1) % 3] = np.nextafter(top[i], np.float32(np.inf if i % 8 == 1 else -np.inf))
    logs[2:400:4] = top[2:400:4, None]                      # isotropic
    renderer = Renderer(rt, SHAPES["cpu"], poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 3, np.zeros(3))
    geometry = SplitGeometry(renderer.context)(g, cam, res, 5)
    record = geometry_record(5)
    geo = record.views(rt.to_host(geometry, (len(model), record.width)))
    radius = rt.to_host(res.proj.radius, len(model), np.int32)
    cand_px, end_px, valid = split_geometry_reference(model.means, logs, model.quats, cam, radius > 0, 5)
    assert valid.sum() > 200
    d = end_px - cand_px[:, 0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.abs(geo["dir"][valid] - d[valid]).max() < 1e-4


@pytest.mark.parametrize("shape", SHAPES)
def test_backward_in_runs_sums_exactly_as_in_one(rt, rng, shape):
    """The per-pair slots held at once bounded (Tuning.pair_chunk): the frame's pairs are walked in runs of
    consecutive pairs, each run's slots summed onto the sums (a tile holding pairs of two runs walked by both, each
    writing its own); a Gaussian's pairs are added in the same order, so the sums (gradients, statistics and split
    sums, the widest layout) equal the one-run backward's bit for bit, also where the frame was given room for more
    pairs than it has (runs past its pairs find nothing to do). So do the split sums added per column block after
    its pixels' walk (Tuning.split_sums_per_block): the same adds in the same order."""
    model = random_model(rng, 900, spread=1.0, scale_range=(0.01, 0.12))
    cam = random_camera(rng, int(rng.integers(80, 130)), int(rng.integers(60, 100)))
    bg = rng.uniform(0, 1, 3)
    dL_dimage = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
    layout = SumsLayout(stats=True, dc_stats=True, split_candidates=5)
    runs = replace(SHAPES[shape], pair_chunk=0.1, min_run_tiles=1)
    got, walked = {}, {}
    for name, tuning, room in (("one run", SHAPES[shape], None), ("runs", runs, None), ("runs with room", runs, 2.0),
                               ("per block", replace(SHAPES[shape], split_sums_per_block=True), None)):
        renderer = Renderer(rt, tuning, poison=True)
        g = DeviceGaussians(rt, model)
        res = renderer.render(g, cam, 3, bg)
        pairs = res.isect.n_pairs
        if room:
            res = renderer.render(g, cam, 3, bg, pair_capacity=int(room * pairs))
        geometry = SplitGeometry(renderer.context)(g, cam, res, 5)
        backward = RasterizeBackward(renderer.context)
        plan = backward.plan(res, layout)
        walked[name] = plan.runs, (plan.runs - 1) * plan.pairs_per_run >= pairs   # a run past the pairs
        sums = backward(res, rt.to_device(dL_dimage), bg, layout, geometry)
        got[name] = rt.to_host(sums, (len(model), layout.width))
    assert walked["one run"] == (1, False) and walked["runs"][0] >= 4 and walked["runs with room"][1]
    assert np.isfinite(got["runs"]).all() and np.count_nonzero(got["runs"][:, -5:]) > 100
    for name in ("runs", "runs with room", "per block"):
        assert np.array_equal(got[name], got["one run"]), name


@pytest.mark.parametrize("shape", SHAPES)
def test_split_sums_of_candidates_out_of_order(rt, rng, shape):
    """A candidate's left sums depend on its own t_k alone: with the candidates 1 .. N-1 of every line given in
    reverse order (t_k decreasing, which the walk's crossing range cannot take: it then tests every candidate per
    pixel), each candidate's sums are those it has in order, where most pairs test one or two candidates per pixel
    and take the pair's totals or zeros for the rest (so within rounding of the totals, not bit for bit)."""
    model = random_model(rng, 900, spread=1.0, scale_range=(0.02, 0.2))
    cam = random_camera(rng, int(rng.integers(80, 130)), int(rng.integers(60, 100)))
    bg = rng.uniform(0, 1, 3)
    dL_dimage = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
    layout, record = SumsLayout(stats=True, dc_stats=True, split_candidates=5), geometry_record(5)
    renderer = Renderer(rt, SHAPES[shape], poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 3, bg)
    n = len(model)
    geo = rt.to_host(SplitGeometry(renderer.context)(g, cam, res, 5), (n, record.width)).copy()
    t = record.views(geo)["t"]
    assert (np.diff(t[(t != 0).any(axis=1)], axis=1) > 0).all()         # in order as the projection gives them
    reverse = geo.copy()
    record.views(reverse)["t"][:] = t[:, ::-1]
    got = {}
    for name, rows in (("in order", geo), ("reversed", reverse)):
        sums = RasterizeBackward(renderer.context)(res, rt.to_device(dL_dimage), bg, layout, rt.to_device(rows))
        got[name] = layout.views(rt.to_host(sums, (n, layout.width)).astype(np.float64))["split"].reshape(n, 5, 5)
    assert np.count_nonzero(got["in order"]) > 1000
    unreversed = got["reversed"][:, [0, 4, 3, 2, 1]]
    # rounding is relative to the sum of the terms' magnitudes: ux, uy add unit-vector components (at most the
    # count, and they cancel), the counts and the absolute sums their own values
    most = np.abs(got["in order"]).max(axis=1, keepdims=True)
    count = most[..., [2]]
    scale = np.concatenate([count, count, most[..., 2:]], axis=-1) + 1e-6
    assert (np.abs(unreversed - got["in order"]) <= 1e-5 * scale).all()


@pytest.mark.parametrize("candidates", [5, 15])
def test_split_sums_of_the_subgroup_reduction_are_its_twins(rt, rng, candidates):
    """DC4GS' split sums in the GPU shape: reduced over 32-lane subgroups (KHR or PTX), each lane
    testing its own pixel against the candidates crossing the subgroup's two rows after the walk (only those
    reduced, the others zeros or the pair's totals), they are the bits of the portable twin (32 pixels per
    work-item, the same two rows in 16-column blocks), split sums and all; and the same bits again when the frame
    is walked in runs (other launches, tiles cut between them)."""
    if rt.caps.subgroups is None:
        pytest.skip("needs subgroups: cl_khr_subgroup_shuffle with Intel's required subgroup size (Intel's CPU "
                    'runtime: DC4GS_DEVICE="Intel(R) OpenCL") or NVIDIA\'s inline PTX')
    from dc4gs_cl.render import StageContext
    model = random_model(rng, 900, spread=1.0, scale_range=(0.02, 0.2))
    cam = random_camera(rng, int(rng.integers(80, 130)), int(rng.integers(60, 100)))
    bg = rng.uniform(0, 1, 3)
    dL_dimage = rt.to_device(rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32))
    layout = SumsLayout(stats=True, dc_stats=True, split_candidates=candidates)
    renderer = Renderer(rt, replace(SHAPES["gpu"], subgroups=rt.caps.subgroups), poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 3, bg)
    geometry = SplitGeometry(renderer.context)(g, cam, res, candidates)
    runs = replace(SHAPES["gpu"], subgroups=rt.caps.subgroups, pair_chunk=0.1, min_run_tiles=1)   # many runs
    backwards = {name: RasterizeBackward(ctx) for name, ctx in (
        ("subgroups", renderer.context), ("twin", StageContext(rt, SHAPES["gpu"])),
        ("subgroups in runs", StageContext(rt, runs)))}
    got = {name: rt.to_host(backward(res, dL_dimage, bg, layout, geometry), (len(model), layout.width))
           for name, backward in backwards.items()}
    # built with subgroups (no fallback to the twin, which would make the comparison vacuous)
    assert [b.subgroups for b in backwards.values()] == [rt.caps.subgroups, None, rt.caps.subgroups]
    assert np.count_nonzero(layout.views(got["twin"])["split"]) > 1000
    assert np.array_equal(got["subgroups"].view(np.uint32), got["twin"].view(np.uint32))
    assert np.array_equal(got["subgroups in runs"].view(np.uint32), got["twin"].view(np.uint32))


def spanning_runs(rt, res, tuning, n: int, width: int) -> tuple[int, int, np.ndarray]:
    """From the isect arrays: how many Gaussians have pairs in more than one of the frame's runs (pair_runs, slots
    of `width` sums), the runs, and each Gaussian's first and last run as run_spans keeps them (0, 0 for one with no
    pair)."""
    runs, per_run = pair_runs(res.isect.n_pairs, n, res.tiles_x * res.tiles_y, tuning, width)
    touched = rt.to_host(res.proj.tiles_touched, n, np.uint32).astype(np.int64)
    first = rt.to_host(res.isect.pair_first, n, np.uint32).astype(np.int64)
    pair_of_emission = rt.to_host(res.isect.pair_of_emission, res.isect.n_pairs, np.uint32)
    some = touched > 0
    first_run, last_run = np.zeros(n, np.uint32), np.zeros(n, np.uint32)
    first_run[some] = pair_of_emission[first[some]] // per_run
    last_run[some] = pair_of_emission[first[some] + touched[some] - 1] // per_run
    return int((first_run != last_run).sum()), runs, first_run << 16 | last_run


@pytest.mark.parametrize("base", ["3dgs", "absgs", "pixelgs"])
@pytest.mark.parametrize("pooling", ["view", "window"])
def test_sum_pairs_folds_the_window_as_the_window_kernel_does(rt, rng, base, pooling):
    """sum_pairs folds a view's statistics into the window (window_fold.h) and only its gradients reach memory,
    for a frame walked in one run and in runs (a Gaussian whose pairs span runs carries its partial sums from run
    to run; run_spans' record of each one's runs and its count of them against the host's). Over two views (the
    second adds to a window holding the first), both give the same window and gradients, bit for bit, as the full
    sums folded by the window's own kernel."""
    from dc4gs_cl.densify import STRATEGIES
    from dc4gs_cl.statistics import GRADIENTS
    model = random_model(rng, 700, spread=1.0, scale_range=(0.01, 0.12))
    g = DeviceGaussians(rt, model)
    bg = rng.uniform(0, 1, 3)
    paths = {"fused": SHAPES["cpu"],
             "runs": replace(SHAPES["cpu"], pair_chunk=0.1, min_run_tiles=1, max_folded_runs=10 ** 6),
             "window kernel": SHAPES["cpu"]}
    renderers = {name: Renderer(rt, tuning, poison=True) for name, tuning in paths.items()}
    backwards = {name: RasterizeBackward(r.context) for name, r in renderers.items()}
    strategies = {name: STRATEGIES[base](dc4gs=DC4GSConfig(dcc=True, dcs=True, pooling=pooling)) for name in paths}
    for name, s in strategies.items():
        s.attach(renderers[name].context, 1.0, len(model))
    for _ in range(2):
        cam = random_camera(rng, int(rng.integers(80, 130)), int(rng.integers(60, 100)))
        dL_dimage = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
        grads = {}
        for name in paths:
            res = renderers[name].render(g, cam, 3, bg)
            gathering = strategies[name].gather(1, g, cam, res)
            args = (res, rt.to_device(dL_dimage), bg, gathering.layout, gathering.geometry)
            if name == "window kernel":
                sums, layout = backwards[name](*args), gathering.layout
                backwards[name].densify_stats(res, sums, gathering.geometry, gathering.window)
            else:
                sums, layout = backwards[name].folding(*args, window=gathering.window)
            assert layout == (GRADIENTS if name != "window kernel" else gathering.layout)
            if name == "runs":                   # a row for each Gaussian spanning runs, each taken once
                ctx = renderers[name].context
                carried = rt.to_host(ctx.ws.get(CARRY_TAKEN, 4), 1, np.uint32)[0]
                spanning, runs, spans = spanning_runs(rt, res, paths["runs"], len(model),
                                                      gathering.layout.width)
                assert carried == spanning == ctx.frame_counts()["SPANNING"] > 10 and runs >= 4
                assert ctx.ws.get(CARRY_ROWS, 4).size >= 4 * gathering.layout.width * spanning
                assert np.array_equal(rt.to_host(ctx.ws.get(RUN_SPANS, 4), len(model), np.uint32), spans)
            grads[name] = rt.to_host(sums, (len(model), layout.width))[:, :GRADIENTS.width]
        assert np.isfinite(grads["fused"]).all() and np.count_nonzero(grads["fused"]) > 1000
        assert np.array_equal(grads["fused"], grads["window kernel"]) and np.array_equal(grads["runs"], grads["fused"])
    windows = {name: s.window.download() for name, s in strategies.items()}
    assert np.count_nonzero(windows["fused"][SPLIT_COSTS]) > 50
    for column, expected in windows["window kernel"].items():
        assert np.array_equal(windows["fused"][column], expected), column
        assert np.array_equal(windows["runs"][column], expected), column


def test_pair_runs_hold_the_bound_within_the_budget(rng):
    """A view's pairs (its room for them: the bound) in runs of consecutive pairs: one run unless the bound tops the
    budget (the slots of the width that the frame's pair temporaries hold, or fewer: pair_chunk per Gaussian) in a
    frame of at least 2 min_run_tiles tiles; then runs of at least the budget, as few as cover the bound,
    and at most one per min_run_tiles tiles."""
    for _ in range(500):
        n, tiles = int(rng.integers(1, 5000)), int(rng.integers(1, 4000))
        bound, width = int(rng.integers(0, 40 * n)), int(rng.choice([9, 12, 15, 40, 90]))
        chunk = [None, 0.1, 1.0, 2.5][int(rng.integers(4))]
        tuning = replace(SHAPES["cpu"], pair_chunk=chunk, min_run_tiles=int(rng.choice([1, 16, 256])))
        runs, per_run = pair_runs(bound, n, tiles, tuning, width)
        room = len(PAIR_TEMPORARIES) * bound // width
        budget = max(room if chunk is None else min(int(np.ceil(chunk * n)), room), 1)
        if bound <= budget or tiles < 2 * tuning.min_run_tiles:
            assert (runs, per_run) == (1, max(bound, 1))
            continue
        assert per_run >= budget and (runs - 1) * per_run < bound <= runs * per_run
        assert 2 <= runs <= tiles // tuning.min_run_tiles
        assert per_run == budget or per_run - 1 < bound / (tiles // tuning.min_run_tiles) <= per_run
        # the slots fit in the room of the pair temporaries unless the tiles cap the runs
        assert per_run * width <= max(len(PAIR_TEMPORARIES) * bound, width) or per_run > budget
    assert pair_runs(10 ** 6, 1000, 10 ** 4, replace(SHAPES["cpu"], pair_sums=False), 40) == (1, 10 ** 6)


def one_view_window(rt, model, cam, target, background, strategy):
    """The window statistics of one view for a hand-built model, through the strategy's hooks (the device
    path training takes)."""
    from dc4gs_cl.backward.loss import Loss
    from dc4gs_cl.render.workspace import POISON
    renderer = Renderer(rt, poison=True)
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 0, background)
    grad = rt.to_device(np.full(target.size, POISON, np.uint32))
    Loss(renderer.context)(res.raster.image, rt.to_device(target.astype(np.float32)), cam.width, cam.height, grad)
    strategy.attach(renderer.context, 1.0, len(model))
    gathering = strategy.gather(1, g, cam, res)
    backward = RasterizeBackward(renderer.context)
    sums = backward(res, grad, background, gathering.layout, gathering.geometry)
    backward.densify_stats(res, sums, gathering.geometry, gathering.window)
    return strategy.window.download(), gathering.layout.views(rt.to_host(sums, (len(model), gathering.layout.width)))


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
    from dc4gs_cl.densify.dc4gs import split_positions
    cam, model, to_sh = flat_scene(1)
    sigma = 0.5
    model.log_scales[0] = np.log([sigma, 0.05, 0.25])          # long along x: the principal axis
    model.sh[0, 0] = to_sh([0.5, 0.5, 0.5])
    boundary = 0.35                                             # normalised position along the diameter
    target = two_objects(cam, sigma, boundary, cam.fx * 0.25 / 4.0)
    strategy = AbsGS(dc4gs=DC4GSConfig(dcc=True, dcs=True))
    stats, _ = one_view_window(rt, model, cam, target, np.zeros(3, np.float32), strategy)
    for pick in ("poly", "argmin"):                              # measured: 0.317 and 0.333
        x = split_positions(stats[SPLIT_COSTS], pick)[0]
        assert abs(x - boundary) < 0.08, (pick, x, stats[SPLIT_COSTS])
    assert split_positions(stats[SPLIT_COSTS], "poly")[0] != 0.5      # the costs did decide


def test_directional_consistency_tells_a_shift_from_two_objects(rt):
    """Two Gaussians of one view: A's target is A itself shifted (its pixels agree: move), B covers two
    objects (its pixels disagree: split). DCC weights B's gradient by far more than A's."""
    from dc4gs_cl.model import GaussianModel
    from dc4gs_cl.statistics import ABS_PER_VIEW
    cam, model, to_sh = flat_scene(2)
    sigma = 0.35
    model.log_scales[:] = np.log([sigma, 0.05, 0.2])
    model.means[:, 0] = [-1.3, 1.3]
    model.sh[:, 0] = to_sh(np.array([[0.7, 0.7, 0.7], [0.5, 0.5, 0.5]]))
    shifted_a = GaussianModel(model.means[:1] + [0.3 * sigma, 0, 0], model.log_scales[:1], model.quats[:1],
                              model.opacity_logits[:1], model.sh[:1])
    target = Renderer(rt).render(DeviceGaussians(rt, shifted_a), cam, 0, np.zeros(3, np.float32)).image(rt)
    target = target + np.roll(two_objects(cam, sigma, 0.5, cam.fx * 0.2 / 4.0), int(pixel_x(cam, 1.3) - cam.cx), axis=1)
    strategy = AbsGS(dc4gs=DC4GSConfig(dcc=True))
    stats, sums = one_view_window(rt, model, cam, target, np.zeros(3, np.float32), strategy)
    kappa = np.linalg.norm(sums["dc"][:, :2], axis=1) / sums["dc"][:, 2]
    assert kappa[0] > 0.5 and kappa[1] < 0.3, kappa             # measured: 0.59 and 0.17
    weight = strategy.split_criterion(stats) / ABS_PER_VIEW(stats)
    np.testing.assert_allclose(weight, 1 - kappa, rtol=1e-5)    # one view: DCC = (1 - kappa) |ghat|
    assert weight[1] > 1.4 * weight[0]


def fake_view(rt, radius, depth, width, height):
    """What the window's fold (backward.DensifyStats) reads of a render result, for hand-made per-view sums."""
    from types import SimpleNamespace
    return SimpleNamespace(width=width, height=height, proj=SimpleNamespace(
        n=len(radius), radius=rt.to_device(radius.astype(np.int32)), depth=rt.to_device(depth.astype(np.float32))))


@pytest.mark.parametrize("pooling", ["view", "window"])
@pytest.mark.parametrize("track", [0.0, 1.2])   # absolute thresholds: |ghat| per view is about 1.25 here
def test_densify_stats_kernel_matches_reference(rt, rng, pooling, track):
    """Random per-view sums folded by the device (kernels/densify_stats.cl) against the float64 reference of the
    spec (reference/densify_stats.py), view after view, every column of the window."""
    from dc4gs_cl.backward import DensifyStats
    from dc4gs_cl.densify.window import Window
    from dc4gs_cl.reference.densify_stats import fold_view_reference
    from dc4gs_cl.render.stage import StageContext
    from dc4gs_cl.statistics import ABS_PER_VIEW, PIXELGS_DEPTH_FRACTION, StatisticsSpec
    n, views, candidates, extent, width, height = 300, 7, 5, 3.0, 120, 80
    spec = StatisticsSpec(dc=True, split_candidates=candidates, window_pooling=pooling == "window",
                          tracked=ABS_PER_VIEW)
    layout, geo_record = spec.sums, geometry_record(candidates)
    stats, fold = Window(rt, spec, extent, track_threshold=track), DensifyStats(StageContext(rt, poison=True))
    stats.reset(n)
    want = {k: np.zeros((n, w)).squeeze(1) if w == 1 else np.zeros((n, w)) for k, w in spec.window.widths().items()}
    for _ in range(views):
        sums = rng.normal(size=(n, layout.width)).astype(np.float32)
        v = layout.views(sums)
        count = rng.integers(0, 40, n).astype(np.float32)
        count[rng.random(n) < 0.1] = 0                                  # some see no pixel
        v["dc"][:, 2] = count
        v["pixels"][:] = count + rng.integers(0, 5, n)
        total = np.concatenate([v["dc"], v["abs"]], 1)                  # left sums within the totals
        v["split"][:] = (rng.uniform(0, 1, (n, candidates, 5)) * total[:, None, :]).reshape(n, -1)
        radius = rng.integers(0, 3, n) * rng.integers(1, 30, n)
        depth = rng.uniform(0.5, 3.0, n)
        geometry = np.zeros((n, geo_record.width), np.float32)
        line = rng.random(n) < 0.8
        geometry[line, geo_record.offsets["dir"]] = 1.0
        fold(fake_view(rt, radius, depth, width, height), rt.to_device(sums), rt.to_device(geometry), stats.fold)
        want = fold_view_reference(want, v, radius, depth, line, width, height, PIXELGS_DEPTH_FRACTION * extent,
                                   pooling == "window", track, (ABS_PER_VIEW.total, ABS_PER_VIEW.count))
    got = stats.download()
    assert set(got) == set(want)
    for key in want:
        np.testing.assert_allclose(got[key], want[key], rtol=2e-4, atol=1e-4, err_msg=key)
    if track:
        assert 0 < got["skip_split"].mean() < 1                           # the draw tracks some and skips some


def test_poly_split_position_is_the_exact_minimum_of_the_interpolating_quartic(rng):
    from dc4gs_cl.densify.dc4gs import interpolating_polynomials, split_positions
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
    from dc4gs_cl.densify.dc4gs import split_positions
    candidates = np.arange(1, 6) / 6
    ends = np.array([1 / 12 + 1e-4, 11 / 12 - 1e-4])
    costs = (candidates[None, :] - ends[:, None]) ** 2 + 0.3          # parabolas: the quartic through them
    np.testing.assert_allclose(split_positions(costs, "poly"), ends, atol=1e-9)


def test_argmin_dense_and_constant_costs():
    from dc4gs_cl.densify.dc4gs import split_positions
    costs = np.array([[3.0, 1.0, 2.0, 5.0, 4.0], [0.0] * 5, [2.0] * 5, [1.0, np.nan, 1.0, 1.0, 1.0]])
    np.testing.assert_allclose(split_positions(costs, "argmin"), [2 / 6, 0.5, 0.5, 0.5])
    dense = np.abs(np.linspace(0, 1, 61)[1:-1] - 0.7)[None]       # 59 candidates, minimum nearest 0.7
    assert abs(split_positions(dense, "dense")[0] - 0.7) < 1 / 60
    np.testing.assert_allclose(split_positions(costs[1:3], "poly"), 0.5)


@pytest.mark.parametrize("shrink_others", [False, True])
def test_dc_guided_split_children(rng, shrink_others):
    """Children per the spec (section 5); with --dcs-other-scale F (drawn here) the other two axes are the
    parent's times F, the rest unchanged."""
    from dc4gs_cl.densify.ops import split_at
    from dc4gs_cl.geometry import quat_to_rotmat
    from dc4gs_cl.model import GaussianSet
    n = 3
    q = rng.normal(size=(n, 4))
    params = {"means": rng.normal(size=(n, 3)),
              "log_scales": np.log([[0.2, 0.5, 0.1], [0.3, 0.3, 0.3], [0.1, 0.1, 0.4]]),
              "quats": q, "opacity_logits": np.array([[0.4], [1.0], [-0.5]]), "sh": rng.normal(size=(n, 12))}
    params = {k: v.astype(np.float32) for k, v in params.items()}
    gs = GaussianSet(dict(params), {k: np.ones_like(v) for k, v in params.items()},
                     {k: np.ones_like(v) for k, v in params.items()})
    x = np.array([0.3, 0.6])
    other_scale = rng.uniform(0.3, 0.9) if shrink_others else 1.0
    assert split_at(gs, np.array([0, 1]), x, other_scale) == 2
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
            want = s * other_scale
            want[axis] = sigma * fraction
            np.testing.assert_allclose(np.exp(gs.params["log_scales"][child]), want, rtol=1e-5)
            o = 1 / (1 + np.exp(-params["opacity_logits"][parent, 0]))
            np.testing.assert_allclose(1 / (1 + np.exp(-gs.params["opacity_logits"][child, 0])),
                                       o * fraction, rtol=1e-5)
            np.testing.assert_array_equal(gs.params["quats"][child], params["quats"][parent])
            np.testing.assert_array_equal(gs.params["sh"][child], params["sh"][parent])
            for moments in (gs.m, gs.v):
                assert all(np.all(moments[k][child] == 0) for k in moments)


def test_noise_sized_costs_split_in_the_middle(rng):
    from dc4gs_cl.densify.dc4gs import split_positions
    noise = rng.normal(0, 1e-16, (4, 5))         # vanishing gradients leave only rounding noise
    np.testing.assert_array_equal(split_positions(np.abs(noise), "poly"), 0.5)


def test_split_costs_stop_for_gaussians_whose_criterion_stays_low(rt, rng):
    """With tracking, a Gaussian whose running split criterion stays under track x threshold after its
    first views gets no split line (no costs); one above it keeps its line."""
    from dc4gs_cl.backward import DensifyStats
    from dc4gs_cl.densify.window import Window
    from dc4gs_cl.statistics import ABS_PER_VIEW, SKIP_SPLIT, TRACK_MIN_VIEWS, StatisticsSpec
    n, candidates = 4, 5
    spec = StatisticsSpec(dc=True, split_candidates=candidates, tracked=ABS_PER_VIEW)
    renderer = Renderer(rt, poison=True)
    window, fold = Window(rt, spec, 1.0, track_threshold=1.0), DensifyStats(renderer.context)
    window.reset(n)
    sums = np.zeros((n, spec.sums.width), np.float32)
    spec.sums.views(sums)["abs"][:, 0] = [0.1, 5.0, 0.1, 5.0]          # per-view |ghat| below / above 1
    view = fake_view(rt, np.full(n, 3), np.ones(n), 10, 10)
    no_lines = rt.to_device(np.zeros((n, geometry_record(candidates).width), np.float32))
    for seen in range(TRACK_MIN_VIEWS + 1):
        assert np.array_equal(window.download()[SKIP_SPLIT], [0, 0, 0, 0] if seen < TRACK_MIN_VIEWS else [1, 0, 1, 0])
        fold(view, rt.to_device(sums), no_lines, window.fold)

    # split_geometry then gives the skipped Gaussians no line, and the others theirs
    cam, model, _ = flat_scene(n)
    model.means[:, 0] = [-1.5, -0.5, 0.5, 1.5]
    model.log_scales[:] = np.log([0.3, 0.05, 0.1])     # longest along world x = image x
    g = DeviceGaussians(rt, model)
    res = renderer.render(g, cam, 0)
    assert (rt.to_host(res.proj.radius, n, np.int32) > 0).all()
    geometry = SplitGeometry(renderer.context)(g, cam, res, candidates, window=window.fold)
    geo = geometry_record(candidates).views(rt.to_host(geometry, (n, geometry_record(candidates).width)))
    np.testing.assert_array_equal(np.abs(geo["dir"]).sum(1) > 0, [False, True, False, True])


def test_views_that_dcs_skips_leave_the_split_costs_alone(rt):
    """--dcs-every K (an approximation): the split costs are the sum of what the exact run's every K-th iteration
    adds to them; every other statistic, and the parameters, are the exact run's."""
    from dc4gs_cl.apps.bench import frozen_trainer
    from dc4gs_cl.config import TrainConfig
    from dc4gs_cl.scene.builtin import builtin_scene
    from dc4gs_cl.train import Trainer
    scene = builtin_scene(resolution=4)
    warm = Trainer(TrainConfig(scene="builtin", iterations=600), scene, rt)
    for _ in range(40):
        warm.step()
    state, every, steps = warm.model.download(), 3, 7

    def run(cost_every):
        cfg = TrainConfig(scene="builtin", iterations=600, strategy="absgs",
                          dc4gs=DC4GSConfig(dcc=True, dcs=True, cost_every=cost_every))
        trainer = frozen_trainer(cfg, scene, rt, state, 100)
        added = {}                                   # iteration -> what its view added to the split costs
        for _ in range(steps):
            before = trainer.strategy.window.download()[SPLIT_COSTS].astype(np.float64)
            trainer.step()
            added[trainer.iteration] = trainer.strategy.window.download()[SPLIT_COSTS] - before
        return trainer.model.download().params, trainer.strategy.window.download(), added

    exact_params, exact, added = run(1)
    got_params, got, skipped = run(every)
    sampled = [it for it in added if it % every == 0]
    assert 0 < len(sampled) < steps
    assert all(np.abs(added[it]).max() > 0 for it in added)              # every view adds costs in the exact run
    assert all(np.abs(skipped[it]).max() == 0 for it in skipped if it % every)
    # each view's addition is read back as a difference of float32 running sums: exact to their rounding
    want = sum(added[it] for it in sampled)
    rounding = 1e-6 * np.abs(exact[SPLIT_COSTS]).max(axis=1, keepdims=True)
    assert np.all(np.abs(got[SPLIT_COSTS] - want) <= 1e-5 * np.abs(want) + rounding)
    for name in exact:
        if name != SPLIT_COSTS:
            np.testing.assert_array_equal(got[name], exact[name], err_msg=name)
    for name in exact_params:
        np.testing.assert_array_equal(got_params[name], exact_params[name], err_msg=name)
