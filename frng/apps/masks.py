"""Masks for photos that have none and no plain background: a classical segmentation (issue 88).

:func:`frng.apps.capture.make_masks` takes a photo's mask from, in order, ``--masks``, the photo's alpha, a uniform
background keyed out (:func:`frng.apps.capture.key_background`), and only then from :func:`segment`: OpenCV's
GrabCut (colour mixtures of object and background + a graph cut; ``opencv-python-headless``, pinned; no model, no
download). The asset's ``capture.masks`` names the source of each photo's mask (``grabcut:centre``,
``grabcut:sfm-points``) and ``capture.segmentation`` the numbers below.

**Seeds** (:class:`Seeds`, one per photo). The photo starts as probable background; a border ring (:data:`BORDER`
of the shorter side, >= 2 px) is certain background (the object is whole in the photo, as the view selection also
wants):

* ``centre`` (no structure from motion): a disc of probable object, :data:`CORE` of the half shorter side in
  radius, at the image centre (the object is centred and covers it). A loose window instead keeps whatever lies
  inside it and looks unlike the border (a shadow on the table, measured): a seed inside the object lets GrabCut
  grow the object out to its edges;
* ``sfm-points`` (:func:`seeds_from_sfm`, after ``frng reconstruct --sfm``): the keypoints of this photo that
  became sparse points. The plane the object stands on (:func:`support_plane`: the table) is found among the
  points; points on it, and points farther than :data:`FAR` x h from the cameras' common focus (h: the half-width
  of the median camera's field of view at the focus's distance, the largest object that fits in the frame), are
  background the photo itself sees (its own keypoints, so never hidden behind the object): each a disc of certain
  background (:data:`SEED_RADIUS` px at the working size). The other points within :data:`NEAR` x h are the
  object's: their convex hull (the 2 % farthest from their median left out) is probable object, which GrabCut
  grows to the object's edges (a hull grown beforehand took in the shadow at the object's foot: measured). With
  fewer than :data:`MIN_SEEDS` such points the centre disc is used, at the focus's projection.

**Segmentation** (:func:`segment`): GrabCut (:data:`SEG_ITERS` iterations) on the photo resized to at most
:data:`SEG_SIDE` px, seeing the chromaticity (r and g over r + g + b in linear light, which a shadow keeps) and the
sRGB lightness damped by :data:`LIGHTNESS`; the result is cleaned (a 3 x 3 opening; parts smaller than
:data:`KEEP_PART` of the largest dropped; holes smaller than :data:`FILL_HOLE` of the object filled, larger ones,
e.g. seen through a handle, kept) and resized to the photo (bilinear, softened over the resize factor).
Measured on a synthetic sphere with a hard shadow on a textured table, 256 px (``tests/test_capture_masks.py``):
IoU with the true mask >= 0.99 from either seed.

**Refused** (``None`` and the reason; :func:`frng.apps.capture.make_masks` makes it one line naming the photo):
photos under :data:`MIN_SIDE` px; GrabCut finding no object or everything (under :data:`MIN_FRACTION` or over
:data:`MAX_FRACTION` of the photo); an object whose colours are not told from the background's: the total-variation
distance between the colour histograms of object and background (8 bins per sRGB channel) below
:data:`MIN_SEPARATION` (a camouflaged object, or a photo of texture alone: give ``--masks``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from frng import io
from frng.apps.capture_frame import camera_up

SEG_SIDE = 480  # px: GrabCut's working size (long side)
SEG_ITERS = 5
MIN_SIDE = 64  # px: smaller photos are not segmented
BORDER = 0.02  # of the shorter side: certain background
CORE = 0.3  # the centre seed: a disc of this fraction of the half shorter side
NEAR, FAR = 1.0, 1.5  # sparse points near the focus / far from it, in units of the frame's half-width there
SEED_RADIUS = 2  # px at the working size: a far point's disc of certain background
MIN_SEEDS = 8  # near points a photo needs for the points' window
KEEP_PART, FILL_HOLE = 0.1, 0.02
MIN_FRACTION, MAX_FRACTION = 0.002, 0.9
MIN_SEPARATION = 0.35
LIGHTNESS = 0.4  # GrabCut sees the lightness scaled by this towards mid grey (and the chromaticity)
PLANE_TRIALS, PLANE_TOL, PLANE_MIN, PLANE_TILT_DEG = 300, 0.02, 0.2, 25.0


@dataclass
class Seeds:
    """What guides one photo's segmentation, in its pixels (x right, y down, pixel centres at +0.5)."""

    source: str = "centre"  # "centre" | "sfm-points"
    centre: tuple[float, float] | None = None  # the object's centre's projection (None: the image centre)
    near: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (K, 2) keypoints of points near it
    far: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (M, 2) keypoints of far points it sees


def seeds_from_sfm(cset) -> dict[str, Seeds]:
    """Per photo name, the seeds of a structure-from-motion :class:`~frng.apps.camera_formats.CameraSet` (its
    ``points`` and ``observations``; module docstring). Cameras in the model's frame, with their distortion."""
    from frng.benchmarks.common import optical_axes_centre

    cams = dict(cset.cams)
    if not cams or cset.points is None or not cset.observations:
        return {}
    c2ws = np.stack([c.c2w for c in cams.values()])
    focus = optical_axes_centre(c2ws)
    halves = []
    for c in cams.values():
        fx, fy, cx, cy = c.intr
        W, H = c.size if c.size is not None else (2 * cx, 2 * cy)
        halves.append(np.linalg.norm(c.c2w[:3, 3] - focus) * min(W / (2 * fx), H / (2 * fy)))
    h = float(np.median(halves))
    dist = np.linalg.norm(cset.points - focus, axis=1)
    plane = support_plane(cset.points, focus, h, camera_up(c2ws)[0])
    out = {}
    for name, (xy, rows) in cset.observations.items():
        cam = cams.get(name)
        if cam is None:
            continue
        d, on = dist[rows], plane[rows]
        out[name] = Seeds("sfm-points", _project(focus, cam), xy[(d < NEAR * h) & ~on], xy[(d > FAR * h) | on])
    return out


def support_plane(points: np.ndarray, focus: np.ndarray, h: float, up: np.ndarray) -> np.ndarray:
    """Which sparse points lie on the plane the object stands on (N,) bool, all False when there is none: the plane
    (RANSAC, :data:`PLANE_TRIALS` trials, inliers within :data:`PLANE_TOL` x h) holding the most points, if it
    holds :data:`PLANE_MIN` of them, faces the cameras' up (within :data:`PLANE_TILT_DEG`), lies below the focus
    (by more than its tolerance: the top face of a box is no support) and reaches beyond the object (its points
    spread over more than h)."""
    P = np.asarray(points, np.float64)
    none = np.zeros(len(P), bool)
    if len(P) < 30:
        return none
    rng = np.random.default_rng(0)
    tol = PLANE_TOL * h
    best, best_n = none, None
    for _ in range(PLANE_TRIALS):
        a, b, c = P[rng.choice(len(P), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        inl = np.abs((P - a) @ n) < tol
        if inl.sum() > best.sum():
            best, best_n = inl, (n if n @ up > 0 else -n, a)
    if best_n is None or best.sum() < PLANE_MIN * len(P):
        return none
    n, a = best_n
    tilt = math.degrees(math.acos(min(1.0, abs(float(n @ up)))))
    above = float((focus - a) @ n)
    spread = np.ptp(P[best] - np.outer(P[best] @ n, n), axis=0).max()
    if tilt > PLANE_TILT_DEG or above < 2 * tol or spread < h:
        return none
    return best


def _project(p: np.ndarray, cam) -> tuple[float, float] | None:
    """The pixel of world point ``p`` in ``cam`` (a FileCamera, distortion applied), None when behind it."""
    q = (p - cam.c2w[:3, 3]) @ cam.c2w[:3, :3]
    if q[2] <= 1e-9:
        return None
    x, y = q[0] / q[2], q[1] / q[2]
    if cam.distortion is not None:
        xd, yd = cam.distortion.distort(np.array([x]), np.array([y]))
        x, y = float(xd[0]), float(yd[0])
    fx, fy, cx, cy = cam.intr
    return float(fx * x + cx), float(fy * y + cy)


def _features(img8: np.ndarray) -> np.ndarray:
    """What GrabCut sees: chromaticity (r, g over r + g + b, linear light: a shadow keeps its ground's) and the
    lightness damped by :data:`LIGHTNESS`, as 8-bit channels."""
    lin = io.srgb_decode(img8.astype(np.float32) / 255.0) + 1e-3
    chrom = lin[..., :2] / lin.sum(-1, keepdims=True)
    light = img8.astype(np.float32).mean(-1) / 255.0
    out = np.concatenate([chrom * 1.5, (0.5 + LIGHTNESS * (light - 0.5))[..., None]], -1)
    return (np.clip(out, 0, 1) * 255 + 0.5).astype(np.uint8)


def separation(img8: np.ndarray, fg: np.ndarray) -> float:
    """Total-variation distance (0: the same colours, 1: none shared) between the colour histograms (8 bins per
    channel) of the pixels in ``fg`` and the others; ``img8`` (H, W, 3) uint8."""
    q = (img8 >> 5).astype(np.int64)
    idx = (q[..., 0] * 64 + q[..., 1] * 8 + q[..., 2]).ravel()
    m = fg.ravel()
    if m.all() or not m.any():
        return 0.0
    a = np.bincount(idx[m], minlength=512) / m.sum()
    b = np.bincount(idx[~m], minlength=512) / (~m).sum()
    return float(0.5 * np.abs(a - b).sum())


def _clean(fg: np.ndarray) -> np.ndarray:
    """Opening, small parts dropped, small holes filled (module docstring)."""
    from scipy import ndimage

    fg = ndimage.binary_opening(fg, structure=np.ones((3, 3), bool))
    lab, n = ndimage.label(fg)
    if n == 0:
        return fg
    sizes = ndimage.sum(fg, lab, range(1, n + 1))
    fg = np.isin(lab, 1 + np.nonzero(sizes >= KEEP_PART * sizes.max())[0])
    holes, nh = ndimage.label(~fg)
    if nh:
        hs = ndimage.sum(~fg, holes, range(1, nh + 1))
        edge = np.unique(np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]]))
        small = [i + 1 for i, s in enumerate(hs) if s < FILL_HOLE * fg.sum() and (i + 1) not in edge]
        fg = fg | np.isin(holes, small)
    return fg


def segment(rgb: np.ndarray, seeds: Seeds | None = None) -> tuple[np.ndarray | None, dict]:
    """The object's mask in a photo by GrabCut (module docstring).

    rgb (H, W, 3) linear (straight: the photo has no alpha). Returns (alpha (H, W) float32 in [0, 1], info) or
    (None, info) with ``info["reason"]`` when the segmentation is refused."""
    import cv2

    seeds = seeds or Seeds()
    H, W = rgb.shape[:2]
    info: dict = {"source": f"grabcut:{seeds.source}"}
    if min(H, W) < MIN_SIDE:
        return None, info | {"reason": f"the photo is too small to segment ({W}x{H}; at least {MIN_SIDE} px)"}
    k = max(1.0, max(H, W) / SEG_SIDE)
    w, h = max(1, round(W / k)), max(1, round(H / k))
    img = (np.clip(io.srgb_encode(np.clip(rgb, 0.0, None)), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if k > 1:
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    sx, sy = w / W, h / H
    label = np.full((h, w), cv2.GC_PR_BGD, np.uint8)
    near = np.asarray(seeds.near, np.float64).reshape(-1, 2) * [sx, sy]
    far = np.asarray(seeds.far, np.float64).reshape(-1, 2) * [sx, sy]
    b = max(2, int(round(BORDER * min(w, h))))
    if len(near) >= MIN_SEEDS:
        med = np.median(near, 0)
        r = np.linalg.norm(near - med, axis=1)
        keep = near[r <= np.quantile(r, 0.98)]  # a stray point does not stretch the hull
        hull = cv2.convexHull((keep - 0.5).round().astype(np.int32))
        cv2.fillConvexPoly(label, hull, int(cv2.GC_PR_FGD))
        info["window"] = "the hull of the sparse points near the object's centre"
    else:
        cu, cv = (w / 2, h / 2) if seeds.centre is None else (seeds.centre[0] * sx, seeds.centre[1] * sy)
        cu, cv = min(max(cu, 0.25 * w), 0.75 * w), min(max(cv, 0.25 * h), 0.75 * h)
        yy, xx = np.mgrid[0:h, 0:w] + 0.5
        label[np.hypot(xx - cu, yy - cv) < CORE * min(w, h) / 2] = cv2.GC_PR_FGD
        info["window"] = "the central disc" if seeds.centre is None else "a disc at the object's projection"
    for u, v in far:
        cv2.circle(label, (int(round(u - 0.5)), int(round(v - 0.5))), SEED_RADIUS, int(cv2.GC_BGD), -1)
    label[:b], label[-b:], label[:, :b], label[:, -b:] = (cv2.GC_BGD,) * 4
    info |= {"near_points": int(len(near)), "far_points": int(len(far))}
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    try:
        cv2.setRNGSeed(0)
        cv2.grabCut(_features(img), label, None, bgd, fgd, SEG_ITERS, cv2.GC_INIT_WITH_MASK)
    except cv2.error as e:
        return None, info | {"reason": f"GrabCut failed ({str(e).strip().splitlines()[-1][:120]})"}
    fg = _clean((label == cv2.GC_FGD) | (label == cv2.GC_PR_FGD))
    frac = float(fg.mean())
    sep = separation(img, fg)
    info |= {"fraction": round(frac, 4), "separation": round(sep, 3)}
    if frac < MIN_FRACTION:
        return None, info | {"reason": "the segmentation found no object"}
    if frac > MAX_FRACTION:
        return None, info | {"reason": f"the segmentation took {frac:.0%} of the photo for the object"}
    if sep < MIN_SEPARATION:
        return None, info | {
            "reason": f"the object's colours are not told from the background's (separation {sep:.2f} < "
            f"{MIN_SEPARATION})"
        }
    alpha = fg.astype(np.float32)
    if k > 1:
        alpha = cv2.resize(alpha, (W, H), interpolation=cv2.INTER_LINEAR)
        alpha = cv2.GaussianBlur(alpha, (0, 0), sigmaX=0.5 * k)
    return np.clip(alpha, 0.0, 1.0).astype(np.float32), info


__all__ = ["MIN_SEPARATION", "Seeds", "seeds_from_sfm", "segment", "separation"]
