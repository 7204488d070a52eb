"""What every benchmark importer shares: the in-memory scene, the conversion into the dataset contract, and
the input checks.

A reader (``frng.benchmarks.<layout>.read``) turns a benchmark folder into a :class:`Scene`: views with OpenCV
cameras (4x4 camera-to-world + fx, fy, cx, cy at the files' own resolution) in the benchmark's world frame, their
images as linear straight-alpha RGB + mask arrays, and the lights as equirect maps already converted to
:mod:`frng.render.envmap`'s (Blender's) convention and to the benchmark's world frame. Each module's docstring says how
its files map to that, citing the official loader. :func:`write_object` then converts once:

- **Input views** (``in_00 .. in_05``, then ``in_06 ..`` up to ``render.extra_input_views`` more): chosen from the
  benchmark's TRAINING views, rig-like (:func:`select_rig`): the 6 rig directions of :mod:`frng.data.rig`
  (azimuths a0 + 0/90/180/270 deg at 0 deg elevation, a0 + 45/225 deg at 45 deg), a0 = the azimuth of the first
  training view in file order; each rig direction takes the unused training view whose direction from the object
  centre is closest (largest dot product); the extra views are then picked farthest-point (largest minimum angle
  to the views already taken). Deterministic: ties go to the earlier file.
- **Target views** (``tgt_000 ..``): the benchmark's test (relighting) views, one per camera in file order,
  under their lights (``targets/{light}/{view}.exr``).
  Benchmarks with one light per test view (Stanford-ORB, OWL) list the (light, view) pairs that have a ground
  truth in ``meta.json`` ``benchmark.pairs``; the relighting stage renders every target view under every target
  light, and the benchmark evaluation scores only those pairs.
- **World normalisation**: centre = the least-squares point closest to every camera's optical axis; radius = the
  largest, over the views, of ``|centre - camera| sin(a)`` with ``a`` the widest angle between the ray to the
  centre and the rays through the view's mask pixels (the bounding cone of the silhouette). World points map as
  ``x' = s R (x - c)`` with ``s = 1 / radius`` (``R`` = identity unless the reader sets ``world_rotation``: OWL
  uses it to make its env frame, Z up, the world). The 4x4 ``source_to_world`` is recorded in ``meta.json``
  (``benchmark.source_to_world``), so any point of the benchmark's frame maps to the imported object's.
- **Images**: centre-cropped to a square around the mask's bounding-box centre when not square, resampled to
  ``render.resolution`` by area averaging (intrinsics scaled and shifted accordingly), written as linear float32
  premultiplied RGBA EXR with alpha = the mask (the contract of ``config/README.md``, "Dataset layout on disk").
- **Lights**: each map resized to ``envmaps.width`` and written to ``{results}/envmaps/{light}.exr`` (where
  :mod:`frng.apps.relight` reads every light), light names prefixed by the object id.

Nothing half-imported looks complete: the object is written to ``objects/.tmp-{id}-*`` (its lights too, in a
``.envmaps/`` folder there) and moved into place once everything is written (``meta.json`` last): the lights first,
the previous ones kept aside until the object folder is swapped in, so a failed re-import (a full disk) leaves the
previous import whole, lights included. Any bad input raises :class:`BenchmarkError` with one line naming the file,
before anything is written. Names from the files (light and scene names) are sanitised to ``[a-z0-9_-]``
(:func:`frng.confine.safe_id`) before they become file names; cameras and intrinsics must be finite.
"""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from frng import confine, io
from frng.benchmarks.plan import BenchmarkError, object_id  # noqa: F401
from frng.plan.layout import Layout, ObjectFolder
from frng.render import envmap

RIG = ((0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (270.0, 0.0), (45.0, 45.0), (225.0, 45.0))  # frng.data.rig


@dataclass
class View:
    """One benchmark view: OpenCV camera in the benchmark's world frame, linear straight-alpha image."""

    name: str
    c2w: np.ndarray  # (4, 4) OpenCV camera-to-world, benchmark world frame
    K: np.ndarray  # (4,) fx, fy, cx, cy in pixels of ``rgb``
    rgb: np.ndarray  # (H, W, 3) linear, straight (not premultiplied)
    mask: np.ndarray  # (H, W) in [0, 1]
    light: str  # the light it was captured/rendered under
    source: str  # the file it came from
    exposure: float | None = None  # OWL: the exposure of its tone mapping


@dataclass
class Scene:
    """A benchmark scene as read from disk (see the module docstring)."""

    layout: str  # tensoir, orb, owl, nerf-synthetic
    scene: str  # the benchmark's scene name
    path: str  # the folder it was read from
    protocol: str  # frng.benchmarks.protocols name
    train: list[View]
    test: list[View]
    lights: dict[str, np.ndarray]  # name -> (H, 2H, 3) equirect, frng.render.envmap convention, benchmark world frame
    input_light: str
    world_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # applied before normalisation
    notes: dict = field(default_factory=dict)


# -- small readers shared by the layouts ------------------------------------------------------------------------


def need(path: Path, what: str = "file") -> Path:
    path = Path(path)
    if not path.exists():
        raise BenchmarkError(f"{path}: missing {what}")
    return path


def read_json(path: Path) -> dict:
    need(path)
    try:
        return io.read_json(path)
    except ValueError as e:
        raise BenchmarkError(str(e)) from e


def read_png(path: Path) -> np.ndarray:
    need(path, "image")
    try:
        return io.read_png(path)
    except io.ImageError as e:
        raise BenchmarkError(str(e)) from e


def read_srgba_png(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """An 8/16-bit sRGB PNG with straight alpha (NeRF-synthetic, TensoIR) -> (linear rgb, alpha)."""
    img = read_png(path)
    if img.ndim != 3 or img.shape[-1] != 4:
        raise BenchmarkError(f"{path}: expected an RGBA PNG, got shape {img.shape}")
    return io.srgb_decode(img[..., :3]), img[..., 3].astype(np.float32)


def write_srgba_png(path: Path, rgba: np.ndarray) -> None:
    """Linear premultiplied RGBA -> straight-alpha sRGB RGBA PNG (8 bit), as Blender writes film-transparent PNGs."""
    a = rgba[..., 3:4]
    rgb = np.where(a > 1e-6, rgba[..., :3] / np.maximum(a, 1e-6), 0.0)
    io.write_png(path, np.concatenate([io.srgb_encode(rgb), np.clip(a, 0, 1)], -1))


def read_mask_png(path: Path) -> np.ndarray:
    m = read_png(path)
    if m.ndim == 3:
        m = m[..., 1] if m.shape[-1] >= 3 else m[..., 0]  # OWL's evaluate.py reads the green channel
    return m.astype(np.float32)


def read_exr_rgb(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    need(path, "image")
    try:
        ch = io.read_exr_channels(path)
    except io.ImageError as e:
        raise BenchmarkError(str(e)) from e
    if not all(c in ch for c in "RGB"):
        raise BenchmarkError(f"{path}: expected R, G, B channels; has {sorted(ch)}")
    return np.stack([ch[c] for c in "RGB"], -1), ch.get("A")


def read_map(path: Path) -> np.ndarray:
    """An equirect map (.exr/.hdr) as stored; 2:1 checked (one line naming the file)."""
    need(path, "environment map")
    try:
        return envmap.read(path)
    except envmap.EnvMapError as e:
        raise BenchmarkError(str(e)) from e


def same_size(views: list[View]) -> None:
    """Every image of a split must have the same size as its mask (and the benchmarks ship one size per scene)."""
    for v in views:
        if v.rgb.shape[:2] != v.mask.shape[:2]:
            raise BenchmarkError(
                f"{v.source}: image is {v.rgb.shape[1]}x{v.rgb.shape[0]} but its mask is "
                f"{v.mask.shape[1]}x{v.mask.shape[0]}"
            )
    sizes = {v.rgb.shape[:2] for v in views}
    if len(sizes) > 1:
        first = views[0]
        odd = next(v for v in views if v.rgb.shape[:2] != first.rgb.shape[:2])
        raise BenchmarkError(
            f"{odd.source}: image is {odd.rgb.shape[1]}x{odd.rgb.shape[0]}, the scene's "
            f"{first.source} is {first.rgb.shape[1]}x{first.rgb.shape[0]} (images of different "
            f"sizes)"
        )


# -- env maps: direction look-ups -------------------------------------------------------------------------------


def map_directions(height: int) -> np.ndarray:
    """World direction (H, 2H, 3) of every pixel centre of a map in frng.render.envmap's convention."""
    return envmap.pixel_directions(height, 2 * height, dtype=__import__("torch").float64).numpy()


def sample_map(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear look-up of an equirect map at (u, v) in [0, 1) (pixel centres at (i + 0.5) / n), u periodic."""
    H, W = image.shape[:2]
    x = u * W - 0.5
    y = np.clip(v * H - 0.5, 0, H - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    tx = (x - x0)[..., None]
    ty = (y - y0)[..., None]
    x0m, x1m = x0 % W, (x0 + 1) % W
    y1 = np.minimum(y0 + 1, H - 1)
    top = (1 - tx) * image[y0, x0m] + tx * image[y0, x1m]
    bot = (1 - tx) * image[y1, x0m] + tx * image[y1, x1m]
    return ((1 - ty) * top + ty * bot).astype(np.float32)


def blender_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """frng.render.envmap's dir -> (u, v), numpy."""
    u = np.remainder(0.5 - np.arctan2(d[..., 1], d[..., 0]) / (2 * math.pi), 1.0)
    v = np.arccos(np.clip(d[..., 2], -1, 1)) / math.pi
    return u, v


def rotate_map(image: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The map seen in a frame rotated by R: ``E'(d) = E(R^T d)`` (R maps the old frame's directions to the new)."""
    d = map_directions(image.shape[0]) @ np.asarray(R, dtype=np.float64)  # row vectors: (R^T d)^T = d^T R
    return sample_map(image, *blender_uv(d))


# -- geometry ---------------------------------------------------------------------------------------------------


def optical_axes_centre(c2ws: np.ndarray) -> np.ndarray:
    """Least-squares point closest to every camera's optical axis (OpenCV +z)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c2w in c2ws:
        d = c2w[:3, 2] / np.linalg.norm(c2w[:3, 2])
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c2w[:3, 3]
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:  # all axes parallel: the mean camera position pushed along the axis is unknown
        return np.mean([c[:3, 3] for c in c2ws], 0)


def silhouette_radius(view: View, centre: np.ndarray) -> float:
    """``|c - o| sin(a)``, a = widest angle between the ray to the centre and the rays through mask pixels."""
    ys, xs = np.nonzero(view.mask > 0.5)
    o = view.c2w[:3, 3]
    to_c = centre - o
    dist = float(np.linalg.norm(to_c))
    if len(xs) == 0 or dist == 0:
        return 0.0
    fx, fy, cx, cy = view.K
    d = np.stack([(xs + 0.5 - cx) / fx, (ys + 0.5 - cy) / fy, np.ones_like(xs, dtype=np.float64)], -1)
    d = d @ view.c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cos = np.clip(d @ (to_c / dist), -1, 1).min()
    return dist * math.sin(math.acos(cos)) if cos > 0 else dist


def normalisation(scene: Scene) -> np.ndarray:
    """The 4x4 ``source_to_world`` similarity ``x' = s R (x - c)`` (see the module docstring)."""
    views = scene.train + scene.test
    R = np.asarray(scene.world_rotation, dtype=np.float64)
    c = optical_axes_centre(np.stack([v.c2w for v in views]))
    radius = max(silhouette_radius(v, c) for v in views)
    if not radius > 0:
        raise BenchmarkError(f"{scene.path}: every mask is empty; cannot place the object")
    s = 1.0 / radius
    T = np.eye(4)
    T[:3, :3] = s * R
    T[:3, 3] = -s * R @ c
    return T


def transform_camera(c2w: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Camera-to-world after the similarity T (rotation part kept orthonormal)."""
    s = np.cbrt(np.linalg.det(T[:3, :3]))
    R = T[:3, :3] / s
    out = np.eye(4)
    out[:3, :3] = R @ c2w[:3, :3]
    out[:3, 3] = T[:3, :3] @ c2w[:3, 3] + T[:3, 3]
    return out


def direction_of(c2w: np.ndarray) -> np.ndarray:
    p = c2w[:3, 3]
    return p / max(np.linalg.norm(p), 1e-12)


def select_rig(c2ws: list[np.ndarray], n_extra: int = 0) -> list[int]:
    """Indices of the input views: the 6 rig directions, then ``n_extra`` farthest-point (see the docstring).
    ``c2ws`` are in the normalised world (object at the origin, Z up)."""
    if len(c2ws) < 6:
        raise BenchmarkError(f"need at least 6 training views for the 6-view rig, the benchmark has {len(c2ws)}")
    dirs = np.stack([direction_of(c) for c in c2ws])
    a0 = math.degrees(math.atan2(dirs[0, 1], dirs[0, 0]))
    chosen: list[int] = []
    for az, el in RIG:
        a, e = math.radians(a0 + az), math.radians(el)
        target = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        score = dirs @ target
        score[chosen] = -np.inf
        chosen.append(int(np.argmax(score)))
    for _ in range(min(n_extra, len(c2ws) - 6)):
        cos = dirs @ dirs[chosen].T  # (N, k)
        worst = cos.max(1)
        worst[chosen] = np.inf
        chosen.append(int(np.argmin(worst)))
    return chosen


# -- images -----------------------------------------------------------------------------------------------------


def square_crop(view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb, mask, K) cropped to a square around the mask's bounding-box centre (clamped to the image)."""
    H, W = view.mask.shape
    K = np.asarray(view.K, dtype=np.float64).copy()
    if H == W:
        return view.rgb, view.mask, K
    n = min(H, W)
    ys, xs = np.nonzero(view.mask > 0.5)
    cy, cx = ((ys.min() + ys.max()) / 2, (xs.min() + xs.max()) / 2) if len(xs) else (H / 2, W / 2)
    y0 = int(np.clip(round(cy - n / 2), 0, H - n))
    x0 = int(np.clip(round(cx - n / 2), 0, W - n))
    K[2] -= x0
    K[3] -= y0
    return view.rgb[y0 : y0 + n, x0 : x0 + n], view.mask[y0 : y0 + n, x0 : x0 + n], K


def area_resize(img: np.ndarray, size: int) -> np.ndarray:
    """Area-average resize of a square (n, n, C) image to (size, size, C) (exact box filter when n % size == 0)."""
    n = img.shape[0]
    if n == size:
        return img.astype(np.float32)
    if n % size == 0:
        f = n // size
        return img.reshape(size, f, size, f, -1).mean((1, 3)).astype(np.float32)
    from skimage.transform import resize

    return resize(img, (size, size, img.shape[-1]), order=1, anti_aliasing=True, preserve_range=True).astype(np.float32)


def to_contract(view: View, res: int) -> tuple[np.ndarray, np.ndarray]:
    """(premultiplied linear RGBA (res, res, 4), K at res)."""
    rgb, mask, K = square_crop(view)
    n = mask.shape[0]
    rgba = np.concatenate([rgb * mask[..., None], mask[..., None]], -1)
    out = area_resize(rgba, res)
    K = K * (res / n)
    return out, K


# -- the writer -------------------------------------------------------------------------------------------------


def write_object(
    scene: Scene,
    results: str | Path,
    resolution: int,
    envmap_width: int,
    extra_inputs: int = 0,
    max_targets: int | None = None,
    oid: str | None = None,
    pairs: list[tuple[str, str]] | None = None,
) -> Path:
    """Write ``scene`` into ``{results}/objects/{oid}`` (+ its lights into ``{results}/envmaps/``); returns the
    object folder. See the module docstring for every conversion."""
    from frng.benchmarks.plan import scene_name

    oid = confine.check_id(oid or object_id(scene.layout, scene_name(scene.layout, scene.path)), "object id")
    L = Layout(results)
    same_size(scene.train)
    same_size(scene.test)
    if not scene.test:
        raise BenchmarkError(f"{scene.path}: no test views found")
    for v in scene.train + scene.test:  # NaN/inf cameras would pass as "every mask is empty" or NaN intrinsics
        confine.finite(v.c2w, source=v.source, field="camera-to-world", shape=(4, 4))
        confine.finite(v.K[:2], source=v.source, field="focal length", positive=True)
        confine.finite(v.K[2:], source=v.source, field="principal point")
    T = normalisation(scene)
    for v in scene.train + scene.test:
        v.c2w = transform_camera(v.c2w, T)
    R = T[:3, :3] / np.cbrt(np.linalg.det(T[:3, :3]))
    rig = select_rig([v.c2w for v in scene.train], extra_inputs)
    keep = list(dict.fromkeys(v.name for v in scene.test))[:max_targets] if max_targets else None
    tests = [v for v in scene.test if keep is None or v.name in keep]
    light_name = {name: f"{oid}_{confine.safe_id(name, source=scene.path, field='light')}" for name in scene.lights}
    if len(set(light_name.values())) != len(light_name):
        raise BenchmarkError(f"{scene.path}: light names {sorted(scene.lights)} are not distinct once sanitised")
    in_light = light_name[scene.input_light]
    target_lights = list(dict.fromkeys(light_name[v.light] for v in tests))

    objects = Path(L.objects_dir())
    objects.mkdir(parents=True, exist_ok=True)
    final = objects / oid
    stage = io.temp_dir(f".tmp-{oid}-", objects)
    staged_maps: list[tuple[Path, Path]] = []  # (staged, final)
    try:
        F = ObjectFolder(stage)
        views_in, views_tgt = [], []
        for k, idx in enumerate(rig):
            v = scene.train[idx]
            name = f"in_{k:02d}"
            rgba, K = to_contract(v, resolution)
            io.write_exr(F.image("inputs", in_light, name), rgba, channels=["R", "G", "B", "A"])
            views_in.append(_camera(name, "input", v, K, resolution))
        gt_pairs, tgt_names, exposures = [], {}, {}
        for v in tests:  # one target view per camera (view name); a camera seen under several lights repeats
            if v.name not in tgt_names:
                tgt_names[v.name] = f"tgt_{len(tgt_names):03d}"
                rgba, K = to_contract(v, resolution)
                views_tgt.append(_camera(tgt_names[v.name], "target", v, K, resolution))
            else:
                rgba, _ = to_contract(v, resolution)
            name = tgt_names[v.name]
            io.write_exr(F.image("targets", light_name[v.light], name), rgba, channels=["R", "G", "B", "A"])
            gt_pairs.append([light_name[v.light], name])
            if v.exposure is not None:
                exposures[f"{light_name[v.light]}/{name}"] = v.exposure
        per_view_light = len(gt_pairs) < len(target_lights) * len(tgt_names)
        lights = {}
        for name, img in scene.lights.items():
            rotate = not np.allclose(R, np.eye(3)) and not scene.notes.get("lights_in_world_frame")
            world = rotate_map(img, R) if rotate else img
            if world.shape[1] != envmap_width:
                world = envmap.resize(world, envmap_width)
            path = Path(L.envmap(light_name[name]))
            lights[light_name[name]] = {
                "base": name,
                "source": "benchmark",
                "split": "test",
                "rotation_deg": 0.0,
                "licence": f"{scene.layout} benchmark",
                "scale": 1.0,
                "file": os.path.relpath(path, results),
            }
            staged = stage / ".envmaps" / path.name
            envmap.write(staged, world)
            staged_maps.append((staged, path))
        meta = {
            "id": oid,
            "split": "test",
            "seed": 0,
            "source": "benchmark",
            "mesh": None,
            "licence": f"{scene.layout} benchmark (see its licence)",
            "up_axis": "z",
            "material_class": scene.layout,
            "render": {"resolution": resolution},
            "input_lights": [in_light],
            "target_lights": target_lights,
            "lights": lights,
            "views": {"inputs": views_in, "targets": views_tgt},
            "benchmark": {
                "layout": scene.layout,
                "scene": scene.scene,
                "path": str(Path(scene.path).resolve()),
                "protocol": scene.protocol,
                "source_to_world": T.tolist(),
                "input_views_from": [scene.train[i].source for i in rig],
                "input_view_rule": "6-view rig directions (frng.data.rig) matched to the nearest training views, "
                "then farthest-point extra views (frng.benchmarks.common.select_rig)",
                "pairs": pairs or gt_pairs,
                "per_view_light": per_view_light,
                "exposures": exposures,
                **scene.notes,
            },
        }
        io.write_json(F.meta(), meta)
        _commit(stage, final, staged_maps)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return final


def _commit(stage: Path, final: Path, maps: list[tuple[Path, Path]]) -> None:
    """Move the staged lights into the envmaps folder and the staged object folder to ``final`` (renames only, no
    new bytes: nothing to fail on a full disk); the previous maps and folder are kept aside until both are in place
    and put back if a rename fails."""
    aside = io.temp_dir(f".old-{final.name}-", final.parent)
    moved: list[tuple[Path, Path | None]] = []  # (final map, its previous version aside or None)
    try:
        for k, (staged, path) in enumerate(maps):
            path.parent.mkdir(parents=True, exist_ok=True)
            old = None
            if path.exists():
                old = aside / f"{k}{path.suffix}"
                os.replace(path, old)
            moved.append((path, old))
            os.replace(staged, path)
        if (stage / ".envmaps").exists():
            shutil.rmtree(stage / ".envmaps")
        if final.exists():
            os.replace(final, aside / "object")
        try:
            os.replace(stage, final)
        except BaseException:
            if (aside / "object").exists():
                os.replace(aside / "object", final)
            raise
    except BaseException:
        for path, old in reversed(moved):
            if old is not None:
                os.replace(old, path)
            else:
                path.unlink(missing_ok=True)
        raise
    finally:
        shutil.rmtree(aside, ignore_errors=True)


def _camera(name: str, kind: str, v: View, K: np.ndarray, res: int) -> dict:
    return {
        "name": name,
        "kind": kind,
        "c2w": np.asarray(v.c2w, dtype=float).tolist(),
        "intrinsics": [float(x) for x in K],
        "width": res,
        "height": res,
        "source": v.source,
    }


# -- exporting: what a curated object offers -------------------------------------------------------------------


@dataclass
class Curated:
    """A curated object read for export: cameras in OpenCV, images linear premultiplied RGBA."""

    oid: str
    inputs: list[dict]  # meta views (name, c2w, intrinsics, width, height)
    targets: list[dict]
    input_light: str
    target_lights: list[str]
    extra: list[dict]  # input views beyond the rig (in_06 ..)
    image: callable  # (kind, light, view) -> (H, W, 4)
    envmap: callable  # light -> (H, 2H, 3)


def open_curated(results: str | Path, oid: str) -> Curated:
    from frng.data.dataset import open_object

    obj = open_object(results, oid)
    ins = obj.meta["views"]["inputs"]
    return Curated(
        oid=oid,
        inputs=ins[:6],
        targets=obj.meta["views"]["targets"],
        input_light=obj.input_lights[0],
        target_lights=obj.target_lights,
        extra=ins[6:],
        image=lambda kind, light, view: io.read_rgba(obj.files.image(kind, light, view)),
        envmap=lambda light: envmap.read(obj.envmap_path(light, results)),
    )


def fov_x(intr, width: int) -> float:
    return 2.0 * math.atan(0.5 * width / float(intr[0]))
