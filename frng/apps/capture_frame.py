"""Upright, centred captures and the choice of views among more photos than the model takes (issue 88).

**Upright** (:func:`camera_up`, :func:`upright_rotation`): the model was trained on an upright rig (world Z up)
and relights in its own frame, so a capture whose world is sideways (LLFF's, COLMAP's arbitrary frame) is turned
upright first. The world's up is, in this order: the camera file's ``up`` (the SfM's gravity, where given); the
direction perpendicular to every camera's right axis (a camera held level has a horizontal right axis, however far
it looks up or down: the smallest eigenvector of sum x x^T over the cameras' unit right axes), signed by the
cameras' mean up vector; or, when the right axes are nearly parallel (their second eigenvalue below
:data:`MIN_SPREAD`), the cameras' mean up vector itself. The world is turned by the smallest rotation that takes
that up to +Z: a world already Z up keeps its frame exactly (and the azimuth is always the user's).

**Centred**: the object's centre is, in this order, the file's own (IDR / NeuS ``scale_mat``: the object's unit
sphere), the sparse points (COLMAP ``points3D``) that fall inside the masks of the views that see them
(:func:`points_centre`: in at least :data:`POINTS_IN_MASK` of the views whose frame they are in, at least two;
then the mean of those within 3 median distances of their median; needs :data:`MIN_POINTS` points), else the
cameras' common focus (the point nearest every optical axis, :func:`frng.apps.capture.common_centre`). The scale
puts the median camera distance at the training rig's (``render.camera_distance``).

**The transform** (:meth:`Frame.record`): ``world_to_asset``, a 4 x 4 similarity, x_asset = M @ [x_user, 1]
(M = [[s R, -s c], [0, 1]]: R the upright rotation, c the centre in the upright frame, s the scale); a camera
maps as c2w_asset = M @ c2w_user with its rotation columns renormalised (divide by s); a render of the asset maps
back to the user's frame with M^-1. A ``--light`` map given in the user's frame is turned into the asset's
(:func:`light_to_asset`).

**View selection** (:func:`select_photos`, :func:`choose_views`): given more photos than the model takes (more
than :data:`frng.apps.capture.MAX_VIEWS`, or ``--select N``), N views (default :data:`RIG_VIEWS`, the training
rig's count) are chosen among the photos that have a camera: the training rig's directions (azimuth 0, 90, 180,
270 deg at elevation 0; 45, 225 deg at 45 deg; first N of them, at the azimuth offset (5 deg steps) that fits best)
are each given one photo by an optimal assignment whose cost is the angle between the photo's direction from the
centre and the rig direction (radians) plus a quality penalty (:func:`quality_penalty`: :data:`W_SHARP` x (1 -
sharpness / the sharpest photo's) + :data:`W_MASK` x (1 - mask size / the median, clipped at 0) + :data:`W_CUT` when
the mask touches the photo's border, i.e. the object is cut off); views beyond the rig's 6 are added farthest
first. Sharpness: the variance of the Laplacian of the luminance over the eroded mask, over the squared mean
luminance, at a common size (longest side :data:`QUALITY_SIDE`). A photo whose mask cannot be made (no --masks, no
alpha, a background that is neither plain nor segmented: :func:`frng.apps.capture.make_masks`) is left out and named
in the line (the asset's ``selection.no_mask``, with the reason) when at least N photos remain; else one error. The
other photos are held out: their names and cameras (in the asset's frame, at their own size) are recorded, and one
line says what was chosen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from frng.apps.camera_formats import CameraSet, FileCamera, undistort_photos
from frng.apps.capture_errors import CaptureError

MIN_SPREAD = 0.01
POINTS_IN_MASK = 0.8
MIN_POINTS = 20
RIG_VIEWS = 6
W_SHARP, W_MASK, W_CUT = 0.35, 0.35, 1.5  # radians of direction error a quality flaw is worth
QUALITY_SIDE = 512


# -- up, rotation, similarity ----------------------------------------------------------------------------------


def camera_up(c2ws: np.ndarray, given=None) -> tuple[np.ndarray, str]:
    """The world's up (unit, in the cameras' frame) and where it came from (module docstring)."""
    c2ws = np.asarray(c2ws, np.float64)
    if given is not None:
        g = np.asarray(given, np.float64)
        return g / np.linalg.norm(g), "the camera file's up"
    ups = -c2ws[:, :3, 1] / np.linalg.norm(c2ws[:, :3, 1], axis=1, keepdims=True)
    mean_up = ups.mean(0)
    x = c2ws[:, :3, 0] / np.linalg.norm(c2ws[:, :3, 0], axis=1, keepdims=True)
    vals, vecs = np.linalg.eigh(x.T @ x / len(x))
    if vals[1] >= MIN_SPREAD:
        up = vecs[:, 0]
        if up @ mean_up < 0:
            up = -up
        return up / np.linalg.norm(up), "perpendicular to the cameras' right axes"
    if np.linalg.norm(mean_up) < 1e-9:
        return np.array([0.0, 0.0, 1.0]), "none (the cameras' up vectors cancel): the file's Z"
    return mean_up / np.linalg.norm(mean_up), "the cameras' mean up vector"


def upright_rotation(up) -> np.ndarray:
    """The smallest rotation (3, 3) taking the unit vector ``up`` to +Z (the identity when it is +Z)."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(u, z)
    s, c = float(np.linalg.norm(v)), float(u @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / (s * s))


def rotate_c2w(c2w: np.ndarray, R: np.ndarray) -> np.ndarray:
    out = np.array(c2w, np.float64)
    out[:3, :] = R @ out[:3, :]
    return out


def similarity(R: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    """world -> asset: x_asset = scale (R x - centre) (``centre`` in the rotated frame) as a 4 x 4 matrix."""
    M = np.eye(4)
    M[:3, :3] = scale * np.asarray(R)
    M[:3, 3] = -scale * np.asarray(centre)
    return M


def to_asset(c2w: np.ndarray, M: np.ndarray) -> np.ndarray:
    """A user-frame OpenCV c2w -> the asset's (module docstring)."""
    M = np.asarray(M, np.float64)
    s = float(np.cbrt(np.linalg.det(M[:3, :3])))
    out = M @ np.asarray(c2w, np.float64)
    out[:3, :3] /= s
    return out


def points_centre(points, cams, alphas) -> tuple[np.ndarray | None, int]:
    """The object's centre from sparse ``points`` (N, 3): those inside the masks (module docstring). ``cams``:
    objects with ``c2w`` and ``intr`` at the size of their ``alphas`` (H, W). Returns (centre or None, points used)."""
    P = np.asarray(points, np.float64)
    seen = np.zeros(len(P), int)
    inside = np.zeros(len(P), int)
    for cam, a in zip(cams, alphas):
        c2w = np.asarray(cam.c2w, np.float64)
        q = (P - c2w[:3, 3]) @ c2w[:3, :3]
        z = q[:, 2]
        fx, fy, cx, cy = cam.intr
        zs = np.where(z > 1e-9, z, 1.0)
        u, v = fx * q[:, 0] / zs + cx, fy * q[:, 1] / zs + cy
        H, W = a.shape
        ok = (z > 1e-9) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        seen += ok
        iu = np.clip(u, 0, W - 1).astype(int)
        iv = np.clip(v, 0, H - 1).astype(int)
        inside += ok & (a[iv, iu] > 0.5)
    keep = (seen >= 2) & (inside >= POINTS_IN_MASK * seen)
    if keep.sum() < MIN_POINTS:
        return None, int(keep.sum())
    Q = P[keep]
    med = np.median(Q, 0)
    d = np.linalg.norm(Q - med, axis=1)
    Q = Q[d <= 3 * max(float(np.median(d)), 1e-12)]
    return Q.mean(0), len(Q)


def rotate_envmap(env: np.ndarray, R: np.ndarray) -> np.ndarray:
    """An equirect map turned by the rotation ``R``: E'(R d) = E(d) (bilinear, wrapping in azimuth)."""
    import torch
    from scipy import ndimage

    from frng.render import envmap

    H, W = env.shape[:2]
    d = envmap.pixel_directions(H, W, dtype=torch.float64).numpy()
    src = d @ np.asarray(R, np.float64)  # R^T d' for each row
    u, v = envmap.dir_to_uv(torch.from_numpy(src))
    x = u.numpy() * W - 0.5
    y = np.clip(v.numpy() * H - 0.5, 0, H - 1)
    pad = np.concatenate([env[:, -1:], env, env[:, :1]], 1)
    xs = np.mod(x + 0.5, W) + 0.5  # in the padded map: column 0 is column W - 1
    return np.stack(
        [ndimage.map_coordinates(pad[..., c], [y, xs], order=1, mode="nearest") for c in range(env.shape[-1])], -1
    ).astype(np.float32)


def light_to_asset(env: np.ndarray, world_to_asset) -> np.ndarray:
    """A map given in the user's frame, in the asset's (unchanged when the world was upright already)."""
    M = np.asarray(world_to_asset, np.float64)
    R = M[:3, :3] / float(np.cbrt(np.linalg.det(M[:3, :3])))
    return env if np.allclose(R, np.eye(3), atol=1e-9) else rotate_envmap(env, R)


# -- the frame of a capture ------------------------------------------------------------------------------------


@dataclass
class Selection:
    """Which photos are the views (``chosen``, in file order) and which are held out, with one summary line."""

    names: list[str]  # every photo, file order
    chosen: list[str]
    held_out: list[str]
    sizes: dict[str, tuple[int, int]]
    summary: str
    cset: CameraSet
    scores: dict = field(default_factory=dict)
    cover: dict = field(default_factory=dict)
    no_mask: dict[str, str] = field(default_factory=dict)  # photos left out: no mask could be made (name -> why)


@dataclass
class Frame:
    """A capture's cameras turned upright (and undistorted), and the rest of the user -> asset transform."""

    cset: CameraSet
    R: np.ndarray
    up: np.ndarray
    up_source: str
    assigned: dict[str, FileCamera]
    undistorted: dict
    selection: Selection | None = None
    centre_source: str = "the cameras' common focus"

    @classmethod
    def build(cls, cset: CameraSet, photos, selection: Selection | None = None) -> Frame:
        """Match cameras to photos (all the folder's photos with a selection), undistort the loaded ``photos`` in
        place, and turn the cameras upright (the up from every camera of the file)."""
        names = selection.names if selection is not None else [p.name for p in photos]
        assigned = cset.assign(names)
        undone = undistort_photos(photos, assigned, cset.path)
        up, source = camera_up(np.stack([c.c2w for _, c in cset.cams]), cset.up)
        R = upright_rotation(up)
        turned = {n: FileCamera(rotate_c2w(c.c2w, R), c.intr, c.size, c.distortion) for n, c in assigned.items()}
        return cls(cset, R, up, source, turned, undone, selection)

    @property
    def cameras(self) -> list[tuple[str, FileCamera]]:
        """[(photo name, camera)] in the upright frame, for :func:`frng.apps.capture.match_cameras`."""
        return list(self.assigned.items())

    def object_centre(self, cams, photos, focus: np.ndarray) -> np.ndarray:
        """The object's centre in the upright frame (module docstring); ``focus``: the cameras' common focus."""
        if self.cset.centre is not None:
            self.centre_source = self.cset.centre_source
            return self.R @ self.cset.centre
        if self.cset.points is not None:
            c, n = points_centre(self.cset.points @ self.R.T, cams, [p.alpha for p in photos])
            if c is not None:
                self.centre_source = f"{n} of {len(self.cset.points)} sparse points, inside the masks"
                return c
            self.centre_source = f"the cameras' common focus (only {n} sparse points inside the masks)"
        return np.asarray(focus, np.float64)

    def record(self, centre: np.ndarray, scale: float) -> dict:
        """The capture record's frame fields (module docstring), the held-out views' cameras among them."""
        M = similarity(self.R, centre, scale)
        rec = {
            "camera_format": self.cset.format,
            "up": {"vector": self.up.tolist(), "source": self.up_source},
            "centre_source": self.centre_source,
            "world_to_asset": M.tolist(),
        }
        if self.undistorted:
            rec["undistorted"] = self.undistorted
        sel = self.selection
        if sel is not None:
            held = []
            for n in sel.held_out:
                c = self.assigned[n]
                W, H = sel.sizes[n]
                intr = np.asarray(c.intr, np.float64)
                if c.size is not None and tuple(c.size) != (W, H):
                    intr = intr * np.array([W / c.size[0], H / c.size[1], W / c.size[0], H / c.size[1]])
                c2w = np.array(c.c2w)
                c2w[:3, 3] = (c2w[:3, 3] - centre) * scale
                held.append(
                    {
                        "name": n,
                        "c2w": c2w.tolist(),
                        "intrinsics": intr.tolist(),
                        "width": int(W),
                        "height": int(H),
                        **(
                            {"distortion": c.distortion.named() | {"model": c.distortion.model}} if c.distortion else {}
                        ),
                    }
                )
            rec["selection"] = {
                "chosen": list(sel.chosen),
                "held_out": list(sel.held_out),
                "summary": sel.summary,
                "coverage": sel.cover,
                "scores": sel.scores,
                "no_mask": dict(sel.no_mask),
            }
            rec["held_out_cameras"] = held
        return rec


# -- view selection --------------------------------------------------------------------------------------------


def photo_quality(rgb: np.ndarray, alpha: np.ndarray) -> dict:
    """Sharpness, mask size (fraction of the photo) and whether the mask touches the border (module docstring)."""
    from scipy import ndimage

    H, W = alpha.shape
    k = max(1, math.ceil(max(H, W) / QUALITY_SIDE))
    h, w = H // k, W // k
    y = rgb[: h * k, : w * k].mean(-1).reshape(h, k, w, k).mean((1, 3))
    a = alpha[: h * k, : w * k].reshape(h, k, w, k).mean((1, 3))
    m = a > 0.5
    inner = ndimage.binary_erosion(m, iterations=2)
    if inner.sum() < 16:
        sharp = 0.0
    else:
        lap = ndimage.laplace(y.astype(np.float64))
        sharp = float(lap[inner].var() / max(float(y[inner].mean()) ** 2, 1e-12))
    ring = np.concatenate([m[0], m[-1], m[:, 0], m[:, -1]])
    return {"sharpness": sharp, "mask_fraction": float(m.mean()), "cut": bool(ring.mean() > 0.005)}


def quality_penalty(qualities: list[dict]) -> np.ndarray:
    """Per photo, in radians of direction error (module docstring)."""
    sharp = np.array([q["sharpness"] for q in qualities], np.float64)
    frac = np.array([q["mask_fraction"] for q in qualities], np.float64)
    cut = np.array([q["cut"] for q in qualities], np.float64)
    rel_sharp = sharp / sharp.max() if sharp.max() > 0 else np.ones_like(sharp)
    med = float(np.median(frac))
    rel_mask = np.minimum(1.0, frac / med) if med > 0 else np.ones_like(frac)
    return W_SHARP * (1 - rel_sharp) + W_MASK * (1 - rel_mask) + W_CUT * cut


def rig_directions() -> np.ndarray:
    """The training rig's unit view directions (from the centre towards the cameras), in rig order."""
    from frng import camera
    from frng.data.rig import RIG_AZIMUTH_OFFSETS_DEG, RIG_ELEVATIONS_DEG

    return np.stack(
        [camera.spherical_to_cartesian(a, e, 1.0) for a, e in zip(RIG_AZIMUTH_OFFSETS_DEG, RIG_ELEVATIONS_DEG)]
    )


def choose_views(dirs: np.ndarray, penalty: np.ndarray, n: int) -> tuple[list[int], dict]:
    """Indices of ``n`` photos (rig slot order, then farthest first) given their unit directions from the centre
    (upright frame, (N, 3)) and quality penalties (N,); and how well they cover the rig."""
    from scipy.optimize import linear_sum_assignment

    dirs = np.asarray(dirs, np.float64)
    base = rig_directions()
    k = min(n, len(base))
    best = None
    for phi in np.arange(0.0, 360.0, 5.0):
        c, s = math.cos(math.radians(phi)), math.sin(math.radians(phi))
        slots = base[:k] @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # rotated by phi about Z
        ang = np.arccos(np.clip(dirs @ slots.T, -1.0, 1.0))
        cost = ang + penalty[:, None]
        r, col = linear_sum_assignment(cost)
        total = float(cost[r, col].sum())
        if best is None or total < best[0] - 1e-9:
            order = np.argsort(col)
            best = (total, phi, [int(i) for i in r[order]], ang[r[order], col[order]])
    _, phi, chosen, ang = best
    while len(chosen) < n:
        rest = [i for i in range(len(dirs)) if i not in chosen]
        gap = np.arccos(np.clip(dirs[rest] @ dirs[chosen].T, -1.0, 1.0)).min(1)
        chosen.append(rest[int(np.argmax(gap - penalty[rest]))])
    return chosen, {"rig_azimuth_deg": float(phi), "worst_deg": float(np.degrees(ang.max()))}


def select_photos(
    images,
    cameras,
    files: list[Path],
    *,
    select: int | None,
    load,
    read_set,
    min_views: int,
    max_views: int,
) -> Selection | None:
    """The views among ``files`` (module docstring), or None when every photo is a view (no more than
    ``max_views`` and no ``select``). ``load(file)``: the photo with its mask (``.name``, ``.size``, ``.rgb``,
    ``.alpha``); ``read_set(cameras, sizes)``: the :class:`~frng.apps.camera_formats.CameraSet`."""
    from frng.benchmarks.common import optical_axes_centre

    if select is None and len(files) <= max_views:
        return None
    n = RIG_VIEWS if select is None else int(select)
    if not min_views <= n <= max_views:
        raise CaptureError(f"--select {n}: the model takes {min_views}-{max_views} views")
    if n > len(files):
        raise CaptureError(f"{images}: --select {n}, but the folder holds {len(files)} images")
    qualities, sizes, no_mask = [], {}, {}
    for f in files:
        try:
            p = load(f)
        except CaptureError as e:  # no mask for this photo (segmentation refused): left out when enough remain
            no_mask[f.stem] = str(e)
            continue
        sizes[p.name] = p.size
        qualities.append(photo_quality(p.rgb, p.alpha))
        del p
    names = [f.stem for f in files if f.stem not in no_mask]
    if len(names) < n:
        first = next(iter(no_mask.values()))
        raise CaptureError(
            f"{images}: {len(no_mask)} of {len(files)} photos have no mask, {len(names)} left for {n} views; "
            f"the first: {first}"
        )
    cset = read_set(Path(cameras), sizes)
    assigned = cset.assign(names)
    R = upright_rotation(camera_up(np.stack([c.c2w for _, c in cset.cams]), cset.up)[0])
    c2ws = np.stack([rotate_c2w(assigned[nm].c2w, R) for nm in names])
    centre = optical_axes_centre(c2ws)
    d = c2ws[:, :3, 3] - centre
    dirs = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    pen = quality_penalty(qualities)
    idx, cover = choose_views(dirs, pen, n)
    chosen = [names[i] for i in sorted(idx)]
    held = [nm for nm in names if nm not in chosen]
    summary = (
        f"{images}: {n} of {len(names)} photos chosen as views (the training rig's directions, worst "
        f"{cover['worst_deg']:.0f} deg off; sharpness; mask size): {', '.join(chosen)}; {len(held)} held out"
        + (f"; {len(no_mask)} left out, no mask: {', '.join(no_mask)}" if no_mask else "")
    )
    scores = {
        nm: {**q, "penalty": round(float(pe), 4), "elevation_deg": round(math.degrees(math.asin(dz)), 1)}
        for nm, q, pe, dz in zip(names, qualities, pen, np.clip(dirs[:, 2], -1, 1))
    }
    return Selection(names, chosen, held, sizes, summary, cset, scores, cover, no_mask)


__all__ = [
    "Frame",
    "MIN_POINTS",
    "RIG_VIEWS",
    "Selection",
    "camera_up",
    "choose_views",
    "light_to_asset",
    "photo_quality",
    "points_centre",
    "quality_penalty",
    "rig_directions",
    "rotate_envmap",
    "select_photos",
    "similarity",
    "to_asset",
    "upright_rotation",
]
