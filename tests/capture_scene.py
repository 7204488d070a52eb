"""A small numpy ray-caster for synthetic real-looking captures (tests/test_sfm.py, tests/test_capture_masks.py): a
sphere with a solid (3D) blob texture in warm colours resting on a textured ground plane in cool colours (a table),
under a fixed directional light, seen by OpenCV pinhole cameras with world Z up. The texture is a function of the
3D point, so every view sees the same surface: enough SIFT features for structure from motion, and a background
that is not uniform (no key), so masks must be segmented. Deterministic (one seed), a few seconds for 12 views."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from frng import camera

SPHERE_R = 0.8  # the object: a sphere of this radius centred at the origin
GROUND_Z = -SPHERE_R  # the table it rests on
GROUND_R = 9.0  # the table's radius; beyond it, a plain sky
LIGHT = np.array([0.4, -0.3, 0.87]) / np.linalg.norm([0.4, -0.3, 0.87])


@dataclass
class Shot:
    """One synthetic photo: display-encoded RGB in [0, 1], the object's true mask, its OpenCV camera."""

    rgb: np.ndarray  # (H, W, 3) float32
    mask: np.ndarray  # (H, W) bool: the sphere is the first hit
    c2w: np.ndarray  # (4, 4)
    intr: np.ndarray  # (fx, fy, cx, cy)


class _Texture:
    """A solid texture: random dots (balls of the 3D point's lattice cell: random centre, radius, shade) at three
    scales over a smooth value noise. Sharp-edged blobs of many sizes, each distinct: what SIFT finds and matches."""

    def __init__(self, seed: int, size: int = 64):
        rng = np.random.default_rng(seed)
        self.size = size
        self.noise = rng.uniform(size=(size, size, size)).astype(np.float32)
        self.cells = rng.uniform(size=(3, size, size, size, 5)).astype(np.float32)  # centre xyz, radius, shade

    def __call__(self, p: np.ndarray, cell: float) -> np.ndarray:
        """(N, 3) points -> (N,) shade in [0, 1]; ``cell``: the larger dots' lattice spacing."""
        from scipy import ndimage

        q = (p / (2.5 * cell)).T + 11.3
        out = 0.15 + 0.7 * ndimage.map_coordinates(self.noise, q, order=1, mode="grid-wrap")
        for layer, c in enumerate((cell, 0.5 * cell, 0.25 * cell)):
            i = np.floor(p / c).astype(np.int64)
            v = self.cells[layer][tuple((i % self.size).T)]  # (N, 5)
            centre = (i + 0.5 + 0.2 * (v[:, :3] - 0.5)) * c
            inside = np.linalg.norm(p - centre, axis=1) < (0.22 + 0.2 * v[:, 3]) * c
            out = np.where(inside, v[:, 4], out)
        return out.astype(np.float32)


def cameras(n: int, distance: float = 4.0, fov_deg: float = 42.0, res: int = 256, seed: int = 0):
    """``n`` cameras around the object (azimuth evenly spread with jitter, elevation 20-40 deg), looking near the
    origin, world Z up: [(c2w (4, 4), intrinsics)]."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        az = 360.0 * k / n + rng.uniform(-8, 8)
        el = 20.0 + 20.0 * ((k * 0.618) % 1.0)
        eye = camera.spherical_to_cartesian(az, el, distance * rng.uniform(0.95, 1.05))
        out.append((camera.look_at(eye, rng.normal(0, 0.05, 3)), camera.intrinsics_from_fov(fov_deg, res, res)))
    return out


def render(c2w: np.ndarray, intr, res: int = 256, ss: int = 2, seed: int = 0, shadow: float = 0.45) -> Shot:
    """One view of the scene (``ss`` x ``ss`` supersampling); ``shadow``: what the sphere's shadow leaves of the
    table's colour (1: no shadow)."""
    fx, fy, cx, cy = (float(v) for v in intr)
    R = res * ss
    u = (np.arange(R) + 0.5) / ss
    uu, vv = np.meshgrid(u, u, indexing="xy")
    d = np.stack([(uu - cx) / fx, (vv - cy) / fy, np.ones_like(uu)], -1).reshape(-1, 3)
    d = d @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = c2w[:3, 3]
    # sphere at the origin
    b = d @ o
    c = o @ o - SPHERE_R**2
    disc = b * b - c
    t_s = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    t_s = np.where(t_s > 1e-6, t_s, np.inf)
    # ground plane
    t_g = np.where(d[:, 2] < -1e-6, (GROUND_Z - o[2]) / np.where(d[:, 2] < -1e-6, d[:, 2], -1.0), np.inf)
    p_g = o + d * np.where(np.isfinite(t_g), t_g, 0.0)[:, None]
    t_g = np.where(np.hypot(p_g[:, 0], p_g[:, 1]) < GROUND_R, t_g, np.inf)
    hit_s = t_s < t_g
    hit_g = np.isfinite(t_g) & ~hit_s
    rgb = np.empty((len(d), 3), np.float32)
    rgb[:] = (0.78, 0.80, 0.84)  # sky
    if hit_s.any():
        p = o + d[hit_s] * t_s[hit_s, None]
        n = p / SPHERE_R
        tex = _Texture(seed)(p, 0.22)
        warm = np.stack([0.35 + 0.65 * tex, 0.12 + 0.7 * tex, 0.04 + 0.3 * tex**2], -1)
        shade = 0.35 + 0.65 * np.clip(n @ LIGHT, 0, 1)
        rgb[hit_s] = warm * shade[:, None]
    if hit_g.any():
        p = p_g[hit_g]
        tex = _Texture(seed + 1)(p * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 3.1]), 0.3)
        cool = np.stack([0.08 + 0.45 * tex, 0.25 + 0.55 * tex, 0.35 + 0.5 * tex], -1)
        # the sphere's shadow: the ray towards the light hits the sphere
        bl = p @ LIGHT
        dark = (bl * bl - (np.sum(p * p, 1) - SPHERE_R**2) > 0) & (bl < 0)
        rgb[hit_g] = cool * np.where(dark, shadow, 1.0)[:, None]
    img = rgb.reshape(res, ss, res, ss, 3).mean((1, 3))
    mask = hit_s.reshape(res, ss, res, ss).mean((1, 3)) > 0.5
    return Shot(np.clip(img, 0, 1).astype(np.float32), mask, np.asarray(c2w, np.float64), np.asarray(intr, np.float64))


def shots(n: int, res: int = 256, seed: int = 0, shadow: float = 0.45, **kw) -> list[Shot]:
    """``n`` views (:func:`cameras`, ``kw``) of the scene."""
    return [render(c, k, res, seed=seed, shadow=shadow) for c, k in cameras(n, res=res, seed=seed, **kw)]


def similarity_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama: (s, R, t) minimising |s R src + t - dst|^2 over the rows (N, 3)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a * a).sum(1).mean())
    return s, R, md - s * R @ ms


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1)))
