"""Densification rules on hand-built states: clone, split, prune, opacity reset and clamp, the three
criteria, and Adam moments staying with their Gaussians through every operation."""
from dataclasses import replace

import numpy as np
import pytest

from dc4gs_cl.densify import AbsGS, DC4GSConfig, DensifyConfig, PixelGS, Strategy, ops
from dc4gs_cl.geometry import quat_to_rotmat
from dc4gs_cl.model import GaussianSet
from dc4gs_cl.statistics import ABS_PER_VIEW, BASE_COLUMNS, GRAD_PER_PIXEL, VIEWS

EXTENT = 2.0


def hand_built(rng, n=6, sh=4):
    """n Gaussians whose parameters and moments encode their index, so every row can be traced."""
    idx = np.arange(n, dtype=np.float32)[:, None]
    params = {"means": idx + np.zeros((n, 3)), "log_scales": np.full((n, 3), np.log(0.01), np.float32),
              "quats": rng.normal(size=(n, 4)).astype(np.float32), "opacity_logits": np.zeros((n, 1), np.float32),
              "sh": idx + np.zeros((n, 3 * sh), np.float32)}
    m = {k: v * 0 + idx + 100 for k, v in params.items()}
    v = {k: v * 0 + idx + 200 for k, v in params.items()}
    return GaussianSet({k: np.asarray(a, np.float32) for k, a in params.items()}, m, v)


def at_extent(s: Strategy) -> Strategy:
    """The strategy as attach() leaves it for a scene of EXTENT (less the device state, which densify does not use)."""
    s.extent = EXTENT
    return s


def window(n, **columns):
    stats = {k: np.zeros(n) for k in BASE_COLUMNS}
    stats[VIEWS][:] = 10
    for k, val in columns.items():
        stats[k][:] = val
    return stats


def test_clone_appends_exact_copies_with_zero_moments(rng):
    gs = hand_built(rng)
    assert ops.clone(gs, np.array([0, 1, 0, 1, 0, 0], bool)) == 2
    assert gs.n == 8
    for k in gs.params:
        np.testing.assert_array_equal(gs.params[k][6:], gs.params[k][[1, 3]])
        np.testing.assert_array_equal(gs.m[k][:6, 0], 100 + np.arange(6))
        np.testing.assert_array_equal(gs.m[k][6:], 0)
        np.testing.assert_array_equal(gs.v[k][6:], 0)


def test_random_split_replaces_parent_by_two_children(rng):
    gs = hand_built(rng)
    gs.params["log_scales"][2] = np.log([0.5, 0.1, 0.2])
    parent = {k: v[2].copy() for k, v in gs.params.items()}
    assert ops.split_random(gs, np.array([0, 0, 1, 0, 0, 0], bool), np.random.default_rng(1)) == 1
    assert gs.n == 7
    np.testing.assert_array_equal(gs.params["means"][:5, 0], [0, 1, 3, 4, 5])   # parent removed, order kept
    np.testing.assert_array_equal(gs.m["means"][:5, 0], 100 + np.array([0, 1, 3, 4, 5]))
    children = slice(5, 7)
    np.testing.assert_allclose(np.exp(gs.params["log_scales"][children]),
                               np.broadcast_to(np.exp(parent["log_scales"]) / 1.6, (2, 3)), rtol=1e-6)
    for k in ("quats", "opacity_logits", "sh"):
        np.testing.assert_array_equal(gs.params[k][children], np.broadcast_to(parent[k], gs.params[k][children].shape))
    # Offsets in the parent's frame are N(0, S): large along its first axis, small along the others.
    eps = np.random.default_rng(1).normal(size=(2, 3)) * np.exp(parent["log_scales"])
    R = quat_to_rotmat(parent["quats"][None])[0]
    np.testing.assert_allclose(gs.params["means"][children], parent["means"] + eps @ R.T, rtol=1e-5)
    np.testing.assert_array_equal(gs.m["means"][children], 0)


def test_densify_clones_small_splits_large_and_never_splits_clones(rng):
    s = at_extent(Strategy(DensifyConfig(percent_dense=0.01)))
    gs = hand_built(rng)
    gs.params["log_scales"][3:] = np.log(0.1)          # 3, 4, 5 are large (> 0.01 * EXTENT)
    gs.params["opacity_logits"][:] = 2.0
    stats = window(6)
    stats["grad"][:] = 10 * np.array([3e-4, 1e-4, 2e-4, 3e-4, 1e-4, 2e-4])   # mean 3e-4, 1e-4, exactly 2e-4
    report = s.densify(gs, stats, it=1000, rng=rng)
    assert (report.cloned, report.split, report.pruned) == (2, 2, 0)       # >= threshold, as the release
    # kept 0, 1, 2, 4; clones of 0, 2; children of 3, 5
    np.testing.assert_array_equal(gs.params["sh"][:, 0], [0, 1, 2, 4, 0, 2, 3, 3, 5, 5])


def test_before_densify_observes_each_step_before_it_changes_anything(rng):
    s = at_extent(Strategy())
    gs = hand_built(rng)
    gs.params["opacity_logits"][:] = 2.0
    stats = window(6, grad=10 * 3e-4)                    # every one is cloned
    seen = []
    s.before_densify = lambda g, w, it: seen.append((g is gs, g.n, w is stats, it))
    assert s.densify(gs, stats, it=1000, rng=rng).cloned == 6
    assert seen == [(True, 6, True, 1000)] and gs.n == 12


def test_dcs_middle_splits_at_the_middle_without_costs(rng):
    """--split-pick middle (an ablation): DCS' deterministic split at x = 0.5 (children at mu -/+ 1.5 sigma p,
    half the scale along the axis and half the opacity), no split costs gathered nor needed in the window."""
    s = at_extent(AbsGS(DensifyConfig(split_threshold=4e-4, percent_dense=0.01),
                        DC4GSConfig(dcs=True, split_pick="middle")))
    assert s.split_candidates == 0 and s.statistics.split_candidates == 0
    gs = hand_built(rng)
    gs.params["log_scales"][3] = np.log([0.02, 0.3, 0.1])         # large; its principal axis is y
    gs.params["opacity_logits"][:] = 2.0
    parent = {k: v[3].astype(np.float64) for k, v in gs.params.items()}
    stats = window(6)
    stats["abs"][3] = 10 * 5e-4
    report = s.densify(gs, stats, it=1000, rng=rng)
    assert report.split == 1 and gs.n == 7
    p = quat_to_rotmat(parent["quats"][None])[0][:, 1]
    np.testing.assert_allclose(gs.params["means"][5:], parent["means"] + np.outer([-1.5, 1.5], 0.3 * p), atol=1e-6)
    np.testing.assert_allclose(np.exp(gs.params["log_scales"][5:]), [[0.02, 0.15, 0.1]] * 2, rtol=1e-6)
    opacity = 1 / (1 + np.exp(-gs.params["opacity_logits"][5:, 0]))
    np.testing.assert_allclose(opacity, [0.5 / (1 + np.exp(-2.0))] * 2, rtol=1e-6)


def test_prune_rules(rng):
    gs = hand_built(rng)
    gs.params["opacity_logits"][:, 0] = [-6.0, 2.0, 2.0, 2.0, 2.0, 2.0]   # sigmoid(-6) < 0.005
    gs.params["log_scales"][2] = np.log(0.3)                            # > 0.1 * EXTENT
    stats = window(6, max_radius=5.0)
    stats["max_radius"][4] = 30.0
    early = at_extent(Strategy(DensifyConfig(big_world_after=3000)))
    report = early.densify(gs, stats, it=2000, rng=rng)
    assert report.pruned == 1 and gs.n == 5                             # opacity only before 3,000
    late = at_extent(Strategy(DensifyConfig(big_world_after=3000, screen_size_px=20)))
    stats = window(5, max_radius=5.0)
    stats["max_radius"][3] = 30.0                                       # former index 4
    report = late.densify(gs, stats, it=3100, rng=rng)
    assert report.pruned == 2
    np.testing.assert_array_equal(gs.params["sh"][:, 0], [1, 3, 5])


@pytest.mark.parametrize("cls, column, threshold", [(Strategy, "grad", 2e-4), (AbsGS, "abs", 4e-4)])
def test_split_criterion_of_each_base(rng, cls, column, threshold):
    s = at_extent(cls())
    gs = hand_built(rng, n=2)
    gs.params["log_scales"][:] = np.log(0.5)
    gs.params["opacity_logits"][:] = 2.0
    stats = window(2)
    stats[column][:] = 10 * np.array([threshold * 1.01, threshold * 0.99])
    assert s.densify(gs, stats, it=1000, rng=rng).split == 1


def test_pixelgs_averages_over_pixels_not_views(rng):
    s = at_extent(PixelGS())
    gs = hand_built(rng, n=2)
    gs.params["log_scales"][:] = np.log(0.001)
    gs.params["opacity_logits"][:] = 2.0
    stats = window(2, views=1000.0)
    stats["pix_grad"][:] = [3e-4 * 50, 1e-4 * 50]
    stats["pix"][:] = 50
    assert s.densify(gs, stats, it=1000, rng=rng).cloned == 1


def test_cap_takes_the_highest_criteria_of_clones_and_splits_together(rng):
    """With max_gaussians the step adds at most the room left; clone and split candidates are ranked together
    by criterion over threshold (AbsGS: clones on grad / 2e-4, splits on abs / 4e-4)."""
    n = 8
    gs = hand_built(rng, n=n)
    gs.params["log_scales"][:4] = np.log(0.001)                    # 0-3 small (clone; AbsGS: <= 0.001 x extent)
    gs.params["log_scales"][4:] = np.log(0.5)                      # 4-7 large (split)
    gs.params["opacity_logits"][:] = 2.0
    ratios = rng.permutation(np.linspace(1.1, 3.0, n))             # every one qualifies, distinct scores
    stats = window(n)
    stats["grad"][:4] = 10 * 2e-4 * ratios[:4]
    stats["abs"][4:] = 10 * 4e-4 * ratios[4:]
    for room in (0, 1, 3, 5, 8, 20):
        g = GaussianSet({k: v.copy() for k, v in gs.params.items()}, dict(gs.m), dict(gs.v))
        report = at_extent(AbsGS(replace(AbsGS.default_config(), max_gaussians=n + room))).densify(
            g, {k: v.copy() for k, v in stats.items()}, it=1000, rng=rng)
        taken = min(room, n)
        assert g.n == n + taken and report.cloned + report.split == taken and report.capped == n - taken
        winners = set(np.argsort(-ratios)[:taken])
        cloned = set(np.flatnonzero(np.arange(n) < 4)) & winners
        split = winners - cloned
        assert (report.cloned, report.split) == (len(cloned), len(split))
        # the originals stay in order less the split parents; clones of the winners follow, then children
        np.testing.assert_array_equal(g.params["sh"][:n - len(split), 0], sorted(set(range(n)) - split))
        np.testing.assert_array_equal(g.params["sh"][n - len(split):n - len(split) + len(cloned), 0], sorted(cloned))


def test_cap_growth_ties_and_growth(rng):
    clone = np.array([1, 0, 1, 0], bool)
    split = np.array([0, 1, 0, 1], bool)
    score = np.ones(4)                                            # all tied: lower index first
    c, s = ops.cap_growth(2, [(clone, score, 1), (split, score, 1)])
    np.testing.assert_array_equal(c | s, [1, 1, 0, 0])
    c, s = ops.cap_growth(3, [(clone, score, 1), (split, score, 2)])   # a split adding two needs room for two
    assert c.sum() + 2 * s.sum() <= 3 and c[0] and s[1]
    c, s = ops.cap_growth(-5, [(clone, score, 1), (split, score, 1)])  # already past the cap: nothing
    assert not c.any() and not s.any()


def test_schedule_follows_the_recipe():
    s = Strategy()
    steps = [it for it in range(1, 30_001) if s.densify_now(it)]
    assert steps[0] == 600 and steps[-1] == 14_900 and len(steps) == 144
    assert [it for it in range(1, 30_001) if s.reset_opacity_now(it, False)] == [3000, 6000, 9000, 12000]
    assert s.reset_opacity_now(500, True) and not s.reset_opacity_now(500, False)
    a = AbsGS()
    clamps = [it for it in range(1, 30_001) if a.clamp_opacity_now(it)]
    assert clamps[0] == 500 and clamps[-1] == 14_500 and not s.clamp_opacity_now(500)
    assert s.last_densify_step == 14_900 and s.collecting(1) and s.collecting(14_900) and not s.collecting(14_901)
    assert a.last_densify_step == 14_900 and not s.collecting(15_000)
    # no step in the window: nothing gathered; a step on the window's last iteration is not one (it < until)
    assert Strategy(DensifyConfig(densify_from=500, densify_until=550)).last_densify_step == 0
    assert Strategy(DensifyConfig(densify_from=0, densify_until=200)).last_densify_step == 100
    assert not Strategy(DensifyConfig(densify_until=0)).collecting(1)


class ToyBase(Strategy):
    """A new base strategy, added by subclassing alone: clone on Pixel-GS' per-pixel criterion, split on AbsGS'
    homodirectional one at twice 3DGS' threshold. DC4GS applies to it as to any base."""
    name = "toy"
    clone_criterion = GRAD_PER_PIXEL
    base_split_criterion = ABS_PER_VIEW

    @staticmethod
    def default_config() -> DensifyConfig:
        return DensifyConfig(split_threshold=4e-4, densify_from=10, densify_until=60, densify_every=10,
                             opacity_reset_every=1000)


def test_a_new_base_strategy_is_a_subclass(rng):
    s = at_extent(ToyBase())
    gs = hand_built(rng, n=4)
    gs.params["log_scales"][2:] = np.log(0.5)                       # 0, 1 small; 2, 3 large
    gs.params["opacity_logits"][:] = 2.0
    stats = window(4, pix=50.0)
    stats["pix_grad"][:] = 50 * np.array([3e-4, 1e-4, 3e-4, 3e-4])  # per pixel: clones 0 (2 is large)
    stats["abs"][:] = 10 * np.array([9e-4, 9e-4, 5e-4, 3e-4])       # per view: splits 2 (0, 1 are small)
    report = s.densify(gs, stats, it=1000, rng=rng)
    assert (report.cloned, report.split) == (1, 1)
    from dc4gs_cl.densify import DC4GSConfig
    from dc4gs_cl.statistics import DCC_ABS
    assert ToyBase(dc4gs=DC4GSConfig(dcc=True)).split_criterion.total == DCC_ABS   # DCC weights its own term


@pytest.mark.parametrize("settings, label", [
    (DC4GSConfig(), "toy"), (DC4GSConfig(dcc=True, dcs=True), "toy+DC4GS"),
    (DC4GSConfig(dcs=True, split_pick="middle"), "toy+DCS")], ids=["toy", "toy+DC4GS", "toy+DCS-middle"])
def test_a_new_base_strategy_trains(rt, tmp_path, settings, label):
    """The trainer takes the subclass as it is: its window on the device, its hooks, its densification."""
    from dc4gs_cl.config import TrainConfig
    from dc4gs_cl.scene.loader import load_scene
    from dc4gs_cl.train import Trainer
    scene = load_scene("builtin", resolution=4)
    strategy = ToyBase(dc4gs=settings)
    trainer = Trainer(TrainConfig(scene="builtin", iterations=80, resolution=4, dc4gs=settings), scene, rt, tmp_path,
                      strategy=strategy)
    assert trainer.strategy is strategy and strategy.label == label
    start = trainer.model.n
    trainer.run(progress="none")
    assert trainer.model.n != start and np.isfinite(trainer.params.download()["means"]).all()
