"""gsplat (CUDA, through torch) on bench's own frames, for `dc4gs-cl bench --gsplat`: the same Gaussians and
cameras, timed the way bench times ours (wall ms per frame or iteration, medians of rounds, the GPU synchronised
before each clock read).

- forward: gsplat's `rasterization` with SH degree 3 (the model's), no gradients;
- training iteration: as gsplat's simple_trainer runs one: rasterization, 0.8 L1 + 0.2 (1 - SSIM) against a target
  (the frame's own render with its colour channels reversed, as bench's ours), backward, DefaultStrategy's
  statistics (its refinement never due), Adam per parameter group; absgrad off (3DGS) or on (AbsGS).
- the first view's image against ours (PSNR), so that a ratio is known to compare the same frames.

torch and gsplat are imported only here, and only when asked for (`available`).
"""
from __future__ import annotations

import time

import numpy as np

from ..model import GaussianModel
from ..scene.camera import Camera

# gsplat 1.5.3's simple_trainer defaults (examples/simple_trainer.py), per parameter group
LEARNING_RATES = {"means": 1.6e-4, "scales": 5e-3, "quats": 1e-3, "opacities": 5e-2, "sh0": 2.5e-3,
                  "shN": 2.5e-3 / 20}
ITERATION = 3_000   # the step DefaultStrategy is told (inside its window; it never refines: its bounds are far)


def available() -> str | None:
    """None where torch and gsplat import and torch sees a CUDA device; else why not, in a few words."""
    try:
        import torch
    except ImportError as e:
        return f"torch does not import ({e})"
    if not torch.cuda.is_available():
        return f"torch {torch.__version__} sees no CUDA device"
    try:
        import gsplat  # noqa: F401
    except ImportError as e:
        return f"gsplat does not import ({e})"
    return None


def camera_matrices(cams: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """gsplat's viewmats (C, 4, 4: world to camera, [R | t]) and Ks (C, 3, 3: pinhole intrinsics, pixels) of our
    cameras (the same conventions: docs/conventions.md)."""
    viewmats = np.stack([np.block([[c.R, c.t[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]) for c in cams])
    ks = np.stack([np.array([[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]]) for c in cams])
    return viewmats.astype(np.float32), ks.astype(np.float32)


def _ssim(a, b):
    """Inria's SSIM (11 x 11 Gaussian window, sigma 1.5) of two (1, 3, H, W) images, in torch."""
    import torch
    import torch.nn.functional as F
    x = torch.arange(11, device=a.device, dtype=torch.float32) - 5
    g = torch.exp(-x ** 2 / 4.5)
    g = g / g.sum()
    window = (g[:, None] @ g[None, :]).expand(3, 1, 11, 11).contiguous()
    blur = lambda t: F.conv2d(t, window, padding=5, groups=3)
    mu1, mu2 = blur(a), blur(b)
    s11, s22, s12 = blur(a * a) - mu1 ** 2, blur(b * b) - mu2 ** 2, blur(a * b) - mu1 * mu2
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    return (((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 ** 2 + mu2 ** 2 + c1) * (s11 + s22 + c2))).mean()


def _timed(fn, rounds: int, per: int) -> float:
    """Median wall ms per call of fn over rounds of `per` calls, after one call outside the timing."""
    import torch
    fn()
    torch.cuda.synchronize()
    times = []
    for _ in range(rounds):
        torch.cuda.synchronize()
        start = time.perf_counter()
        for _ in range(per):
            fn()
        torch.cuda.synchronize()
        times.append((time.perf_counter() - start) / per * 1e3)
    return float(np.median(times))


def time_gsplat(model: GaussianModel, cams: list[Camera], background: np.ndarray, ours_image: np.ndarray,
                rounds: int, iterations: int, modes: dict[str, bool]) -> dict:
    """gsplat on this frame: {"forward": {"wall_ms"}, "train": {name: {"wall_ms", "peak_bytes_per_gaussian"}} for
    each of modes (name -> absgrad), "image_psnr_db": its first view against ours_image (H, W, 3)}."""
    import torch
    from gsplat import rasterization
    from gsplat.strategy import DefaultStrategy

    dev = "cuda"
    tensor = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32, device=dev)
    viewmats, ks = (tensor(m) for m in camera_matrices(cams))
    width, height, views = cams[0].width, cams[0].height, len(cams)
    sh = model.sh
    params = torch.nn.ParameterDict({"means": tensor(model.means), "scales": tensor(model.log_scales),
                                     "quats": tensor(model.quats), "opacities": tensor(model.opacity_logits),
                                     "sh0": tensor(sh[:, :1]), "shN": tensor(sh[:, 1:])})
    bg = tensor(background)[None]
    degree = int(round(np.sqrt(sh.shape[1]))) - 1

    def render(i: int, absgrad: bool = False):
        return rasterization(params["means"], params["quats"], torch.exp(params["scales"]),
                             torch.sigmoid(params["opacities"]), torch.cat([params["sh0"], params["shN"]], 1),
                             viewmats[i:i + 1], ks[i:i + 1], width, height, sh_degree=degree, packed=False,
                             absgrad=absgrad, backgrounds=bg)

    with torch.no_grad():
        first = render(0)[0][0].clamp(0, 1).cpu().numpy()
        targets = [render(i)[0][0].flip(-1).contiguous() for i in range(views)]
    mse = float(np.mean((first.astype(np.float64) - np.clip(ours_image, 0, 1)) ** 2))
    out = {"image_psnr_db": float(10 * np.log10(1.0 / max(mse, 1e-20))), "train": {}}
    view = [0]

    def next_view() -> int:
        view[0] += 1
        return view[0] % views

    def forward():
        with torch.no_grad():
            render(next_view())

    out["forward"] = {"wall_ms": _timed(forward, rounds, views)}
    for name, absgrad in modes.items():
        optimisers = {k: torch.optim.Adam([{"params": params[k], "lr": lr, "name": k}], eps=1e-15)
                      for k, lr in LEARNING_RATES.items()}
        strategy = DefaultStrategy(refine_start_iter=10 ** 9, refine_stop_iter=10 ** 9, reset_every=10 ** 9,
                                   absgrad=absgrad, verbose=False)
        strategy.check_sanity(params, optimisers)
        state = strategy.initialize_state(scene_scale=1.0)
        torch.cuda.reset_peak_memory_stats()

        def iteration():
            i = next_view()
            image, _, info = render(i, absgrad)
            strategy.step_pre_backward(params, optimisers, state, ITERATION, info)
            l1 = (image[0] - targets[i]).abs().mean()
            loss = 0.8 * l1 + 0.2 * (1 - _ssim(image[0].permute(2, 0, 1)[None], targets[i].permute(2, 0, 1)[None]))
            loss.backward()
            strategy.step_post_backward(params, optimisers, state, ITERATION, info, packed=False)
            for o in optimisers.values():
                o.step()
                o.zero_grad(set_to_none=True)

        out["train"][name] = {"wall_ms": _timed(iteration, rounds, iterations),
                              "peak_bytes_per_gaussian": torch.cuda.max_memory_allocated() / len(model)}
    del params, targets
    torch.cuda.empty_cache()
    return out
