"""What the relighting viewer (:mod:`frng.apps.view`) shows, without the server: the maps of its picker (lights),
the viewport's cameras (viser's and the browser's, checked), the asset rendered frame by frame
(:class:`FrameRenderer`), a frame as shown (:func:`display`) and a relit test object's images side by side
(:class:`TestObject`). Nothing here imports viser; torch only when a frame is rendered.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from frng import confine, io
from frng.apps.capture import read_light
from frng.data.envmaps import read_index
from frng.plan.layout import Layout
from frng.plan.variants import BACKBONE, PLUS, PLUS_METHOD, VIEW_RUN
from frng.render import envmap
from frng.render.envmap import EnvMapError

# while moving, the rasterizer (frng.render.tiles, the torch backend) stops a tile once its transmittance is below
# 1e-2 (the asset's setting: 1e-4) and composites 1024 Gaussians per depth chunk (the asset's: 64): rasterizing
# 26k Gaussians is per-Gaussian work that a lower resolution does not shorten; measured 3x faster at 48 px on the
# 2-core CPU (frame alpha within 0.01 of the exact one)
LOW_RASTER = {"min_transmittance": 1e-2, "chunk": 1024}
BACKGROUND = (0.05, 0.05, 0.05)  # linear RGB behind the object (sRGB ~0.25 grey)
THUMB_WIDTH = 256  # the map thumbnail's width in the panel
TILE_MIN = 128  # side-by-side tiles are upscaled (nearest neighbour, integer factor) to at least this


class ViewError(ValueError):
    """Bad input to the viewer (option, map, port, results folder); the message names the file or option."""


# -- lights -------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Light:
    """One map of the picker: ``label`` (unique; what the dropdown shows), the equirect ``image`` (He, 2 He, 3)
    linear float32, and the file it came from."""

    label: str
    image: np.ndarray = field(repr=False)
    path: Path


def results_of_asset(asset: Path) -> Path | None:
    """The results folder an asset folder sits in when it is a relighting run's (``{results}/relight/{run}/{obj}/
    asset``, :meth:`frng.plan.layout.RelightFolder.asset`) and that folder has prepared env maps; else None."""

    p = Path(asset).resolve()
    if len(p.parents) < 4 or p.parents[2].name != "relight":
        return None
    results = p.parents[3]
    return results if Path(Layout(results).envmap_index()).exists() else None


def collect_lights(
    asset: Path, results: Path | None, env_files: Sequence[str | Path], object_id: str | None
) -> list[Light]:
    """The picker's maps, in order: the files given (``--env``), the asset's input light (``input_light.exr`` of
    ``frng reconstruct``, else the results' object's first input light), then the results folder's test maps (one
    per test base map).
    Raises :class:`~frng.apps.capture.CaptureError` (a map missing, unreadable or not 2:1) or :class:`ViewError`."""

    out: list[Light] = []

    def add(label: str, path: Path) -> None:
        if any(x.path.resolve() == path.resolve() for x in out):
            return
        taken = {x.label for x in out}
        name, k = label, 2
        while name in taken:
            name, k = f"{label} ({k})", k + 1
        out.append(Light(name, read_light(path), path))

    for f in env_files:
        add(f"{Path(f).stem} · file", Path(f))
    if (Path(asset) / "input_light.exr").exists():
        try:  # a symlink out of the asset's folder is not read (frng.confine.folder_file, as load_asset)
            light = confine.folder_file(asset, "input_light.exr", source=Path(asset) / "input_light.exr", field=None)
        except confine.UntrustedInputError as e:
            raise ViewError(str(e)) from None
        add("input light", light)
    if results is not None:
        L = Layout(results)
        if not (Path(asset) / "input_light.exr").exists() and object_id and Path(L.object_meta(object_id)).exists():
            lights = io.read_json(L.object_meta(object_id)).get("input_lights") or []
            if lights:
                add(f"{lights[0]} · input light", Path(L.envmap(lights[0])))
        try:
            index = read_index(L.envmap_index())
        except EnvMapError as e:
            raise ViewError(str(e)) from None
        bases: set[str] = set()  # one map per test base map (each base has a rotated map per object that drew it)
        for rec in index["maps"]:
            if rec.get("split") == "test" and rec.get("base", rec["name"]) not in bases:
                bases.add(rec.get("base", rec["name"]))
                add(f"{rec['name']} · test map", Path(L.envmap(rec["name"])))
    if not out:
        raise ViewError("no environment map to light the asset with: give --env MAP (EXR/HDR, 2:1) or --config C")
    return out


def rotated(light: Light, degrees: float) -> np.ndarray:
    """The light's map rotated about world Z by ``degrees`` (:func:`frng.render.envmap.rotate_z`), (He, We, 3)."""

    return light.image if degrees % 360.0 == 0.0 else envmap.rotate_z(light.image, degrees)


def thumbnail(env: np.ndarray, width: int = THUMB_WIDTH) -> np.ndarray:
    """A display thumbnail of an equirect map (He, We, 3) -> uint8 (width / 2, width, 3): scaled so its 99th
    luminance percentile is white, sRGB-encoded, resized (nearest neighbour up, area down)."""

    lum = envmap.luminance(env)
    img = io.srgb_encode(env / max(float(np.percentile(lum, 99)), 1e-6))
    h, w = img.shape[:2]
    if w < width:
        k = max(1, width // w)
        img = np.repeat(np.repeat(img, k, 0), k, 1)
    elif w > width:
        img = envmap.resize(img, width)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


# -- cameras ------------------------------------------------------------------------------------------------------


def quat_to_matrix(wxyz: Sequence[float]) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> rotation matrix (3, 3), float64 (normalised first)."""
    w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(np.asarray(wxyz, np.float64))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def frame_size(height: int, aspect: float) -> tuple[int, int]:
    """(width, height) of a frame ``height`` px tall at the viewport's aspect ratio (width / height)."""
    height = max(1, int(height))
    return max(1, round(height * float(aspect))), height


def viewport_camera(
    position: Sequence[float], wxyz: Sequence[float], fov_y: float, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """A viewport camera (viser's: OpenCV axes, ``wxyz`` the camera-to-world rotation, vertical field of view
    ``fov_y`` in radians) -> (c2w (4, 4), intrinsics (fx, fy, cx, cy) (4,)) for a ``width`` x ``height`` frame,
    square pixels, centred; float64."""
    c2w = np.eye(4)
    c2w[:3, :3] = quat_to_matrix(wxyz)
    c2w[:3, 3] = np.asarray(position, np.float64)
    f = 0.5 * height / math.tan(0.5 * float(fov_y))
    return c2w, np.array([f, f, width / 2.0, height / 2.0])


MAX_CLIENT_DISTANCE = 1e4  # a viewport camera farther from the origin is ignored (the object lies in the unit sphere)
MAX_EXPOSURE_EV = 20.0  # the panel's slider is +-4; a client's value beyond this is ignored
MAX_ROTATION_DEG = 360.0  # the panel's slider is +-180


def client_camera(position, wxyz, fov, *, source: str) -> tuple[np.ndarray, np.ndarray, float]:
    """A viewport camera from the browser, checked (:mod:`frng.confine`): a finite position within
    :data:`MAX_CLIENT_DISTANCE`, a finite non-zero quaternion, a vertical field of view in (0, pi); else an
    :class:`~frng.confine.UntrustedInputError` naming ``source`` and the field."""
    pos = confine.finite(position, source=source, field="camera.position", shape=(3,), minimum=-MAX_CLIENT_DISTANCE,
                         maximum=MAX_CLIENT_DISTANCE)  # fmt: skip
    q = confine.finite(wxyz, source=source, field="camera.wxyz", shape=(4,))
    if not np.linalg.norm(q) > 1e-8:
        raise confine.NonFiniteError(f"{source}: field 'camera.wxyz' is not a rotation (zero quaternion)")
    return pos, q, confine.angle(fov, source=source, field="camera.fov")


def client_light(by_label: dict, label, rotation, exposure, *, source: str) -> tuple[str, float, float]:
    """(map label, rotation degrees, exposure EV) from the browser's panel, checked: a label among ``by_label``, finite
    numbers within :data:`MAX_ROTATION_DEG` / :data:`MAX_EXPOSURE_EV`; else an
    :class:`~frng.confine.UntrustedInputError` naming ``source`` and the field."""
    if not isinstance(label, str) or label not in by_label:
        raise confine.UntrustedInputError(f"{source}: field 'map' is {str(label)[:80]!r}, not one of the viewer's maps")
    rot = confine.finite(rotation, source=source, field="rotation", shape=(), minimum=-MAX_ROTATION_DEG,
                         maximum=MAX_ROTATION_DEG)  # fmt: skip
    ev = confine.finite(exposure, source=source, field="exposure", shape=(), minimum=-MAX_EXPOSURE_EV,
                        maximum=MAX_EXPOSURE_EV)  # fmt: skip
    return label, float(rot), float(ev)


def camera_pose(c2w: np.ndarray, intr: Sequence[float], height: int) -> dict:
    """An OpenCV camera (c2w (4, 4), intrinsics (4,), image height) as viser sets a viewport: position, look_at
    (the point on the optical axis nearest the origin, at least 0.1 ahead), up_direction (-y) and vertical fov."""
    c2w = np.asarray(c2w, np.float64)
    eye, forward = c2w[:3, 3], c2w[:3, 2]
    depth = max(float(-eye @ forward), 0.1)
    return {
        "position": eye,
        "look_at": eye + depth * forward,
        "up_direction": -c2w[:3, 1],
        "fov": 2.0 * math.atan(0.5 * height / float(intr[1])),
    }


def camera_record(name: str, c2w: np.ndarray, intr: np.ndarray, width: int, height: int) -> dict:
    """One camera of the ``--cameras`` file format ``frng render-asset`` reads (``frng cameras.json``)."""
    return {
        "name": name,
        "c2w": np.asarray(c2w, np.float64).tolist(),
        "intrinsics": [float(v) for v in intr],
        "width": int(width),
        "height": int(height),
    }


# -- rendering ----------------------------------------------------------------------------------------------------


class FrameRenderer:
    """An asset folder rendered frame by frame: :class:`frng.apps.asset.AssetRenderer`'s ``rasterize`` then ``shade``
    (what its ``render`` and ``frng render-asset`` do), the light samples seeded as render-asset's ``--seed``; the
    rasterized feature maps are kept while only the light changes. One frame at a time (a lock)."""

    def __init__(self, asset: str | Path, device: str = "auto"):
        from frng.apps.gltf_asset import open_renderer
        from frng.device import resolve_device

        try:
            self.device = resolve_device(device)
        except RuntimeError as e:
            raise ViewError(f"--device {device}: {e}") from None
        self.asset = Path(asset)
        self.renderer = open_renderer(self.asset, self.device)
        self._lock = threading.Lock()
        self._raster_key: tuple | None = None
        self._raster: tuple | None = None

    def forget(self) -> None:
        """Drop the kept feature maps: the next frame is rasterized again."""
        with self._lock:
            self._raster_key = self._raster = None

    @property
    def spp(self) -> int:
        """The asset's light samples per pixel at inference (``shading.spp_infer``)."""
        return int(self.renderer.shading.spp_infer)

    def frame(
        self,
        c2w: np.ndarray,
        intr: np.ndarray,
        width: int,
        height: int,
        env: np.ndarray,
        spp: int,
        seed: int = 0,
        fast: bool = False,
    ) -> tuple[np.ndarray, float]:
        """One frame: c2w (4, 4), intrinsics (4,), env (He, We, 3) linear -> (RGBA (height, width, 4) linear
        premultiplied float32, seconds it took on the device). ``fast``: rasterized with :data:`LOW_RASTER` (a
        frame while moving), else with the asset's settings (the frame render-asset writes)."""
        import dataclasses

        import torch

        from frng.device import synchronize

        c2w, intr, env = np.asarray(c2w), np.asarray(intr), np.asarray(env, np.float32)
        assert c2w.shape == (4, 4) and intr.shape == (4,), (c2w.shape, intr.shape)
        assert env.ndim == 3 and env.shape[2] == 3 and env.shape[1] == 2 * env.shape[0], env.shape
        key = (c2w.tobytes(), intr.tobytes(), int(width), int(height), bool(fast))
        with self._lock, torch.no_grad():
            synchronize(self.device)
            t0 = time.perf_counter()
            if key != self._raster_key:
                exact = self.renderer.raster
                if fast:
                    self.renderer.raster = dataclasses.replace(exact, **LOW_RASTER)
                try:
                    self._raster = self.renderer.rasterize(
                        torch.tensor(c2w[None], dtype=torch.float32),
                        torch.tensor(intr[None], dtype=torch.float32),
                        height,
                        width,
                    )
                finally:
                    self.renderer.raster = exact
                self._raster_key = key
            g = torch.Generator().manual_seed(int(seed))
            rgba = self.renderer.shade(self._raster, torch.from_numpy(env), int(spp), g)[0].float().cpu().numpy()
            synchronize(self.device)
            return rgba, time.perf_counter() - t0


def display(rgba: np.ndarray, exposure_ev: float = 0.0) -> np.ndarray:
    """A frame as shown: RGBA (H, W, 4) linear premultiplied -> uint8 sRGB (H, W, 3), the object's radiance scaled
    by 2^exposure_ev, over :data:`BACKGROUND`."""

    rgba = np.asarray(rgba, np.float32)
    assert rgba.ndim == 3 and rgba.shape[2] == 4, rgba.shape
    a = np.clip(rgba[..., 3:4], 0.0, 1.0)
    rgb = rgba[..., :3] * (2.0 ** float(exposure_ev)) + (1.0 - a) * np.asarray(BACKGROUND, np.float32)
    return (io.srgb_encode(rgb) * 255.0 + 0.5).astype(np.uint8)


def upscale(img: np.ndarray, at_least: int = TILE_MIN) -> np.ndarray:
    """Nearest-neighbour upscale of (H, W, C) by the smallest integer factor making its larger side >= at_least."""
    k = max(1, -(-at_least // max(img.shape[:2])))
    return np.repeat(np.repeat(img, k, 0), k, 1) if k > 1 else img


# -- a test object: its target views and the relit images of the results folder ----------------------------------


def shown_run(results: str | Path, oid: str) -> str:
    """The F-RNG run ``frng view --object`` shows: :data:`frng.plan.variants.VIEW_RUN` (F-RNG+) where the results
    folder relit the object with it, else the paper's ``full``."""

    return VIEW_RUN if Path(Layout(results).relight_record(VIEW_RUN, oid)).exists() else "full"


class TestObject:
    """A relit test object of a results folder: its target views (cameras), the lights it was relit under, and
    per (view, light) the ground truth, the F-RNG run ``run``'s (default :func:`shown_run`: the one whose asset
    ``--object`` opens) and the backbone's images (:mod:`frng.plan.layout`)."""

    __test__ = False  # not a pytest class

    def __init__(self, results: str | Path, oid: str, run: str | None = None):

        self.layout, self.oid, self.run = Layout(results), oid, run or shown_run(results, oid)
        meta_path, rec_path = Path(self.layout.object_meta(oid)), Path(self.layout.relight_record(self.run, oid))
        for p, what in ((meta_path, "curated object"), (rec_path, f"{self.run} run's relighting")):
            if not p.exists():
                raise ViewError(f"{p}: missing ({what} of --object {oid}); run the pipeline on that object first")
        meta, rec = io.read_json(meta_path), io.read_json(rec_path)
        cams = {c["name"]: c for c in (meta.get("views") or {}).get("targets", [])}
        self.views = [v for v in rec.get("target_views", []) if v in cams]
        self.lights = list(rec.get("lights", []))
        if not self.views or not self.lights:
            raise ViewError(f"{rec_path}: field 'target_views' or 'lights' names no target view or light")
        self.cameras = {v: cams[v] for v in self.views}
        self.runs = {"ground truth": None, PLUS_METHOD if self.run == PLUS else "F-RNG": self.run, "backbone": BACKBONE}
        for view in self.views:
            for light in self.lights:
                for p in self.paths(view, light).values():
                    if not Path(p).exists():
                        raise ViewError(f"{p}: missing (a relit image of --object {oid})")

    def paths(self, view: str, light: str) -> dict[str, str]:
        """label -> image file of (view, light): ground truth, F-RNG, backbone."""
        L = self.layout
        return {
            label: L.object_image(self.oid, "targets", light, view)
            if run is None
            else L.relight_image(run, self.oid, light, view)
            for label, run in self.runs.items()
        }

    def targets(self) -> list[tuple[str, str]]:
        """Every (view, light) pair, views outer."""
        return [(v, light) for v in self.views for light in self.lights]

    def camera(self, view: str) -> tuple[np.ndarray, np.ndarray, int, int]:
        """(c2w (4, 4), intrinsics (4,), width, height) of a target view."""
        c = self.cameras[view]
        return np.asarray(c["c2w"], np.float64), np.asarray(c["intrinsics"], np.float64), c["width"], c["height"]

    def side_by_side(self, view: str, light: str, exposure_ev: float = 0.0) -> np.ndarray:
        """Ground truth | F-RNG | backbone at (view, light), as :func:`display` shows frames, 2 px apart, upscaled
        to :data:`TILE_MIN`: uint8 (H, 3 W + 4, 3)."""

        tiles = [upscale(display(io.read_rgba(p), exposure_ev)) for p in self.paths(view, light).values()]
        gap = np.full((tiles[0].shape[0], 2, 3), 255, np.uint8)
        return np.concatenate([tiles[0], gap, tiles[1], gap, tiles[2]], axis=1)
