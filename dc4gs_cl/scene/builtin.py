"""The built-in scene (`--scene builtin`, the default): a small still life ray cast in NumPy.

Objects: an 8 x 8 checkerboard ground square (z = 0, world z up), three boxes at different rotations (one
tilted and sunk into the ground; stripes, diagonal stripes or checker per face), two spheres (latitude /
longitude stripes; the large one has a mild specular highlight, the only view-dependent term), and a capped
cylinder (angular stripes, rings on the cap), lit by a directional light plus ambient, with a plain sky
of the scene's background colour for rays that miss (as a masked capture would have: no SfM point can
explain a sky, and a gradient there only grows floaters). Each pixel averages a regular 3 x 3 grid of rays, so
edges are antialiased.
Cameras: n_views cameras on a ring around the objects (one every 360/n_views degrees), cycling through three
elevations, all looking at the scene centre with a 55 degree horizontal field of view; "view_000"... so
that every test_every-th view (the test set) is spread around the ring.
Points: an SfM-like cloud: hits of random rays from the training cameras, jittered by 0.3 % of the scene
extent, coloured by the shaded surface (+ noise), plus 3 % outliers.
Shares no code with the rasterizer, so it can check it. Images are ray cast on first use and kept.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .camera import Camera, Scene, split_train_test
from .distortion import undistort_points

BUILTIN_SCENE = "builtin"

SEED = 20240607
FOV_X = np.radians(55.0)
TARGET = np.array([0.0, 0.0, 0.5])
CAMERA_DISTANCE = 5.5
ELEVATIONS = np.radians([12.0, 27.0, 42.0])
SUPERSAMPLE = 3                          # rays per pixel along each axis
LIGHT = np.array([0.45, -0.35, 0.82]) / np.linalg.norm([0.45, -0.35, 0.82])
AMBIENT = 0.35
SHININESS = 30.0
COLOR_RANGE = (0.05, 0.95)               # no pure black or white: nothing clips like a saturated photo
POINT_RAYS = 6000                        # rays cast for the point cloud (sky misses are dropped)
POINT_NOISE = 0.003                      # position noise, a fraction of the scene extent
POINT_COLOR_NOISE = 0.02
OUTLIER_FRACTION = 0.03
EPS = 1e-4                               # hits closer than this are the ray's own origin


def _rotation(yaw: float, tilt: float = 0.0) -> np.ndarray:
    """Local-to-world rotation: tilt about x, then yaw about z (degrees)."""
    a, b = np.radians(yaw), np.radians(tilt)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return rz @ rx


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _two_tone(mask: np.ndarray, c0, c1) -> np.ndarray:
    return np.where(mask, np.float32(c1)[:, None], np.float32(c0)[:, None])


def _parity(*coords: np.ndarray) -> np.ndarray:
    """Checker (two coordinates) or stripes (one): alternating unit cells."""
    return sum(np.floor(c).astype(np.int64) for c in coords) % 2 == 1


# Vectors are (3, N) arrays (one row per axis: NumPy is fast on rows); the ray origin is (3, 1): all rays
# of a call come from one camera. Each solid: intersect(o, d) -> distance along the unit rays (inf on a miss), and
# surface(p) -> (normal, albedo) at hit points. Rays start outside every solid, so only the entry hit matters.

class Ground:
    def __init__(self, half: float, tile: float, colors):
        self.half, self.tile, self.colors, self.specular = half, tile, colors, 0.0

    def intersect(self, o, d):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[2] / d[2]
        x, y = o[0] + t * d[0], o[1] + t * d[1]
        return np.where((t > EPS) & (np.abs(x) <= self.half) & (np.abs(y) <= self.half), t, np.inf)

    def surface(self, p):
        n = np.broadcast_to(np.float32([[0], [0], [1]]), p.shape)
        return n, _two_tone(_parity(p[0] / self.tile, p[1] / self.tile), *self.colors)


class Box:
    # face pattern in the face's (a, b) coordinates, one per face (-x, +x, -y, +y, -z, +z)
    PATTERNS = (lambda a, b: _parity(a), lambda a, b: _parity(a, b), lambda a, b: _parity(a + b),
                lambda a, b: _parity(b), lambda a, b: _parity(a - b), lambda a, b: _parity(a, b))

    def __init__(self, center, half, yaw, tilt, colors, cell: float):
        self.c, self.h = np.float32(center)[:, None], np.float32(half)[:, None]
        self.R = _rotation(yaw, tilt).astype(np.float32)
        self.colors, self.cell, self.specular = colors, cell, 0.0

    def intersect(self, o, d):
        ol, dl = self.R.T @ (o - self.c), self.R.T @ d       # slab test in the box's frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-self.h - ol) / dl, (self.h - ol) / dl
        tmin, tmax = np.minimum(t1, t2).max(axis=0), np.maximum(t1, t2).min(axis=0)
        return np.where((tmin <= tmax) & (tmin > EPS), tmin, np.inf)

    def surface(self, p):
        q = self.R.T @ (p - self.c)
        i = np.arange(q.shape[1])
        axis = np.abs(q / self.h).argmax(axis=0)
        sign = np.sign(q[axis, i])
        n = np.zeros_like(q)
        n[axis, i] = sign
        face = 2 * axis + (sign > 0)
        a, b = q[(axis + 1) % 3, i] / self.cell, q[(axis + 2) % 3, i] / self.cell
        mask = np.zeros(len(i), bool)
        for f, pattern in enumerate(self.PATTERNS):
            sel = face == f
            mask[sel] = pattern(a[sel], b[sel])
        tone = np.float32(0.85) + np.float32(0.075) * (face % 3)   # faces differ in tone too
        return self.R @ n, _two_tone(mask, *self.colors) * tone


class Sphere:
    def __init__(self, center, radius, colors, lat_bands: int, lon_bands: int, specular: float = 0.0):
        self.c, self.r, self.colors = np.float32(center)[:, None], radius, colors
        self.lat_bands, self.lon_bands, self.specular = lat_bands, lon_bands, specular

    def intersect(self, o, d):
        oc = o - self.c
        b = _dot(oc, d)
        disc = b * b - _dot(oc, oc) + self.r ** 2
        t = -b - np.sqrt(np.maximum(disc, 0))
        return np.where((disc >= 0) & (t > EPS), t, np.inf)

    def surface(self, p):
        n = (p - self.c) / self.r
        lat = np.arcsin(np.clip(n[2], -1, 1)) / np.pi + 0.5
        lon = np.arctan2(n[1], n[0]) / (2 * np.pi) + 0.5
        return n, _two_tone(_parity(lat * self.lat_bands, lon * self.lon_bands), *self.colors)


class Cylinder:
    """Vertical, standing on the ground (z from 0 to height), with a top cap."""

    def __init__(self, center_xy, radius, height, colors, stripes: int):
        self.c, self.r, self.height = np.float32(center_xy)[:, None], radius, height
        self.colors, self.stripes, self.specular = colors, stripes, 0.0

    def intersect(self, o, d):
        ox, oy = o[0] - self.c[0], o[1] - self.c[1]
        a, b = d[0] ** 2 + d[1] ** 2, ox * d[0] + oy * d[1]
        disc = b * b - a * (ox * ox + oy * oy - self.r ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            side = (-b - np.sqrt(np.maximum(disc, 0))) / a
            cap = (self.height - o[2]) / d[2]
        z = o[2] + side * d[2]
        side = np.where((disc >= 0) & (side > EPS) & (z >= 0) & (z <= self.height), side, np.inf)
        in_cap = (ox + cap * d[0]) ** 2 + (oy + cap * d[1]) ** 2 <= self.r ** 2
        return np.minimum(side, np.where((cap > EPS) & in_cap, cap, np.inf))

    def surface(self, p):
        x, y = p[0] - self.c[0], p[1] - self.c[1]
        on_cap = p[2] > self.height - 1e-3
        n = np.where(on_cap, np.float32([[0], [0], [1]]), np.stack([x / self.r, y / self.r, 0 * x]))
        angle = np.arctan2(y, x) / (2 * np.pi) + 0.5
        rings = np.sqrt(x * x + y * y) / self.r * 3
        return n, _two_tone(np.where(on_cap, _parity(rings), _parity(angle * self.stripes)), *self.colors)


SOLIDS = (
    Ground(4.0, 0.5, ((0.62, 0.58, 0.50), (0.30, 0.34, 0.30))),
    Box((1.3, -0.7, 0.5), (0.5, 0.35, 0.5), 30, 0, ((0.80, 0.30, 0.20), (0.90, 0.75, 0.40)), 0.2),
    Box((-1.1, -1.3, 0.3), (0.4, 0.4, 0.4), -20, 25, ((0.20, 0.35, 0.75), (0.75, 0.80, 0.90)), 0.25),
    Box((0.3, 1.5, 0.8), (0.22, 0.3, 0.8), 65, 0, ((0.30, 0.60, 0.30), (0.85, 0.85, 0.55)), 0.15),
    Sphere((-0.5, 0.2, 0.65), 0.65, ((0.85, 0.85, 0.80), (0.70, 0.20, 0.45)), 6, 8, specular=0.25),
    Sphere((1.4, 1.0, 0.35), 0.35, ((0.95, 0.65, 0.15), (0.30, 0.20, 0.15)), 7, 1),
    Cylinder((-1.6, 0.9), 0.3, 1.1, ((0.55, 0.45, 0.75), (0.90, 0.90, 0.90)), 10),
)


SKY = np.float32([0.55, 0.65, 0.80])     # also the scene's background colour


def cast_rays(o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the scene shows along rays: unit directions d (3, N) from origin o (3, 1) -> (colour (3, N) float32,
    distance to the nearest surface (N,), inf for the sky)."""
    ts = np.stack([s.intersect(o, d) for s in SOLIDS])
    nearest, t = ts.argmin(axis=0), ts.min(axis=0)
    color = np.repeat(SKY[:, None], d.shape[1], axis=1)
    light = LIGHT.astype(np.float32)[:, None]
    for k, solid in enumerate(SOLIDS):
        sel = (nearest == k) & np.isfinite(t)
        if not sel.any():
            continue
        n, albedo = solid.surface(o + t[sel] * d[:, sel])
        color[:, sel] = albedo * (AMBIENT + (1 - AMBIENT) * np.clip(_dot(n, light), 0, None))
        if solid.specular:   # Blinn-Phong: the view-dependent part
            h = light - d[:, sel]
            h /= np.sqrt(_dot(h, h))
            color[:, sel] += solid.specular * np.clip(_dot(n, h), 0, None) ** SHININESS
    return np.clip(color, *COLOR_RANGE).astype(np.float32), t


def _rays(cam: Camera, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origin (3, 1) and unit directions (3, N) of the rays through image points (u, v) (pixel units, the
    image's top-left corner at (0, 0)); through the camera's lens model where it has one."""
    d_cam = np.stack([(u.ravel() - cam.cx) / cam.fx, (v.ravel() - cam.cy) / cam.fy, np.ones(u.size)])
    if cam.distortion is not None:
        d_cam[:2] = undistort_points(cam.distortion, d_cam[:2].T).T
    d = (cam.R.T @ d_cam).astype(np.float32)
    return cam.center.astype(np.float32)[:, None], d / np.sqrt(_dot(d, d))


def render(cam: Camera) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1]: the mean of SUPERSAMPLE^2 rays on a regular grid inside each pixel."""
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE
    u = np.arange(cam.width)[None, :, None, None] + offsets[None, None, None, :]
    v = np.arange(cam.height)[:, None, None, None] + offsets[None, None, :, None]
    color, _ = cast_rays(*_rays(cam, *np.broadcast_arrays(u, v)))
    return np.ascontiguousarray(color.reshape(3, cam.height, cam.width, -1).mean(axis=3).transpose(1, 2, 0))


def _cameras(n_views: int, size: tuple[int, int]) -> list[Camera]:
    cams = []
    for i in range(n_views):
        azimuth, elevation = 2 * np.pi * i / n_views, ELEVATIONS[i % len(ELEVATIONS)]
        eye = TARGET + CAMERA_DISTANCE * np.array(
            [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
        cams.append(Camera.look_at(f"view_{i:03d}", eye, TARGET, size[0], size[1], FOV_X))
    return cams


def _points(cams: list[Camera], extent: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """SfM-like points: noisy surface hits of random rays from the cameras, plus a few outliers."""
    which = rng.integers(len(cams), size=POINT_RAYS)
    hits, colors = [], []
    for k, cam in enumerate(cams):
        m = int((which == k).sum())
        o, d = _rays(cam, rng.uniform(0, cam.width, m), rng.uniform(0, cam.height, m))
        color, t = cast_rays(o, d)
        keep = np.isfinite(t)
        hits.append((o + t[keep] * d[:, keep]).T)
        colors.append(color[:, keep].T)
    points, colors = np.concatenate(hits).astype(np.float64), np.concatenate(colors)
    points += rng.normal(0, POINT_NOISE * extent, points.shape)
    colors += rng.normal(0, POINT_COLOR_NOISE, colors.shape).astype(np.float32)
    n_out = round(OUTLIER_FRACTION * len(points))
    lo, hi = points.min(axis=0), points.max(axis=0)
    points = np.concatenate([points, rng.uniform(lo, hi, (n_out, 3))])
    colors = np.concatenate([colors, rng.uniform(0, 1, (n_out, 3)).astype(np.float32)])
    return points, np.clip(colors, 0, 1).astype(np.float32)


class _Renderer:
    """Scene.read_image: ray cast once per camera and size, then kept in memory."""

    def __init__(self):
        self.memory: dict[tuple[str, int, int], np.ndarray] = {}

    def __call__(self, cam: Camera) -> np.ndarray:
        key = (cam.name, cam.width, cam.height, cam.distortion)
        if key not in self.memory:
            image = render(cam)
            image.flags.writeable = False  # shared by every caller: a stray in-place edit must fail loudly
            self.memory[key] = image
        return self.memory[key]


def builtin_scene(resolution: int | None = None, test_every: int = 8, n_views: int = 32,
                  base_size: tuple[int, int] = (192, 144), test_split: str = "llff") -> Scene:
    """The built-in scene at base_size (resolution None or 1) or 1/resolution of it (the CLI's -r)."""
    train, test = split_train_test(_cameras(n_views, base_size), test_every, test_split)
    scene = Scene(root=Path(BUILTIN_SCENE), train=[c.at_resolution(resolution) for c in train],
                  test=[c.at_resolution(resolution) for c in test], points=None, colors=None,
                  background=SKY.copy(), read_image=_Renderer())
    # points from the base-size cameras, so that -r changes nothing but the images
    scene.points, scene.colors = _points(train or test, scene.extent, np.random.default_rng(SEED))
    return scene
