"""train --exposure on the device (kernels/exposure.cl): a 3x4 affine colour correction per training photo, applied
to the render before the loss; its gradient (summed over the image in a fixed order), the render's gradient through
it, and Adam's step on every photo's correction, taken in the photos' colour coordinates (colour_coordinates), with
the anchor that keeps their mean the identity: three launches a view (exposure_apply, exposure_backward,
exposure_step)."""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pyopencl as cl

from ..render.stage import Stage, StageContext
from ..runtime import DeviceArrays

PARAMS = 12                                     # a correction: [A | b], 3 x 4 row-major
IDENTITY = np.eye(3, 4, dtype=np.float32).reshape(PARAMS)
APPLY_WG = 64                                   # exposure_apply: one item a pixel
# exposure_backward's shape: PER_ITEM pixels an item, WG items a group. The CPU's: one item a group, each a run of
# pixels the compiler walks straight (a 192 x 144 image: 14 groups); the GPUs': 256 items of 16 pixels.
CPU_SHAPE, GPU_SHAPE = {"WG": 1, "PER_ITEM": 2048}, {"WG": 256, "PER_ITEM": 16}
COORDS = 12                                     # colour coordinates: W [3][3] row-major, then mu [3]
PLAIN_COORDS = np.concatenate([np.eye(3).reshape(9), np.zeros(3)]).astype(np.float32)   # Adam on T itself
# colour_coordinates: the smallest variance the whitening takes a colour direction to have, as a fraction of the
# mean one. 1: it shrinks the directions the photos vary along more than on average (their brightness) and never
# amplifies one they hardly vary along; there Adam's steps are mostly noise, and amplified they drifted without
# bound (floored at 0.01, beer's corrections reached gains of 3.4 in 2,000 iterations; README, exposure)
VARIANCE_FLOOR = 1.0


def colour_coordinates(photos: Iterable[tuple[np.ndarray, np.ndarray | None]]) -> np.ndarray:
    """The coordinates the corrections' Adam steps in (kernels/exposure.cl, coords: W [3][3] row-major, then mu [3],
    float32) from the training photos ((H, W, 3) colours, (H, W) keep mask or None): mu their kept pixels' mean
    colour and W = (C / (tr C / 3))^(-1/2) the whitening of their colours' covariance C scaled to a mean variance of
    1, its eigenvalues floored at VARIANCE_FLOOR (so W only shrinks). A photo's colours are nearly collinear (the
    channels move together, and the gain with the offset), so that Adam on T itself moves the corrections slowly and
    along the wrong directions; in these coordinates its parameters are the photos' colour directions, the
    brightness, along which they vary most, scaled to the others.
    Sums in float64 over the photos in order: the same photos give the same coordinates everywhere, resumed too."""
    count, total, outer = 0, np.zeros(3), np.zeros((3, 3))
    for image, keep in photos:
        x = np.asarray(image, np.float64).reshape(-1, 3)
        if keep is not None:
            x = x[np.asarray(keep, bool).reshape(-1)]
        count, total, outer = count + len(x), total + x.sum(0), outer + x.T @ x
    if not count:
        raise ValueError("colour coordinates need at least one kept pixel")
    mu = total / count
    cov = outer / count - np.outer(mu, mu)
    scale = np.trace(cov) / 3
    if not scale > 0:   # one colour everywhere: nothing to whiten
        return np.concatenate([PLAIN_COORDS[:9], mu]).astype(np.float32)
    w, U = np.linalg.eigh(cov / scale)
    W = U @ np.diag(np.maximum(w, VARIANCE_FLOOR) ** -0.5) @ U.T
    return np.concatenate([W.reshape(9), mu]).astype(np.float32)


class Exposure(Stage):
    """The photos' corrections T [photos][12] and Adam's moments on the device (`state`: "T", "m", "v"); coords: the
    colour coordinates Adam steps in (colour_coordinates; PLAIN_COORDS: T's own)."""
    FILE, KERNELS = "exposure.cl", ("exposure_apply", "exposure_backward", "exposure_step")

    def __init__(self, ctx: StageContext, photos: int, shape: dict | None = None,
                 coords: np.ndarray = PLAIN_COORDS):
        super().__init__(ctx)
        if photos < 1:
            raise ValueError("exposure corrections need at least one photo")
        self.photos = photos
        shape = shape or (CPU_SHAPE if self.rt.caps.is_cpu else GPU_SHAPE)
        wg = min(shape["WG"], max(1, self.rt.caps.max_work_group_size))
        self.shape = {"WG": 1 << (wg.bit_length() - 1), "PER_ITEM": shape["PER_ITEM"]}
        self.k_apply, self.k_backward, self.k_step = (self.kernels(self.shape)[name] for name in self.KERNELS)
        self.state = DeviceArrays(self.rt, {"T": PARAMS, "m": PARAMS, "v": PARAMS}, photos)
        self.state.upload({"T": np.tile(IDENTITY, (photos, 1)), "m": np.zeros((photos, PARAMS), np.float32),
                           "v": np.zeros((photos, PARAMS), np.float32)})
        if np.shape(coords) != (COORDS,) or not np.isfinite(coords).all():
            raise ValueError(f"exposure colour coordinates: {COORDS} finite floats")
        self.coords = self.rt.to_device(np.asarray(coords, np.float32))
        self.grad = self.rt.buffer(4 * PARAMS)  # the last view's dL/dT (tests, --check-finite)
        self.no_mask = self.rt.buffer(4)        # bound where a view has no mask (never read)

    def apply(self, image: cl.Buffer, view: int, pixels: int, stage: str = "exposure") -> cl.Buffer:
        """The render corrected by photo `view`'s T, into scratch ("exposure.image", [pixels][3] float32)."""
        out = self.ws.get("exposure.image", 12 * pixels)
        self.rt.launch_items(stage, self.k_apply, pixels, APPLY_WG, np.int32(pixels), np.int32(view),
                             self.state.buffers["T"], image, out)
        return out

    def backward(self, image: cl.Buffer, grad: cl.Buffer, view: int, pixels: int, step: np.void,
                 keep: cl.Buffer | None = None, stage: str = "exposure") -> None:
        """grad (dL/d corrected image, [pixels][3]) becomes dL/dimage = A^T grad in place (0 where keep masks
        out); dL/dT summed over the kept pixels; step (a records.ADAM_STEP value, its slot 0 the corrections':
        optim.adam.one_group_step; stepping 0: no step) steps every photo's T and re-anchors their mean."""
        wg, per_item = self.shape["WG"], self.shape["PER_ITEM"]
        groups = -(-pixels // (wg * per_item))
        partial = self.ws.get("exposure.partial", 4 * PARAMS * groups)
        state = self.state.buffers
        self.rt.launch(stage, self.k_backward, groups * wg, wg, np.int32(pixels), np.int32(view), state["T"], image,
                       grad, np.int32(keep is not None), keep if keep is not None else self.no_mask, self.ctx.frame,
                       partial)
        self.rt.launch(stage, self.k_step, 1, 1, np.int32(groups), np.int32(view), np.int32(self.photos), state["T"],
                       state["m"], state["v"], step, self.coords, self.ctx.frame, partial, self.grad)
        self.check(lambda: {"dL_dT": self.rt.to_host(self.grad, PARAMS),
                            "exposure": self.state.download()["T"]})

    def download(self) -> dict[str, np.ndarray]:
        """T, m and v, each [photos][12] float32."""
        return self.state.download()

    def upload(self, state: dict[str, np.ndarray]) -> None:
        if set(state) != {"T", "m", "v"} or any(np.shape(a) != (self.photos, PARAMS) for a in state.values()):
            raise ValueError(f"exposure state: T, m and v of {self.photos} x {PARAMS}")
        self.state.upload({k: np.asarray(a, np.float32) for k, a in state.items()})
