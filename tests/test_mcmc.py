"""MCMC densification: the counter-based normals against Random123's published answers and their distribution,
the position noise kernel against its float64 reference."""
import dataclasses

import numpy as np
import pytest

from dc4gs_cl.constants import MCMC_NOISE_K, MCMC_NOISE_X0
from dc4gs_cl.optim.position_noise import PositionNoise, seed_words
from dc4gs_cl.reference.mcmc import position_noise_reference, philox4x32_10, philox_normals
from dc4gs_cl.render import DeviceGaussians
from dc4gs_cl.render.stage import StageContext
from dc4gs_cl.reference.testing import random_model
from helpers import straight_and_resumed

# Random123's known-answer vectors for Philox4x32-10 (its kat_vectors file): counter, key -> words
PHILOX_KAT = [((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
              ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
              ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
               (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1))]


@pytest.mark.parametrize("counter,key,words", PHILOX_KAT)
def test_philox_gives_random123s_answers(counter, key, words):
    assert tuple(int(w) for w in philox4x32_10(np.array([counter], np.uint32), key)[0]) == words


def test_philox_normals_are_standard_normal():
    z = philox_normals(np.stack([np.arange(50_000), np.full(50_000, 7), np.zeros(50_000), np.zeros(50_000)],
                                axis=1).astype(np.uint32), seed_words(12345)).ravel()
    assert np.isfinite(z).all()
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1) < 0.01
    assert abs(np.mean(np.abs(z) < 1) - 0.6827) < 0.005   # the mass within one sigma


def test_noise_kernel_matches_reference(rt, rng):
    model = random_model(rng, 3000, sh_degree=0, spread=2.0)
    model.opacity_logits[:1000] = rng.uniform(-9, -4, 1000)    # nearly transparent: the gate open
    model.quats[:10] = 0.0                                      # zero quaternions: the identity rotation
    g = DeviceGaussians(rt, model)
    ctx = StageContext(rt, poison=True)
    seed, iteration, scaler = int(rng.integers(0, 2 ** 63)), int(rng.integers(0, 2 ** 31)), 5e5 * 1.6e-4
    PositionNoise(ctx)(g, iteration, seed, scaler)
    got = g.download_group("means")
    want = position_noise_reference(model.means, model.log_scales, model.quats, model.opacity_logits, iteration,
                                seed_words(seed), scaler, MCMC_NOISE_K, MCMC_NOISE_X0)
    moved = np.linalg.norm(want - model.means, axis=1)
    assert (moved[:1000] > 0).all() and np.median(moved[:1000]) > 1e3 * np.median(moved[1000:])
    assert np.isfinite(got).all()
    err = np.linalg.norm((got - model.means) - (want - model.means)) / np.linalg.norm(want - model.means)
    assert err < 1e-4, err
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_relocation_keeps_a_gaussians_profile_along_a_line(rng):
    """Equation (9): N Gaussians of the new opacity and scale, composited, integrate along a line through their
    centre to what the one they replace did (o sigma sqrt(2 pi)), and are as opaque at the centre."""
    from dc4gs_cl.densify.mcmc import relocated_opacity_scale
    o = rng.uniform(0.01, 0.99, 40)
    shares = rng.integers(1, 60, 40)                 # beyond MAX_SHARES: as MAX_SHARES
    sigma = rng.uniform(0.1, 3.0, (40, 3))
    new_o, new_sigma = relocated_opacity_scale(o, sigma, shares)
    n = np.minimum(shares, 51)
    np.testing.assert_allclose(1 - (1 - new_o) ** n, o, rtol=1e-12)
    x = np.linspace(-60, 60, 240_001)
    dx = x[1] - x[0]
    for i in range(40):
        profile = 1 - (1 - new_o[i] * np.exp(-x ** 2 / (2 * new_sigma[i, 0] ** 2))) ** n[i]
        assert profile.sum() * dx == pytest.approx(o[i] * sigma[i, 0] * np.sqrt(2 * np.pi), rel=1e-6), (o[i], n[i])
    np.testing.assert_allclose(new_sigma / sigma, (new_sigma / sigma)[:, :1] * np.ones(3))   # every axis alike
    one_o, one_sigma = relocated_opacity_scale(o, sigma, np.ones(40, int))
    np.testing.assert_allclose(one_o, o, rtol=1e-12) and np.testing.assert_allclose(one_sigma, sigma, rtol=1e-12)


def test_a_refinement_step_relocates_the_dead_and_grows_to_the_cap(rng):
    from dc4gs_cl.densify import DensifyConfig
    from dc4gs_cl.densify.mcmc import MCMC, relocated_opacity_scale
    from dc4gs_cl.model import GaussianSet
    model = random_model(rng, 1000, sh_degree=1, spread=1.0)
    model.opacity_logits[:100] = -8.0                       # dead: opacity below 0.005
    model.opacity_logits[100:] = rng.uniform(-3.0, 3.0, 900)   # the rest alive
    params = {k: np.asarray(getattr(model, k), np.float32).reshape(1000, -1)
              for k in ("means", "log_scales", "quats", "opacity_logits", "sh")}

    def fresh() -> GaussianSet:
        moments = lambda: {k: rng.normal(size=v.shape).astype(np.float32) for k, v in params.items()}   # noqa: E731
        return GaussianSet({k: v.copy() for k, v in params.items()}, moments(), moments())

    def mcmc(cap: int) -> MCMC:
        return MCMC(DensifyConfig(densify_from=0, densify_until=100, densify_every=10, prune_opacity=0.005,
                                  max_gaussians=cap))
    # at the cap already: relocation alone
    gs = fresh()
    report = mcmc(1000).densify(gs, {}, 10, np.random.default_rng(3))
    assert report.pruned == 100 and report.cloned == 0 and gs.n == 1000
    assert (gs.opacities() > 0.005 - 1e-9).all()
    sources = np.array([np.flatnonzero((params["means"][100:] == gs.params["means"][i]).all(axis=1))[0] + 100
                        for i in range(100)])
    for k in params:   # a dead slot holds a copy of the live Gaussian drawn for it
        np.testing.assert_array_equal(gs.params[k][:100], gs.params[k][sources])
    shares = np.bincount(sources, minlength=1000)[sources] + 1
    o, sigma = relocated_opacity_scale(1 / (1 + np.exp(-params["opacity_logits"][sources, 0].astype(np.float64))),
                                       np.exp(params["log_scales"][sources].astype(np.float64)), shares)
    np.testing.assert_allclose(gs.opacities()[sources], o, rtol=1e-6)
    np.testing.assert_allclose(gs.scales()[sources], sigma, rtol=1e-6)
    touched = np.union1d(np.arange(100), sources)
    untouched = np.setdiff1d(np.arange(1000), touched)
    for moments in (gs.m, gs.v):   # the copies and their sources restart Adam; the rest keep their (random) moments
        assert all((moments[k][touched] == 0).all() and (moments[k][untouched] != 0).all() for k in moments)
    # growth by 5%, up to the cap: 1,050 wanted, 1,030 allowed
    gs = fresh()
    report = mcmc(1030).densify(gs, {}, 10, np.random.default_rng(3))
    assert report.pruned == 100 and report.cloned == 30 and gs.n == 1030
    for k in ("m", "v"):
        assert all((getattr(gs, k)[name][1000:] == 0).all() for name in params)
    gs2 = fresh()
    mcmc(1030).densify(gs2, {}, 10, np.random.default_rng(3))
    assert all(np.array_equal(gs.params[k], gs2.params[k]) for k in params)   # the run's generator decides


@pytest.mark.parametrize("pick", ["poly", "middle"])
def test_dcs_makes_a_gaussian_drawn_once_and_its_copy_dcs_children(rng, pick):
    """--strategy mcmc --dcs: a live Gaussian drawn once for a dead slot becomes, with its copy there, the two
    children DCS' split makes of it on the bases (ops.split_at, cut where its split costs are lowest, or in the
    middle with split_pick middle); one drawn more often shares by equation (9) and its slots hold copies, as
    without DCS."""
    from dc4gs_cl.config import DC4GSConfig
    from dc4gs_cl.densify import DensifyConfig
    from dc4gs_cl.densify import ops
    from dc4gs_cl.densify.mcmc import MCMC, relocated_opacity_scale
    from dc4gs_cl.model import GaussianSet
    from dc4gs_cl.statistics import SPLIT_COSTS
    n, dead = 600, np.arange(200)     # many dead: some live ones are drawn twice or more
    model = random_model(rng, n, sh_degree=1, spread=1.0)
    model.opacity_logits[dead] = -8.0
    model.opacity_logits[200:] = rng.uniform(-3.0, 3.0, n - 200)
    params = {k: np.asarray(getattr(model, k), np.float32).reshape(n, -1)
              for k in ("means", "log_scales", "quats", "opacity_logits", "sh")}
    zeros = lambda: {k: np.zeros_like(v) for k, v in params.items()}   # noqa: E731
    costs = rng.uniform(0.0, 1.0, (n, 5)) ** 3    # each Gaussian's own preferred cut
    strategy = MCMC(DensifyConfig(densify_from=0, densify_until=100, densify_every=10, prune_opacity=0.005,
                                  max_gaussians=n), DC4GSConfig(dcs=True, split_pick=pick))
    window = {SPLIT_COSTS: costs} if pick != "middle" else {}
    gs = GaussianSet({k: v.copy() for k, v in params.items()}, zeros(), zeros())
    assert strategy.densify(gs, window, 10, np.random.default_rng(5)).pruned == len(dead)

    # the live Gaussian each dead slot was drawn from: neither a share nor DCS changes rotation or colour
    sources = np.array([np.flatnonzero((params["quats"][200:] == gs.params["quats"][i]).all(axis=1))[0] + 200
                        for i in dead])
    drawn = np.bincount(sources, minlength=n)[sources]
    once, more = drawn == 1, drawn > 1
    assert once.sum() > 50 and more.sum() > 20
    cuts = strategy.dcs_cuts(window, sources[once])
    if pick == "middle":
        assert (cuts == 0.5).all()
    else:
        assert np.ptp(cuts) > 0.3                       # the costs placed the cuts, not the middle
    split = GaussianSet({k: v.copy() for k, v in params.items()}, zeros(), zeros())
    ops.split_at(split, sources[once], cuts)          # DCS on a base: the children, in pairs, at the end
    children = {k: v[n - once.sum():] for k, v in split.params.items()}
    for k in params:
        np.testing.assert_allclose(gs.params[k][sources[once]], children[k][0::2], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(gs.params[k][dead[once]], children[k][1::2], rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(gs.params[k][dead[more]], gs.params[k][sources[more]])
    o, sigma = relocated_opacity_scale(1 / (1 + np.exp(-params["opacity_logits"][sources[more], 0].astype(np.float64))),
                                       np.exp(params["log_scales"][sources[more]].astype(np.float64)), drawn[more] + 1)
    np.testing.assert_allclose(gs.opacities()[sources[more]], o, rtol=1e-6)
    np.testing.assert_allclose(gs.scales()[sources[more]], sigma, rtol=1e-6)
    # a pair's opacities add up to its parent's: DCS partitions the parent along its axis
    parent_opacity = 1 / (1 + np.exp(-params["opacity_logits"][sources[once], 0].astype(np.float64)))
    np.testing.assert_allclose(gs.opacities()[sources[once]] + gs.opacities()[dead[once]], parent_opacity, rtol=1e-5)

    # growing after relocating, DCS places only Gaussians the relocation left alone (the window's costs are theirs)
    gs = GaussianSet({k: v.copy() for k, v in params.items()}, zeros(), zeros())
    strategy.config = dataclasses.replace(strategy.config, max_gaussians=n + 30)
    assert strategy.densify(gs, window, 10, np.random.default_rng(5)).cloned == 30
    placed = 0
    for j in range(n, n + 30):
        family = np.flatnonzero((gs.params["quats"] == gs.params["quats"][j]).all(axis=1))
        if not any((gs.params["means"][i] == gs.params["means"][j]).all() for i in family if i != j):
            placed += 1      # a DCS pair: its parent, an original untouched by relocation, has no other copy
            assert len(family) == 2 and family[0] >= 200 and family[0] not in sources
    assert placed > 5


@pytest.mark.parametrize("iterations", [30_000, 3_000, 600])
def test_a_shorter_run_refines_as_often_for_its_length(iterations):
    """MCMC's schedule scales with the run as gsplat's steps_scaler scales it, its interval too, so a short run takes
    the full schedule's number of refinement steps and can grow to a cap (a 3DGS run keeps its interval
    unless under 10 steps would fit)."""
    from dc4gs_cl.config import TrainConfig
    from dc4gs_cl.train.schedule import Schedule
    mcmc = Schedule(TrainConfig(scene="builtin", iterations=iterations, strategy="mcmc")).strategy()
    scale = iterations / 30_000
    c = mcmc.config
    assert (c.densify_from, c.densify_until, c.densify_every) == (round(500 * scale), round(25_000 * scale),
                                                                 round(100 * scale))
    steps = sum(mcmc.densify_now(it) for it in range(1, iterations + 1))
    assert steps == 244 and 1.05 ** steps > 100   # 600, 700, ..., 24,900 of 30,000
    three_dgs = Schedule(TrainConfig(scene="builtin", iterations=iterations)).strategy().config
    assert three_dgs.densify_every == min(100, (three_dgs.densify_until - three_dgs.densify_from) // 10)


@pytest.mark.parametrize("dcs", [False, True])
def test_mcmc_trains_grows_and_resumes_to_the_same_model(rt, tmp_path, dcs):
    """--strategy mcmc (and with --dcs) on the built-in scene: it learns, grows by 5% a step up to the cap, keeps
    no dead Gaussian past a step, and a run resumed from a checkpoint ends bit for bit where the straight run does
    (the noise is keyed by seed and iteration, the draws come from the checkpointed generator, DCS' split costs
    from the checkpointed window)."""
    from dc4gs_cl.config import DC4GSConfig, TrainConfig
    from dc4gs_cl.scene.loader import load_scene
    scene = load_scene("builtin", resolution=4)
    cfg = TrainConfig(scene="builtin", iterations=150, resolution=4, strategy="mcmc", max_gaussians=6000,
                      dc4gs=DC4GSConfig(dcs=dcs))

    straight, resumed = straight_and_resumed(cfg, scene, rt, tmp_path, 70)
    start = len(scene.points)
    a, b = straight.model.download(), resumed.model.download()
    assert all(np.array_equal(a.params[k], b.params[k]) and np.array_equal(a.m[k], b.m[k]) for k in a.params)
    assert a.n == 6000 and start < 6000                     # grown to the cap
    assert (a.opacities() > 0.005).mean() > 0.99
    assert straight.loss.read_stats()["loss"] < 0.2


@pytest.mark.parametrize("args,says", [
    (["--opacity-reg", "0.1"], "--opacity-reg applies to --strategy mcmc only"),
    (["--strategy", "mcmc", "--dc4gs"], "--strategy mcmc: of DC4GS only --dcs applies"),
    (["--strategy", "mcmc", "--dcc"], "--strategy mcmc: of DC4GS only --dcs applies"),
    (["--strategy", "mcmc", "--dcs", "--dcs-track", "0.5"], "--dcs-track does not apply to --strategy mcmc"),
    (["--strategy", "mcmc", "--scale-reg", "-1"], "--scale-reg -1.0 must be a finite number >= 0"),
])
def test_mcmc_settings_that_make_no_sense(tmp_path, capsys, args, says):
    from dc4gs_cl.cli import main
    assert main(["train", "--out", str(tmp_path / "o"), "-r", "8", "--no-progress", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()


def test_a_cap_the_device_cannot_hold_is_refused_and_a_cap_says_what_it_takes(rt):
    """MCMC's --max-gaussians 1000000000 was taken without a word and grew to 4.1 GB by iteration 120."""
    from dc4gs_cl.config import TrainConfig
    from dc4gs_cl.errors import InputError
    from dc4gs_cl.scene.loader import load_scene
    from dc4gs_cl.train import Trainer
    scene = load_scene("builtin", resolution=8)
    huge = rt.device.global_mem_size // 100   # 100 bytes a Gaussian would fill the device: the held bytes are more
    with pytest.raises(InputError, match=f"--max-gaussians {huge:,}: .* GiB of the device's"):
        Trainer(TrainConfig(scene="builtin", iterations=10, resolution=8, strategy="mcmc", max_gaussians=huge),
                scene, rt)
    trainer = Trainer(TrainConfig(scene="builtin", iterations=10, resolution=8, strategy="mcmc"), scene, rt)
    held = trainer.held_bytes_per_gaussian()
    assert trainer.cap == 1_000_000 and 4 * 3 * 59 <= held < 1024   # parameters of SH degree 3 and their moments
    assert f"{trainer.cap * held / 2**30:.1f} GiB" in trainer.cap_memory(rt)
