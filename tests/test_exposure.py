"""train --exposure (backward/exposure.py, kernels/exposure.cl): the 3x4 affine correction per photo and its gradients
against a float64 reference (itself checked by finite differences), its Adam step and anchor; in training:
bit-reproducible, resumed bit for bit, the mean correction the identity, nothing of it in the model, three launches
and no blocking sync more an iteration; and the corrected metrics' protocol on a view whose answer is known."""
import json
from pathlib import Path

import numpy as np
import pytest
from helpers import random_camera, random_model, straight_and_resumed

from dc4gs_cl.backward.exposure import IDENTITY, PARAMS, PLAIN_COORDS, VARIANCE_FLOOR, Exposure, colour_coordinates
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.optim.adam import one_group_step
from dc4gs_cl.reference import exposure as ref
from dc4gs_cl.render.stage import StageContext

SHAPES = {"cpu": {"WG": 1, "PER_ITEM": 2048}, "gpu": {"WG": 256, "PER_ITEM": 16}, "mid": {"WG": 4, "PER_ITEM": 7}}


def rel_l2(got, want) -> float:
    assert np.isfinite(got).all()   # NaN never passes
    return float(np.linalg.norm(np.asarray(got, np.float64) - want) / np.linalg.norm(want))


def random_state(rng, photos: int) -> dict:
    return {"T": (IDENTITY + rng.normal(0, 0.2, (photos, PARAMS))).astype(np.float32),
            "m": rng.normal(0, 1e-3, (photos, PARAMS)).astype(np.float32),
            "v": rng.uniform(0, 1e-5, (photos, PARAMS)).astype(np.float32)}


def test_reference_gradients_match_finite_differences(rng):
    """dL/dT and dL/dx of L(A x + b) = sum(c out^2 / 2 + d out) over the kept pixels (float64 central differences)."""
    T, x = IDENTITY + rng.normal(0, 0.3, PARAMS), rng.uniform(0, 1, (7, 5, 3))
    c, d, keep = rng.uniform(0.5, 2, x.shape), rng.normal(0, 1, x.shape), rng.random((7, 5)) > 0.3

    def loss(T, x):
        out = ref.apply(T, x)
        return float(np.sum((c * out ** 2 / 2 + d * out) * keep[..., None]))
    dT, dx = ref.backward(T, x, c * ref.apply(T, x) + d, keep)
    step = 1e-6

    def central(f, a):
        fd = np.empty_like(a)
        for i in np.ndindex(a.shape):
            ap, am = a.copy(), a.copy()
            ap[i] += step
            am[i] -= step
            fd[i] = (f(ap) - f(am)) / (2 * step)
        return fd
    assert rel_l2(dT, central(lambda t: loss(t, x), T)) < 1e-7
    assert rel_l2(dx.reshape(x.shape), central(lambda y: loss(T, y), x)) < 1e-7
    assert not dx.reshape(x.shape)[~keep].any()


def correlated_photo(rng, h: int, w: int) -> np.ndarray:
    """Colours whose channels move together, as a photo's: a grey level plus a little of a colour each pixel."""
    grey = rng.uniform(0.1, 0.9, (h, w, 1))
    return np.clip(grey + rng.normal(0, 0.05, (h, w, 3)) + rng.normal(0, 0.05, 3), 0, 1).astype(np.float32)


def test_coordinates_gradient_matches_finite_differences(rng):
    """dL/dP in the colour coordinates (ref.coords_gradient from dL/dT) against central differences of L(T(P)), and
    T(P) the identity at the anchor's P = [W^-1 | mu]."""
    coords = colour_coordinates([(correlated_photo(rng, 6, 7), None)])
    W, mu = coords[:9].reshape(3, 3).astype(np.float64), coords[9:].astype(np.float64)
    x, c, d = rng.uniform(0, 1, (20, 3)), rng.uniform(0.5, 2, (20, 3)), rng.normal(0, 1, (20, 3))

    def loss(P):
        out = ref.apply(ref.from_coords(P, coords)[0], x)
        return float(np.sum(c * out ** 2 / 2 + d * out))
    anchor = np.concatenate([np.linalg.inv(W), mu[:, None]], axis=1).reshape(12)
    assert np.abs(ref.from_coords(anchor, coords)[0] - IDENTITY).max() < 1e-12
    P = anchor + rng.normal(0, 0.2, 12)
    T = ref.from_coords(P, coords)[0]
    want = ref.coords_gradient(ref.backward(T, x, c * ref.apply(T, x) + d)[0], coords)
    fd = np.empty(12)
    for i in range(12):
        e = np.zeros(12)
        e[i] = 1e-6
        fd[i] = (loss(P + e) - loss(P - e)) / 2e-6
    assert rel_l2(want, fd) < 1e-7


def test_colour_coordinates_whiten_the_kept_pixels(rng):
    """mu is the kept pixels' mean colour and W whitens their covariance, scaled to a mean variance of 1, along each
    of its directions with at least VARIANCE_FLOOR of it, and scales those below by VARIANCE_FLOOR^(-1/2) (masked
    pixels, here garbage, count for nothing), so that grey photos (no colour variance) get finite coordinates whose
    gain is at most VARIANCE_FLOOR^(-1/2) (at the floor of 1: W never amplifies); a fixed order makes them the same
    every call."""
    photos = [correlated_photo(rng, 11, 13), correlated_photo(rng, 9, 8)]
    keep = rng.random((11, 13)) > 0.3
    garbage = photos[0].copy()
    garbage[~keep] = rng.uniform(5, 9, (int((~keep).sum()), 3))
    coords = colour_coordinates([(garbage, keep), (photos[1], None)])
    kept = np.concatenate([photos[0][keep], photos[1].reshape(-1, 3)]).astype(np.float64)
    W = coords[:9].reshape(3, 3).astype(np.float64)
    assert np.allclose(coords[9:], kept.mean(0), atol=1e-6)
    cov = np.cov(kept.T, bias=True)
    cov /= np.trace(cov) / 3
    w, U = np.linalg.eigh(cov)
    assert w.max() > 1.5 * VARIANCE_FLOOR and w.min() < VARIANCE_FLOOR   # both kinds of direction are tested
    assert np.allclose(W @ cov @ W.T, U @ np.diag(np.minimum(w / VARIANCE_FLOOR, 1)) @ U.T, atol=1e-4)
    assert np.linalg.norm(W, 2) <= VARIANCE_FLOOR ** -0.5 * (1 + 1e-5)
    assert np.array_equal(coords, colour_coordinates([(garbage, keep), (photos[1], None)]))
    grey = np.repeat(rng.uniform(0, 1, (10, 10, 1)), 3, axis=2)
    g = colour_coordinates([(grey, None)])
    assert np.isfinite(g).all() and np.linalg.norm(g[:9].reshape(3, 3), 2) <= VARIANCE_FLOOR ** -0.5 * (1 + 1e-5)
    assert np.array_equal(colour_coordinates([(np.full((4, 4, 3), 0.3, np.float32), None)])[:9], PLAIN_COORDS[:9])


@pytest.mark.parametrize("masked", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("coords", ["plain", "photos"])
def test_kernels_match_reference(rt, rng, shape, masked, coords):
    """The correction, dL/dT summed over the (kept) pixels, dL/dx = A^T g, then Adam on every photo (in T's own
    coordinates or in photos' colour coordinates) and the anchor, against the float64 reference, over two views;
    the outputs poisoned (NaN) before the kernels write them."""
    photos, h, w = 5, int(rng.integers(9, 60)), int(rng.integers(9, 60))
    coords = PLAIN_COORDS if coords == "plain" else colour_coordinates([(correlated_photo(rng, h, w), None)])
    ex = Exposure(StageContext(rt, poison=True), photos, SHAPES[shape], coords)
    state = random_state(rng, photos)
    ex.upload(state)
    want = {k: a.astype(np.float64) for k, a in state.items()}
    for t, view in enumerate(rng.choice(photos, 2, replace=False), start=1):
        x, g = rng.uniform(-0.1, 1.1, (h * w, 3)).astype(np.float32), rng.normal(0, 1e-4, (h * w, 3)).astype(np.float32)
        keep = rng.random(h * w) > 0.4 if masked else None
        x_buf, g_buf = rt.to_device(x), rt.to_device(g)
        rt.write(ex.grad, np.full(PARAMS, np.nan, np.float32))
        out = rt.to_host(ex.apply(x_buf, view, h * w), (h * w, 3))
        assert rel_l2(out, ref.apply(ex_T := want["T"][view], x)) < 1e-6
        lr = float(rng.uniform(1e-3, 1e-2))
        ex.backward(x_buf, g_buf, view, h * w, one_group_step(lr, t),
                    rt.to_device(keep.astype(np.uint8)) if masked else None)
        dT, dx = ref.backward(ex_T, x, g, keep)
        assert rel_l2(rt.to_host(ex.grad, PARAMS), dT) < 1e-5
        got_dx = rt.to_host(g_buf, (h * w, 3))
        assert rel_l2(got_dx, dx) < 1e-6 and (not masked or not got_dx[~keep].any())
        want["T"], want["m"], want["v"] = ref.adam_anchor(want["T"], want["m"], want["v"], view, dT, lr, t, coords)
        got = ex.download()
        for k in ("T", "m", "v"):
            assert rel_l2(got[k], want[k]) < 1e-5, k
        assert np.abs(got["T"].mean(0) - IDENTITY).max() < 1e-6   # the anchor: their mean is the identity


def test_no_step_and_a_void_frame(rt, rng):
    """Without an optimiser step (t = 0) the gradient is computed and no correction moves; on a void frame (a view
    that overflowed, to run again) nothing changes at all, and the next view goes on as if it had not been."""
    photos, pixels = 3, 500
    ctx = StageContext(rt, poison=True)
    ex = Exposure(ctx, photos, SHAPES["mid"])
    state = random_state(rng, photos)
    ex.upload(state)
    x = rt.to_device(rng.uniform(0, 1, (pixels, 3)).astype(np.float32))
    g0 = rng.normal(0, 1e-3, (pixels, 3)).astype(np.float32)
    g = rt.to_device(g0)
    ex.backward(x, g, 1, pixels, one_group_step(0.01, 0))
    assert all(np.array_equal(a, state[k]) for k, a in ex.download().items())
    assert np.isfinite(rt.to_host(ex.grad, PARAMS)).all()
    from dc4gs_cl.constants import FRAME_WORDS
    void = np.zeros(len(FRAME_WORDS), np.uint32)
    void[FRAME_WORDS.index("OVERFLOWED")] = 1
    rt.write(ctx.frame, void)
    g = rt.to_device(g0)
    ex.backward(x, g, 1, pixels, one_group_step(0.01, 1))
    assert np.array_equal(rt.to_host(g, (pixels, 3)), g0)
    assert all(np.array_equal(a, state[k]) for k, a in ex.download().items())
    rt.write(ctx.frame, np.zeros(len(FRAME_WORDS), np.uint32))
    ex.backward(x, g, 1, pixels, one_group_step(0.01, 1))
    assert not np.array_equal(ex.download()["T"], state["T"])   # the count of finished groups was left at 0


def train(tmp_path, name, *args) -> Path:
    from dc4gs_cl.cli import main
    out = tmp_path / name
    assert main(["train", "--out", str(out), "-r", "4", "--iterations", "60", "--no-progress", "--lpips", "none",
                 "--test-every", "8", *args]) == 0
    return out


def ply_properties(path) -> list[bytes]:
    """The PLY header's lines but the vertex count."""
    data = path.read_bytes()
    return [line for line in data[:data.index(b"end_header")].split(b"\n") if not line.startswith(b"element")]


def test_training_with_exposure_is_reproducible_anchored_and_kept_out_of_the_model(tmp_path):
    """Two runs of one seed give the same bytes (model and corrections); the corrections moved, their mean over the
    photos is the identity; the model is the same kind of PLY as without --exposure, and holds none of it."""
    a, b = train(tmp_path, "a", "--exposure"), train(tmp_path, "b", "--exposure")
    plain = train(tmp_path, "plain")
    ply = "point_cloud/iteration_60/point_cloud.ply"
    assert (a / ply).read_bytes() == (b / ply).read_bytes()
    assert (a / "exposure.json").read_bytes() == (b / "exposure.json").read_bytes()
    from dc4gs_cl.run_folder import RunFolder
    saved = RunFolder(a).read_exposure()
    T = np.array(list(saved.values()))
    assert json.loads((a / "exposure.json").read_text())["iteration"] == 60
    assert T.shape == (len(saved), 3, 4) and len(saved) > 20
    assert np.abs(T.mean(0) - np.eye(3, 4)).max() < 1e-5 and np.abs(T - np.eye(3, 4)).max() > 1e-3
    assert ply_properties(a / ply) == ply_properties(plain / ply)   # same properties, same kind of model
    assert (a / ply).read_bytes() != (plain / ply).read_bytes()   # (the corrections changed what it learnt)
    assert not (plain / "exposure.json").exists()
    assert [p.name for p in (a / "point_cloud/iteration_60").iterdir()] == ["point_cloud.ply"]



def test_eval_labels_its_corrected_metrics(tmp_path, capsys):
    """eval --corrected-metrics: results.json holds the corrected means beside the raw ones, the output says so;
    train's results are raw alone by default; train --corrected-metrics puts them in metrics.jsonl and report."""
    from dc4gs_cl.cli import main
    run = train(tmp_path, "run", "--exposure")
    raw = json.loads((run / "results.json").read_text())["ours_60"]
    assert "PSNR corrected" not in raw
    capsys.readouterr()
    assert main(["eval", "--model", str(run), "--corrected-metrics", "--no-renders", "--lpips", "none"]) == 0
    out = capsys.readouterr().out
    result = json.loads((run / "results.json").read_text())["ours_60"]
    assert result["PSNR"] == raw["PSNR"] and np.isfinite(result["PSNR corrected"]) and "SSIM corrected" in result
    assert "corrected (a colour correction fitted on each view's left half" in out and "corrected PSNR" in out
    from dc4gs_cl.apps.report import RunMetrics, summary_html
    train(tmp_path, "corrected", "--exposure", "--corrected-metrics")
    from dc4gs_cl.run_folder import RunFolder
    rows = [r for r in RunFolder(tmp_path / "corrected").read_metrics() if "test_psnr" in r]
    assert rows and all(np.isfinite(r["test_psnr_corrected"]) for r in rows)   # each evaluation's, in metrics.jsonl
    assert "test PSNR, corrected" in summary_html([RunMetrics.read(tmp_path / "corrected")])
    assert "corrected" not in summary_html([RunMetrics.read(run)])


def test_a_run_with_exposure_resumes_bit_for_bit(rt, tmp_path):
    from dc4gs_cl.scene.loader import load_scene
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", iterations=80, resolution=4, exposure=True)
    straight, resumed = straight_and_resumed(cfg, scene, rt, tmp_path, 37)
    a, b = straight.model.download(), resumed.model.download()
    assert all(np.array_equal(a.params[k], b.params[k]) and np.array_equal(a.m[k], b.m[k]) for k in a.params)
    ea, eb = straight.exposure.download(), resumed.exposure.download()
    assert all(np.array_equal(ea[k], eb[k]) for k in ea)
    # a step where the Gaussians' means step (none on a densification iteration): their count resumed too
    assert straight.model.adam.steps["means"] == resumed.model.adam.steps["means"] > 40


def test_exposure_adds_three_launches_and_no_blocking_sync(rt):
    """The same state and views stepped with and without --exposure: exactly 3 launches more a view
    (exposure_apply, exposure_backward, exposure_step), not one sync more."""
    from dc4gs_cl.apps.bench import frozen_trainer
    from dc4gs_cl.scene.loader import load_scene
    from dc4gs_cl.train import Trainer
    scene = load_scene("builtin", resolution=4)
    state = Trainer(TrainConfig(scene="builtin", iterations=100, resolution=4), scene, rt).model.download()
    counts = []
    for exposure in (False, True):
        trainer = frozen_trainer(TrainConfig(scene="builtin", iterations=100, resolution=4, exposure=exposure), scene,
                                 rt, state, 50)
        for _ in scene.train:   # kernels built, buffers sized for every view
            trainer.step()
        launches, syncs = rt.launches, rt.syncs
        for _ in scene.train:
            trainer.step()
        counts.append((rt.launches - launches, rt.syncs - syncs))
    (plain_launches, plain_syncs), (launches, syncs) = counts
    assert launches == plain_launches + 3 * len(scene.train) and syncs == plain_syncs


def test_corrected_metrics_on_a_view_whose_colours_are_a_known_affine_of_the_render(rt, rng):
    """A test view whose image is a known affine of the model's render: its raw PSNR is low, its corrected PSNR
    (fitted on the left half, scored on the right) as high as float32 allows, and the fit is that affine."""
    from dc4gs_cl.evaluation.evaluate import CORRECTED, evaluate, summary
    from dc4gs_cl.evaluation.metrics import fit_affine
    from dc4gs_cl.render import DeviceGaussians, Renderer
    from dc4gs_cl.scene.camera import Scene
    cam = random_camera(rng, 64, 48)
    model = random_model(rng, 300, sh_degree=0)
    renderer = Renderer(rt)
    background = np.zeros(3, np.float32)
    gaussians = DeviceGaussians(rt, model)
    image = renderer.render(gaussians, cam, 0, background).image(rt).astype(np.float64)
    M = np.column_stack([np.diag(rng.uniform(0.7, 0.9, 3)) + rng.normal(0, 0.03, (3, 3)), rng.uniform(0.02, 0.08, 3)])
    target = np.clip(image, 0, 1) @ M[:, :3].T + M[:, 3]
    assert target.min() >= 0 and target.max() <= 1   # nothing clipped: the affine is the whole answer
    scene = Scene(root=".", train=[cam], test=[cam], points=None, colors=None, background=background,
                  read_image=lambda c: target.astype(np.float32))
    result = evaluate(rt, renderer, gaussians, scene, [cam], 0, corrected=True)
    mean = result["mean"]
    # raw: the offsets alone (at least 0.02 a channel) keep it under 34 dB where the render is black (30.4 seen)
    assert mean["PSNR"] < 40 and mean[f"PSNR{CORRECTED}"] > 55, mean
    assert mean[f"SSIM{CORRECTED}"] > 0.999 and "corrected" in summary(result)
    assert np.abs(fit_affine(image[:, :32], target[:, :32]) - M).max() < 1e-4
    assert f"PSNR{CORRECTED}" not in evaluate(rt, renderer, gaussians, scene, [cam], 0)["mean"]   # raw: the default


def test_exposure_with_a_batch_is_refused_in_one_line(tmp_path, capsys):
    from dc4gs_cl.cli import main
    assert main(["train", "--out", str(tmp_path / "o"), "-r", "8", "--exposure", "--batch", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--exposure needs --batch 1, one process" in err[0], err
    assert not (tmp_path / "o").exists()
