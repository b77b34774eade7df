"""Training loss on the device (kernels/loss.cl): L = 0.8 L1 + 0.2 (1 - SSIM), its gradient dL/dimage,
and running statistics (loss, L1, SSIM, MSE) that stay on the device until `read_stats()`."""
from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from ..constants import LAMBDA_DSSIM
from ..render.stage import Stage, StageContext, halvings
from ..render.workspace import PAIR_SCRATCH

SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2
SSIM_WINDOW = 11        # Gaussian window side (pixels, odd)
SSIM_SIGMA = 1.5

MASK_WG = 64            # work-group of mask_pixels (one item per pixel)
STAT_KEYS = ("loss", "l1", "dssim", "mse")   # layout of the device stats buffer (sums over calls)


def loss_defines(lambda_dssim: float) -> dict:
    """The SSIM window (its radius, and its normalised 1D Gaussian weights as a C initializer list) and
    constants as -D values; L = (1 - lambda_dssim) L1 + lambda_dssim (1 - SSIM)."""
    r = SSIM_WINDOW // 2
    g = [math.exp(-(k - r) ** 2 / (2 * SSIM_SIGMA ** 2)) for k in range(SSIM_WINDOW)]
    weights = ",".join(f"{v / sum(g)!r}f" for v in g)
    return {"SSIM_RADIUS": r, "SSIM_WEIGHTS": weights, "SSIM_C1": SSIM_C1, "SSIM_C2": SSIM_C2,
            "LAMBDA_DSSIM": float(lambda_dssim)}


class Loss(Stage):
    """The loss of a rendered image against a target, both [H*W*3] float32 (interleaved RGB) buffers.

    Work shape (kernels/loss.cl): a work-group of `wg` items owns wg * seg consecutive floats of a row.
    CPU default seg=2304 (a 768-pixel row), wg=1, measured on PoCL (2 cores): at 768x512, 8% faster than
    512 floats and as fast as 4096; at 160x120 all equal; wg > 1 was 2.5x (seg 64, wg 4) to 11x (seg 1,
    wg 256) slower, PoCL not vectorising across work-items here. GPUs: one float per item, 256 per group.
    """
    FILE, KERNELS = "loss.cl", ("loss_ssim", "loss_grad", "loss_reduce", "mask_pixels")

    def __init__(self, ctx: StageContext, seg: int | None = None, wg: int | None = None,
                 lambda_dssim: float = LAMBDA_DSSIM):
        """lambda_dssim: the SSIM term's weight (in the stats' loss and the gradient). seg, wg: the work shape
        (default: the device kind's), narrowed to the device's limits: wg to its
        work-group size, then seg (then wg) halved until loss_ssim's local arrays fit (the CPU shape's 46,680
        bytes do not fit a 32 KiB device)."""
        super().__init__(ctx)
        self.lambda_dssim = lambda_dssim
        caps = self.rt.caps
        seg, wg = seg or (2304 if caps.is_cpu else 1), wg or (1 if caps.is_cpu else 256)
        wg = next(w for w in halvings(wg) if w <= max(1, caps.max_work_group_size))
        shapes = [{"SEG": s, "WG": wg} for s in halvings(seg)] + [{"SEG": 1, "WG": w} for w in halvings(wg)[1:]]
        shape, k = self.fitting_kernels(shapes, "loss_ssim")
        self.seg, self.wg = shape["SEG"], shape["WG"]
        self.k_ssim, self.k_grad, self.k_reduce, self.k_mask = (k[name] for name in self.KERNELS)
        self.stats = self.rt.buffer(4 * len(STAT_KEYS))
        self.rt.fill(self.stats, np.float32(0), self.stats.size)
        self.calls = 0

    def defines(self) -> dict:   # SEG and WG: the shape, a variant (fitting_kernels)
        return loss_defines(self.lambda_dssim)

    def __call__(self, image: cl.Buffer, target: cl.Buffer, width: int, height: int,
                 grad_out: cl.Buffer | None, stage: str = "loss", keep: cl.Buffer | None = None,
                 kept: int = 0) -> None:
        """Write dL/dimage to grad_out ([H*W*3] float32) and add this image's loss, L1, SSIM and MSE to the
        running stats. grad_out=None computes only the stats (evaluation). keep: the view's mask (H x W
        uint8 or bool, 0 = masked out) with `kept` pixels kept: both images count as zero under it, the loss
        is the mean over the kept pixels, and dL/dimage at masked pixels is meaningless (the backward skips
        them)."""
        if width < 1 or height < 1:
            raise ValueError(f"image size {width} x {height}")
        rt, n3w, h = self.rt, 3 * width, height
        m = n3w * h
        groups_x = -(-n3w // (self.seg * self.wg))
        # temporaries, dead once the loss is queued (PAIR_SCRATCH: the frame's pairs are gathered by now)
        masked = ("masked_image", "masked_target") if keep is not None else ()
        scratch = self.ws.scratch(PAIR_SCRATCH, {**{name: 4 * m for name in (*masked, "d0", "d1", "d2")},
                                                 "partial": 4 * 3 * groups_x * h})
        if keep is not None:   # both images zeroed under the mask, into scratch: neither input is changed
            image, target = (self.mask(stage, src, keep, scratch[name], width * h)
                             for name, src in (("masked_image", image), ("masked_target", target)))
        scale = 3 * max(kept, 1) if keep is not None else m   # the floats the mean is over
        shape, local = (groups_x * self.wg, h), (self.wg, 1)
        d = [scratch[f"d{q}"] for q in range(3)]
        partial = scratch["partial"]
        args = (np.int32(n3w), np.int32(h))
        stats = (self.ctx.frame, np.int32(groups_x * h), np.float32(1 / scale), partial, self.stats)
        rt.launch(stage, self.k_ssim, shape, local, *args, np.float32(-self.lambda_dssim / scale),
                  image, target, *d, partial)
        if grad_out is not None:   # its first work-group adds the stats too
            rt.launch(stage, self.k_grad, shape, local, *args, np.float32((1 - self.lambda_dssim) / scale),
                      image, target, *d, grad_out, *stats)
        else:
            rt.launch(stage, self.k_reduce, self.wg, self.wg, *stats)
        self.calls += 1
        if grad_out is not None:
            self.check(lambda: {"dL_dimage": rt.to_host(grad_out, (h, width, 3))})

    def mask(self, stage: str, src: cl.Buffer, keep: cl.Buffer, out: cl.Buffer, pixels: int) -> cl.Buffer:
        self.rt.launch_items(stage, self.k_mask, pixels, MASK_WG, np.int32(pixels), src, keep, out)
        return out

    def running_sums(self) -> tuple[list[float], int]:
        """The stats' running sums and call count, to carry them through a checkpoint (restore_sums)."""
        return self.rt.to_host(self.stats, len(STAT_KEYS)).tolist(), self.calls

    def restore_sums(self, sums: list[float], calls: int) -> None:
        self.rt.write(self.stats, np.asarray(sums, np.float32))
        self.calls = calls

    def read_stats(self) -> dict[str, float]:
        """Means over the calls since the last read (NaN when there was none) of loss, l1, ssim and mse
        (mse of the unclamped image), then reset them. Waits for the queue: call it every N iterations."""
        sums = self.rt.to_host(self.stats, len(STAT_KEYS)).astype(np.float64)
        self.rt.fill(self.stats, np.float32(0), self.stats.size)
        calls, self.calls = self.calls, 0
        loss, l1, dssim, mse = sums / calls if calls else [math.nan] * len(STAT_KEYS)
        return {"loss": float(loss), "l1": float(l1), "ssim": 1.0 - float(dssim), "mse": float(mse)}
