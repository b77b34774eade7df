"""Forward-pass benchmark: per-stage device times, our sort against pyopencl's RadixSort on the same keys,
and what each skip saves and each approximation costs (time against error), side by side.

    python tools/bench_render.py [--runs 7] [--device D] [--quick]

Cases: gsplat's test asset (111,785 Gaussians, from ../shared/data when present) at full and half size,
and procedural random scenes of 200k and 1M Gaussians at 1280x720 and 640x360. Times are medians of
--runs frames from OpenCL profiling events; ratios compare runs made in this same process.
Needs the `bench` extra (Mako, for pyopencl.algorithm).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np
import pyopencl.array as cla

from bench_train import DATA   # the shared data folder beside the repository
from dc4gs_cl.render import DeviceGaussians, RenderOptions, Renderer
from dc4gs_cl.render.sort import RadixSort
from dc4gs_cl.runtime import Runtime, describe
from dc4gs_cl.scene.camera import Camera
from dc4gs_cl.reference.testing import gsplat_test_garden, random_model

GARDEN = DATA / "gsplat_test_garden" / "test_garden.npz"


def median_ms(values) -> float:
    return float(np.median(values)) * 1e3


def cases(rng, quick: bool):
    if GARDEN.exists():
        model, cams = gsplat_test_garden(GARDEN, rng)
        yield "garden 648x420", model, cams[0]
        yield "garden 324x210", model, cams[0].resized(324, 210)
    else:
        print(f"(gsplat test asset not found at {GARDEN}: garden cases skipped)")
    for n, (w, h) in ([(200_000, (640, 360))] if quick else
                      [(200_000, (640, 360)), (200_000, (1280, 720)), (1_000_000, (1280, 720))]):
        model = random_model(rng, n, sh_degree=3, spread=2.0, scale_range=(0.003, 0.03))
        cam = Camera.look_at("random", (0.0, -5.0, 1.5), (0.0, 0.0, 0.0), w, h, fov_x=1.0)
        yield f"random {n // 1000}k {w}x{h}", model, cam


def frame_times(rt: Runtime, renderer: Renderer, g: DeviceGaussians, cam: Camera, runs: int):
    """Median device ms per stage and wall ms per frame; returns (stages, wall, last result)."""
    res = renderer.render(g, cam)      # warm-up: builds kernels, sizes buffers
    rt.stage_times()
    per_stage, walls = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        res = renderer.render(g, cam)
        rt.queue.finish()
        walls.append(time.perf_counter() - t0)
        per_stage.append(rt.stage_times())
    stages = {s: median_ms([t.get(s, 0.0) for t in per_stage]) for s in per_stage[0]}
    return stages, median_ms(walls), res


def time_ours(rt: Runtime, sort: RadixSort, keys: np.ndarray, vals: np.ndarray, lo: int, hi: int, runs: int) -> float:
    """Median ms of our sort of (keys, vals) over bits [lo, hi), device time only."""
    kb, vb = rt.to_device(keys), rt.to_device(vals)
    times = []
    for _ in range(runs + 1):
        rt.write(kb, keys)
        rt.write(vb, vals)
        rt.stage_times()
        sort(kb, vb, len(keys), lo, hi, stage="sort")
        times.append(sum(rt.stage_times().values()))
    return median_ms(times[1:])


class PyopenclSort:
    """pyopencl.algorithm.RadixSort on (key, value) arrays, the reference we compare with."""

    def __init__(self, rt: Runtime, key_dtype):
        from pyopencl.algorithm import RadixSort as PyclRadixSort
        ctype = "ulong" if key_dtype == np.uint64 else "uint"
        self.rt = rt
        self.sort = PyclRadixSort(rt.context, f"{ctype} *keys, uint *vals", key_expr="keys[i]",
                                  sort_arg_names=["keys", "vals"], key_dtype=key_dtype)

    def time(self, keys: np.ndarray, vals: np.ndarray, key_bits: int, runs: int) -> tuple[float, np.ndarray]:
        q = self.rt.queue
        k, v = cla.to_device(q, keys), cla.to_device(q, vals)
        times, out = [], None
        for _ in range(runs + 1):
            q.finish()
            t0 = time.perf_counter()    # pyopencl's sort launches many kernels: time it on the wall
            (sk, sv), ev = self.sort(k, v, key_bits=max(key_bits, 1), queue=q)
            ev.wait()
            q.finish()
            times.append(time.perf_counter() - t0)
            out = sv
        return median_ms(times[1:]), out.get()


def sort_comparison(rt: Runtime, renderer: Renderer, res, runs: int) -> list[str]:
    """Our sorts against pyopencl's RadixSort on the keys of the frame just rendered."""
    n, v, p = res.proj.n, res.isect.n_visible, res.isect.n_pairs
    depth = rt.to_host(res.proj.depth, n)
    tiles_touched = rt.to_host(res.proj.tiles_touched, n, np.uint32)
    visible = np.flatnonzero(tiles_touched > 0).astype(np.uint32)
    depth_keys = depth[visible].view(np.uint32)
    ranges = rt.to_host(res.isect.ranges, (res.tiles_x * res.tiles_y, 2), np.uint32).astype(np.int64)
    tile_of_pair = np.repeat(np.arange(len(ranges), dtype=np.uint32), ranges[:, 1] - ranges[:, 0])   # the tile keys
    gaussian_of_pair = rt.to_host(res.isect.gaussian_of_pair, p, np.uint32)
    tile_bits = res.isect.tile_bits
    depth_bits = res.isect.depth_bits   # what the frame's depth sort sorted (DEPTH_KEY_BITS)
    varying = int(depth_keys.min() ^ depth_keys.max()).bit_length() if v > 1 else 0
    ours = RadixSort(renderer.context)
    py32, py64 = PyopenclSort(rt, np.uint32), PyopenclSort(rt, np.uint64)
    rows = []

    def compare(label, keys, vals, bits, lo=0):
        t_ours = time_ours(rt, ours, keys, vals, lo, bits, runs)
        t_py, _ = py32.time(keys, vals, bits, runs)
        rows.append(f"  {label:44s} ours {t_ours:8.2f} ms   pyopencl {t_py:8.2f} ms   x{t_py / t_ours:5.1f}")
        return t_ours, t_py

    d = compare(f"depth keys ({v:,} keys, {depth_bits} bits)", depth_keys, visible, depth_bits)
    t = compare(f"tile keys ({p:,} pairs, {tile_bits} bits)", tile_of_pair, gaussian_of_pair, tile_bits)
    # The one-sort formulation: 64-bit (tile << 32 | depth) keys over all pairs, sorted by pyopencl.
    keys64 = ((tile_of_pair.astype(np.uint64) << np.uint64(32))
              | depth[gaussian_of_pair].view(np.uint32).astype(np.uint64))
    t64, order = py64.time(keys64, gaussian_of_pair, 32 + tile_bits, runs)
    assert np.array_equal(order, gaussian_of_pair), "both formulations must give the same pair order"
    rows.append(f"  {'whole job: our 2 sorts vs pyopencl 64-bit keys':44s} ours {d[0] + t[0]:8.2f} ms   "
                f"pyopencl {t64:8.2f} ms   x{t64 / (d[0] + t[0]):5.1f}")
    # Skips inside the sort: unused key bits, culled Gaussians.
    full = time_ours(rt, ours, tile_of_pair, gaussian_of_pair, 0, 32, runs)
    rows.append(f"  {'skip: unused tile-key bits':44s} {tile_bits} bits {t[0]:8.2f} ms vs 32 bits {full:8.2f} ms")
    # Given up for a read-back: the depth sort sorts every bit a key can have, not just those that vary this frame.
    fewer = time_ours(rt, ours, depth_keys, visible, 0, varying, runs)
    rows.append(f"  {'no read-back: all depth-key bits, not those varying':44s} {depth_bits} bits {d[0]:8.2f} ms vs "
                f"{varying} bits {fewer:8.2f} ms")
    all_keys = np.where(tiles_touched > 0, depth.view(np.uint32), np.uint32(0xFFFFFFFF))
    t_all = time_ours(rt, ours, all_keys, np.arange(n, dtype=np.uint32), 0, 32, runs)
    rows.append(f"  {'skip: culled Gaussians emit no keys':44s} {v:,} keys {d[0]:8.2f} ms vs all {n:,} {t_all:8.2f} ms")
    return rows


def variant_rows(rt: Runtime, base: Renderer, g: DeviceGaussians, cam: Camera, runs: int, stages, image) -> list[str]:
    """Each exact skip turned off, each approximation turned on: time and image error."""
    rows = []
    total = sum(stages.values())
    for label, opts in [("skip off: alpha cut (3-sigma pairs)", RenderOptions(alpha_cut=False)),
                        ("skip off: early stop of saturated tiles", RenderOptions(early_stop=False)),
                        ("driver exp instead of ours", RenderOptions(fast_exp=False)),
                        ("approx: -cl-fast-relaxed-math", RenderOptions(relaxed_math=True)),
                        ("approx: relaxed math with the driver's exp",
                         RenderOptions(fast_exp=False, relaxed_math=True)),
                        ("approx: depth sorted on top 16 bits", RenderOptions(depth_sort_bits=16)),
                        ("approx: depth sorted on top 10 bits", RenderOptions(depth_sort_bits=10))]:
        r = Renderer(rt, base.tuning, opts)
        st, _, res = frame_times(rt, r, g, cam, runs)
        img = res.image(rt)
        err = np.abs(img - image)
        psnr = 10 * np.log10(1.0 / max(float(np.mean(err ** 2)), 1e-20))
        rows.append(f"  {label:44s} total {sum(st.values()):8.2f} ms (default {total:8.2f}; "
                    f"raster {st['rasterize']:7.2f}, "
                    f"pairs {res.isect.n_pairs:,})  max |diff| {err.max():.2e}  PSNR vs default {psnr:6.1f} dB")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--device", default=None)
    ap.add_argument("--quick", action="store_true", help="one random case and no variants (a smoke run)")
    args = ap.parse_args(argv)
    rt = Runtime(args.device, profiling=True)
    print(f"device: {describe(rt.device)}")
    rng = np.random.default_rng(0)
    for name, model, cam in cases(rng, args.quick):
        renderer = Renderer(rt)
        g = DeviceGaussians(rt, model)
        # An empty frame at this size: what a frame costs with nothing to draw (empty tiles' floor).
        empty = DeviceGaussians(rt, random_model(rng, 1, sh_degree=model.sh_degree))
        empty_stages, _, _ = frame_times(rt, renderer, empty, replace(cam, t=np.array([0.0, 0.0, -1e6])), args.runs)
        stages, wall, res = frame_times(rt, renderer, g, cam, args.runs)
        image = res.image(rt)
        tiles = res.tiles_x * res.tiles_y
        ranges = rt.to_host(res.isect.ranges, (tiles, 2), np.uint32)
        empty_tiles = int(np.sum(ranges[:, 1] == ranges[:, 0]))
        print(f"\n== {name}: {len(model):,} Gaussians, {res.isect.n_visible:,} visible, {res.isect.n_pairs:,} pairs, "
              f"{tiles:,} tiles ({empty_tiles:,} empty)")
        print("  stage ms (median of %d): " % args.runs + ", ".join(f"{s} {t:.2f}" for s, t in stages.items())
              + f"; device total {sum(stages.values()):.2f}, wall {wall:.2f}")
        print(f"  empty frame at this size (floor paid by empty tiles): raster {empty_stages['rasterize']:.2f} ms, "
              f"total {sum(empty_stages.values()):.2f} ms")
        for row in sort_comparison(rt, renderer, res, args.runs):
            print(row)
        if not args.quick:
            for row in variant_rows(rt, renderer, g, cam, args.runs, stages, image):
                print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
