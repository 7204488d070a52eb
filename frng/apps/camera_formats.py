"""Camera files ``frng reconstruct --cameras`` reads, and lens distortion (issue 88).

:func:`read_camera_set` dispatches on the path; every camera comes out as OpenCV (c2w 4 x 4, x right, y down,
z forward; intrinsics fx, fy, cx, cy in pixels of ``size`` (W, H); pixel centres at +0.5):

* **COLMAP model** (a folder holding ``cameras``, ``images`` and, optionally, ``points3D`` as ``.txt`` or ``.bin``,
  also under ``sparse/0`` or ``sparse``; or one of those files): images' world-to-camera quaternion ``QW QX QY QZ``
  and ``TX TY TZ``, their camera's model and parameters; ``points3D`` gives the sparse points the object's centre
  is taken from (:mod:`frng.apps.capture_frame`). Camera models: ``SIMPLE_PINHOLE``, ``PINHOLE``,
  ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``, ``OPENCV_FISHEYE``, ``SIMPLE_RADIAL_FISHEYE``,
  ``RADIAL_FISHEYE``; the others (``FOV``, thin-prism) are an error (undistort with ``colmap image_undistorter``).
  Matched to the photos by file stem (an image name's folders are dropped).
* **LLFF** ``poses_bounds.npy`` (N x 17: a 3 x 5 matrix [down, right, back | position | H, W, focal] and the
  near / far bounds per image): square pixels, centred principal point. The file names no images: its rows are
  the photos in sorted order, so the counts must agree.
* **IDR / NeuS** ``cameras_sphere.npz`` (DTU, BlendedMVS): ``world_mat_i`` (the 3 x 4 projection P = K [R | t],
  padded to 4 x 4) times ``scale_mat_i`` (which maps the object's unit sphere into the world), split into K, R, t by
  an RQ decomposition. Cameras come out in the normalised frame, whose origin is the object's centre. By sorted
  order, like LLFF.
* **transforms.json / OpenCV camera files**: :func:`frng.apps.capture.read_cameras` (passed in as ``fallback``)
  plus their lens distortion: transforms.json's ``k1 k2 p1 p2`` (and ``k3``; ``k1..k4`` with ``camera_model``
  ``OPENCV_FISHEYE``), per frame or for all; an OpenCV entry's ``dist`` (also ``D``, ``distortion``,
  ``dist_coeffs``: OpenCV's order k1 k2 p1 p2 [k3 [k4 k5 k6]]; with ``"fisheye": true`` k1..k4). A top-level
  ``"up": [x, y, z]`` is the world's up (the SfM's gravity, where it gives one).

**Distortion** (:class:`Distortion`): OpenCV's model on normalised coordinates (x, y) = ((u - cx) / fx, (v - cy) /
fy): radial (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6) plus tangential p1, p2; the fisheye
(equidistant) model theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8), theta = atan(r). Photos are undistorted
before anything else reads their geometry (:func:`undistort_image`): each output pixel samples the photo at its
distorted position (bilinear; outside the photo is transparent), the intrinsics stay the same (a pinhole camera
with the photo's K). Out of range, one line naming the file and the camera: a model that folds back (r_d not
increasing, or a rational denominator <= 0) inside the image's corner radius, |p1| or |p2| above
:data:`MAX_TANGENTIAL`, non-finite parameters.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from frng import confine
from frng.apps.capture_errors import CaptureError

MAX_TANGENTIAL = 0.1
COLMAP_MODELS = {  # id: (name, number of parameters)
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
COLMAP_BY_NAME = {v[0]: (k, v[1]) for k, v in COLMAP_MODELS.items()}
OPENCV_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
FISHEYE_NAMES = ("k1", "k2", "k3", "k4")


# -- distortion -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Distortion:
    """A lens distortion on normalised image coordinates. ``model``: ``opencv`` (params k1 k2 p1 p2 k3 k4 k5 k6,
    OpenCV's rational model) or ``fisheye`` (k1 k2 k3 k4, equidistant)."""

    model: str
    params: tuple[float, ...]

    @staticmethod
    def make(model: str, values) -> Distortion | None:
        """``values`` padded with zeros to the model's length; None when they are all 0 (a pinhole)."""
        n = 8 if model == "opencv" else 4
        v = [float(x) for x in values][:n]
        v += [0.0] * (n - len(v))
        return None if all(x == 0.0 for x in v) else Distortion(model, tuple(v))

    def named(self) -> dict:
        return dict(zip(OPENCV_NAMES if self.model == "opencv" else FISHEYE_NAMES, self.params))

    def radial(self, r: np.ndarray) -> np.ndarray:
        """Distorted radius (pinhole units) at undistorted radius ``r`` (no tangential part)."""
        if self.model == "fisheye":
            k1, k2, k3, k4 = self.params
            th = np.arctan(r)
            t2 = th * th
            return th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        k1, k2, _, _, k3, k4, k5, k6 = self.params
        r2 = r * r
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        return r * num / den

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalised coordinates -> distorted ones."""
        r = np.sqrt(x * x + y * y)
        if self.model == "fisheye":
            s = np.where(r > 1e-12, self.radial(r) / np.maximum(r, 1e-12), 1.0)
            return x * s, y * s
        k1, k2, p1, p2, k3, k4, k5, k6 = self.params
        r2 = x * x + y * y
        s = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * s + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * s + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def undistort_points(self, xd, yd, iters: int = 60) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalised coordinates -> undistorted ones (Newton's method with a numeric Jacobian)."""
        xd, yd = np.asarray(xd, np.float64), np.asarray(yd, np.float64)
        x, y = xd.copy(), yd.copy()
        h = 1e-6
        for _ in range(iters):
            fx, fy = self.distort(x, y)
            ex, ey = fx - xd, fy - yd
            ax, ay = self.distort(x + h, y)
            bx, by = self.distort(x, y + h)
            j11, j21 = (ax - fx) / h, (ay - fy) / h
            j12, j22 = (bx - fx) / h, (by - fy) / h
            det = j11 * j22 - j12 * j21
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            dx = (j22 * ex - j12 * ey) / det
            dy = (-j21 * ex + j11 * ey) / det
            x, y = x - dx, y - dy
            if max(float(np.abs(dx).max(initial=0)), float(np.abs(dy).max(initial=0))) < 1e-12:
                break
        return x, y

    def check(self, intr, size: tuple[int, int], where: str) -> None:
        """An error naming ``where`` when the model is no lens over this image (module docstring)."""
        p = np.asarray(self.params, np.float64)
        text = " ".join(f"{k}={v:g}" for k, v in self.named().items() if v != 0.0)
        if not np.all(np.isfinite(p)):
            raise CaptureError(f"{where}: distortion parameters are not finite ({text})")
        if self.model == "opencv" and max(abs(p[2]), abs(p[3])) > MAX_TANGENTIAL:
            raise CaptureError(
                f"{where}: tangential distortion p1/p2 out of range ({text}; |p| <= {MAX_TANGENTIAL:g} for a lens)"
            )
        fx, fy, cx, cy = (float(v) for v in intr)
        W, H = size
        r_max = max(math.hypot((u - cx) / fx, (v - cy) / fy) for u in (0.0, W) for v in (0.0, H))
        r = np.linspace(0.0, r_max, 1025)[1:]
        bad = ~np.isfinite(self.radial(r))
        if self.model == "opencv":
            k4, k5, k6 = p[5:8]
            r2 = r * r
            bad |= 1 + r2 * (k4 + r2 * (k5 + r2 * k6)) <= 0
        rd = self.radial(r)
        bad[:-1] |= np.diff(rd) <= 0
        bad |= rd <= 0
        if bad.any():
            at = float(r[int(np.argmax(bad))]) / r_max
            raise CaptureError(
                f"{where}: {self.model} distortion out of range ({text}): the lens model folds back at "
                f"{at:.0%} of the way to the image's corner, so it is no lens this {W}x{H} image can come from"
            )


def undistort_image(img: np.ndarray, intr, dist: Distortion) -> np.ndarray:
    """``img`` (H, W, C) taken through ``dist`` -> the pinhole image with the same intrinsics (bilinear; outside
    the photo is 0, i.e. transparent for premultiplied RGBA)."""
    from scipy import ndimage

    H, W = img.shape[:2]
    fx, fy, cx, cy = (float(v) for v in intr)
    out = np.empty(img.shape, np.float32)
    chans = [np.ascontiguousarray(img[..., c], dtype=np.float32) for c in range(img.shape[-1])]
    u = (np.arange(W, dtype=np.float64) + 0.5 - cx) / fx
    for r0 in range(0, H, 256):  # in bands of rows: bounded memory for large photos
        v = (np.arange(r0, min(H, r0 + 256), dtype=np.float64) + 0.5 - cy) / fy
        yy, xx = np.meshgrid(v, u, indexing="ij")
        xd, yd = dist.distort(xx, yy)
        coords = [(fy * yd + cy - 0.5).astype(np.float32), (fx * xd + cx - 0.5).astype(np.float32)]
        for c, ch in enumerate(chans):
            out[r0 : r0 + len(v), :, c] = ndimage.map_coordinates(ch, coords, order=1, mode="constant", cval=0.0)
    return out.astype(img.dtype, copy=False)


# -- one camera set ---------------------------------------------------------------------------------------


@dataclass
class FileCamera:
    """A camera as read: OpenCV c2w, intrinsics in pixels of ``size`` (W, H) (None: the photo's), distortion."""

    c2w: np.ndarray
    intr: np.ndarray
    size: tuple[int, int] | None = None
    distortion: Distortion | None = None


@dataclass
class CameraSet:
    """What a camera file says: cameras in file order (``by_order``: their names are placeholders and the photos,
    sorted by name, are matched by order), and where the file gives them the sparse points, the world's up and the
    object's centre (all in the file's world frame)."""

    path: Path
    format: str
    cams: list[tuple[str, FileCamera]]
    by_order: bool = False
    points: np.ndarray | None = None  # (N, 3)
    up: np.ndarray | None = None  # (3,)
    centre: np.ndarray | None = None  # (3,)
    centre_source: str = ""
    notes: dict = field(default_factory=dict)
    # where the cameras come from a structure-from-motion run: per photo name, the pixel positions (K, 2) of its
    # keypoints that became sparse points and their rows in ``points`` (K,) (what seeds the masks, frng.apps.masks)
    observations: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    # whether the cameras name their images (a JSON file's entries without ``file_path`` / ``image`` / ``name`` do
    # not: their names are the placeholders frame_{k} / cam_{k}, and they are matched by order like ``by_order``)
    named: bool = True

    def assign(self, names: list[str]) -> dict[str, FileCamera]:
        """Photo name -> its camera: by name (COLMAP, JSON files), else, for files whose cameras carry no names
        (LLFF, IDR, JSON entries without image names), by sorted order when the counts agree. A file made for other
        images (a photo without a camera of its name, or no camera named after any photo) is an error naming it."""
        by = dict(self.cams)
        unnamed = self.by_order or not self.named
        if not unnamed and all(n in by for n in names):
            return {n: by[n] for n in names}
        if unnamed and len(self.cams) == len(names):
            return {n: c for n, (_, c) in zip(names, self.cams)}
        if unnamed:
            what = f"{self.format} cameras name no images" if self.by_order else "its cameras name no images"
            raise CaptureError(
                f"{self.path}: {len(self.cams)} cameras for {len(names)} images; {what}, so the folder must hold "
                f"exactly the images the file was made for (matched in sorted order)"
            )
        missing = [n for n in names if n not in by]
        if len(missing) == len(names):
            raise CaptureError(
                f"{self.path}: its {len(self.cams)} cameras name none of the {len(names)} photos (the file names "
                f"{[n for n, _ in self.cams][:3]}, the photos are {names[:3]}): a camera file of other images?"
            )
        raise CaptureError(
            f"{self.path}: no camera for image(s) {missing[:3]} ({len(self.cams)} cameras, {len(names)} images; "
            f"is this the camera file of other images?)"
        )


def _check_cams(path: Path, cams: list[tuple[str, FileCamera]], strict: bool = True) -> None:
    if not cams:
        raise CaptureError(f"{path}: no cameras")
    for name, c in cams:  # finite, not singular, not 1e30 away, a field of view (the one shared check)
        try:
            confine.check_camera(c.c2w, c.intr, c.size, source=path, field=f"camera {name!r}")
        except confine.UntrustedInputError as e:
            raise CaptureError(str(e)) from None
        if strict and abs(np.linalg.det(c.c2w[:3, :3]) - 1.0) > 1e-3:
            raise CaptureError(
                f"{path}: camera {name!r}: its rotation is not a rotation (det {np.linalg.det(c.c2w[:3, :3]):.3g})"
            )


def read_camera_set(path: str | Path, sizes: dict[str, tuple[int, int]] | None = None, fallback=None) -> CameraSet:
    """Any camera file (module docstring) -> :class:`CameraSet`. ``fallback(path, sizes)``: the reader of
    transforms.json / OpenCV files (:func:`frng.apps.capture.read_cameras`), returning [(name, camera)]."""
    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path}: camera file does not exist")
    colmap = colmap_folder(path)
    if colmap is not None:
        cs = read_colmap(*colmap)
    elif path.is_dir():
        raise CaptureError(
            f"{path}: a folder, but no COLMAP model in it (cameras.txt/.bin and images.txt/.bin, also under sparse/0)"
        )
    elif path.suffix.lower() == ".npy":
        cs = read_llff(path)
    elif path.suffix.lower() == ".npz":
        cs = read_idr(path)
    else:
        if fallback is None:
            raise CaptureError(f"{path}: not a COLMAP model, poses_bounds.npy or cameras_sphere.npz")
        cams = [(n, FileCamera(c.c2w, c.intr, c.size)) for n, c in fallback(path, sizes)]
        placeholders = all(n in (f"frame_{k}", f"cam_{k}") for k, (n, _) in enumerate(cams))  # no image names
        cs = CameraSet(path, "json", cams, named=not placeholders)
        _json_extras(cs)
    _check_cams(path, cs.cams, strict=cs.format != "json")  # json: read_cameras' own checks
    return cs


# -- transforms.json / OpenCV extras ----------------------------------------------------------------------


def _num(path: Path, where: str, key: str, v) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise CaptureError(f"{path}: {where} field {key!r} is not a number ({v!r})") from None
    if not math.isfinite(x):
        raise CaptureError(f"{path}: {where} field {key!r} is not finite ({v!r})")
    return x


def _json_extras(cs: CameraSet) -> None:
    """Distortion and ``up`` of a transforms.json / OpenCV file (module docstring), set on ``cs`` in place."""
    import yaml

    try:
        data = yaml.safe_load(cs.path.read_text())
    except (yaml.YAMLError, OSError, UnicodeDecodeError):
        return
    if isinstance(data, dict) and data.get("up") is not None:
        try:
            up = np.asarray(data["up"], np.float64).reshape(3)
        except (TypeError, ValueError):
            raise CaptureError(f"{cs.path}: field 'up' is not 3 numbers ({data['up']!r})") from None
        if not np.all(np.isfinite(up)) or np.linalg.norm(up) < 1e-9:
            raise CaptureError(f"{cs.path}: field 'up' is not a direction ({data['up']!r})")
        cs.up = up / np.linalg.norm(up)
    if isinstance(data, dict) and isinstance(data.get("frames"), list):
        for (name, cam), fr in zip(cs.cams, data["frames"]):
            get = lambda k, fr=fr: fr.get(k, data.get(k)) if isinstance(fr, dict) else data.get(k)  # noqa: E731
            fisheye = str(get("camera_model") or "").upper() in ("OPENCV_FISHEYE", "FISHEYE")
            where = f"frame {name!r}"
            v = {k: _num(cs.path, where, k, get(k)) for k in ("k1", "k2", "k3", "k4", "p1", "p2") if get(k) is not None}
            if fisheye:
                cam.distortion = Distortion.make("fisheye", [v.get(k, 0.0) for k in FISHEYE_NAMES])
            else:
                if v.get("k4", 0.0) != 0.0:
                    raise CaptureError(
                        f"{cs.path}: {where} field 'k4' is read only with camera_model OPENCV_FISHEYE "
                        f"(a perspective camera's distortion is k1 k2 k3 p1 p2)"
                    )
                cam.distortion = Distortion.make("opencv", [v.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])
        return
    entries = data.get("cameras", data.get("views")) if isinstance(data, dict) else data
    if isinstance(entries, dict):
        entries = entries.get("inputs")
    if not isinstance(entries, list):
        return
    for (name, cam), e in zip(cs.cams, entries):
        if not isinstance(e, dict):
            continue
        key = next((k for k in ("dist", "D", "distortion", "dist_coeffs") if e.get(k) is not None), None)
        if key is None:
            continue
        try:
            vals = [float(x) for x in np.asarray(e[key], np.float64).reshape(-1)]
        except (TypeError, ValueError):
            raise CaptureError(f"{cs.path}: camera {name!r} field {key!r} is not a list of numbers") from None
        fisheye = bool(e.get("fisheye")) or str(e.get("model", "")).lower() == "fisheye"
        if len(vals) not in ((4,) if fisheye else (4, 5, 8)):
            raise CaptureError(
                f"{cs.path}: camera {name!r} field {key!r} has {len(vals)} values "
                f"(expected {'4: k1 k2 k3 k4' if fisheye else '4, 5 or 8: k1 k2 p1 p2 [k3 [k4 k5 k6]]'})"
            )
        cam.distortion = Distortion.make("fisheye" if fisheye else "opencv", vals)


# -- COLMAP ------------------------------------------------------------------------------------------------


def colmap_folder(path: Path) -> tuple[Path, str] | None:
    """(folder, ".txt" | ".bin") of the COLMAP model at ``path`` (a model folder, a folder holding ``sparse/0`` or
    ``sparse``, or one of the model's files), or None."""
    if path.is_file():
        if path.stem in ("cameras", "images", "points3D") and path.suffix in (".txt", ".bin"):
            return path.parent, path.suffix
        return None
    for d in (path, path / "sparse" / "0", path / "sparse"):
        for ext in (".bin", ".txt"):
            if (d / f"cameras{ext}").is_file() and (d / f"images{ext}").is_file():
                return d, ext
    return None


def _quat_to_rot(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def colmap_intrinsics(model: str, params, where: str) -> tuple[np.ndarray, Distortion | None]:
    """A COLMAP camera model's parameters -> (fx, fy, cx, cy), distortion."""
    p = [float(x) for x in params]
    if model not in COLMAP_BY_NAME:
        raise CaptureError(f"{where}: unknown camera model {model!r}")
    if len(p) != COLMAP_BY_NAME[model][1]:
        raise CaptureError(f"{where}: camera model {model} takes {COLMAP_BY_NAME[model][1]} parameters, got {len(p)}")
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL", "RADIAL_FISHEYE"):
        intr, rest = np.array([p[0], p[0], p[1], p[2]]), p[3:]
    else:
        intr, rest = np.array(p[:4]), p[4:]
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return intr, None
    if model in ("SIMPLE_RADIAL", "RADIAL", "OPENCV"):
        return intr, Distortion.make("opencv", rest)
    if model == "FULL_OPENCV":  # k1 k2 p1 p2 k3 k4 k5 k6, OpenCV's order
        return intr, Distortion.make("opencv", rest)
    if model in ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        return intr, Distortion.make("fisheye", rest)
    raise CaptureError(
        f"{where}: camera model {model} is not supported (undistort the images with `colmap image_undistorter` "
        f"and pass its PINHOLE model)"
    )


class _Reader:
    def __init__(self, path: Path):
        self.path, self.buf, self.at = path, path.read_bytes(), 0

    def read(self, fmt: str):
        n = struct.calcsize("<" + fmt)
        if self.at + n > len(self.buf):
            raise CaptureError(f"{self.path}: truncated COLMAP binary file (at byte {self.at} of {len(self.buf)})")
        out = struct.unpack_from("<" + fmt, self.buf, self.at)
        self.at += n
        return out

    def skip(self, n: int) -> None:
        if self.at + n > len(self.buf):
            raise CaptureError(f"{self.path}: truncated COLMAP binary file (at byte {self.at} of {len(self.buf)})")
        self.at += n

    def name(self) -> str:
        end = self.buf.find(b"\0", self.at)
        if end < 0:
            raise CaptureError(f"{self.path}: truncated COLMAP binary file (an image name has no end)")
        s = self.buf[self.at : end].decode("utf-8", "replace")
        self.at = end + 1
        return s


def _lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise CaptureError(f"{path}: cannot read ({e})") from None
    return [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines()) if not ln.lstrip().startswith("#")]


def _colmap_text(folder: Path):
    cams, images, points = {}, [], None
    f = folder / "cameras.txt"
    for no, ln in _lines(f):
        if not ln:
            continue
        tok = ln.split()
        where = f"{f}: line {no}"
        try:
            cid, model, w, h = int(tok[0]), tok[1], int(tok[2]), int(tok[3])
            params = [float(x) for x in tok[4:]]
        except (IndexError, ValueError):
            raise CaptureError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]") from None
        cams[cid] = (model, (w, h), params, where)
    f = folder / "images.txt"
    rows = _lines(f)
    i = 0
    while i < len(rows):
        no, ln = rows[i]
        if not ln:
            i += 1
            continue
        tok = ln.split()
        try:
            q = [float(x) for x in tok[1:5]]
            t = [float(x) for x in tok[5:8]]
            cid, name = int(tok[8]), " ".join(tok[9:])
        except (IndexError, ValueError):
            raise CaptureError(f"{f}: line {no}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME") from None
        if not name:
            raise CaptureError(f"{f}: line {no}: image has no NAME")
        images.append((name, q, t, cid, f"{f}: line {no}"))
        i += 2  # the next line lists the image's 2D points (may be empty)
    f = folder / "points3D.txt"
    if f.is_file():
        pts = []
        for no, ln in _lines(f):
            if not ln:
                continue
            try:
                pts.append([float(x) for x in ln.split()[1:4]])
            except ValueError:
                raise CaptureError(f"{f}: line {no}: expected POINT3D_ID X Y Z ...") from None
        points = np.asarray(pts, np.float64).reshape(-1, 3)
    return cams, images, points


def _colmap_binary(folder: Path):
    cams, images, points = {}, [], None
    r = _Reader(folder / "cameras.bin")
    for _ in range(r.read("Q")[0]):
        cid, mid, w, h = r.read("iiQQ")
        if mid not in COLMAP_MODELS:
            raise CaptureError(f"{r.path}: camera {cid}: unknown camera model id {mid}")
        name, n = COLMAP_MODELS[mid]
        cams[cid] = (name, (int(w), int(h)), list(r.read(f"{n}d")), f"{r.path}: camera {cid}")
    r = _Reader(folder / "images.bin")
    for _ in range(r.read("Q")[0]):
        iid, qw, qx, qy, qz, tx, ty, tz, cid = r.read("idddddddi")
        name = r.name()
        (n2d,) = r.read("Q")
        r.skip(24 * n2d)
        images.append((name, [qw, qx, qy, qz], [tx, ty, tz], cid, f"{r.path}: image {iid} ({name})"))
    if (folder / "points3D.bin").is_file():
        r = _Reader(folder / "points3D.bin")
        pts = []
        for _ in range(r.read("Q")[0]):
            xyz = r.read("Q3d3Bd")[1:4]
            (n,) = r.read("Q")
            r.skip(8 * n)
            pts.append(xyz)
        points = np.asarray(pts, np.float64).reshape(-1, 3)
    return cams, images, points


def read_colmap(folder: Path, ext: str = ".txt") -> CameraSet:
    """A COLMAP sparse model (text or binary) -> :class:`CameraSet` (sorted by image name)."""
    cams, images, points = (_colmap_text if ext == ".txt" else _colmap_binary)(folder)
    return colmap_camera_set(folder / f"images{ext}", cams, images, points)


def colmap_camera_set(path: Path, cams: dict, images: list, points, fmt: str = "COLMAP", **extra) -> CameraSet:
    """A COLMAP model's records -> :class:`CameraSet` (sorted by image name); the one conversion shared by the model
    files (:func:`read_colmap`) and a structure-from-motion run in memory (:mod:`frng.apps.sfm`). ``path``: what
    errors name. ``cams``: camera id -> (model name, (W, H), params, where); ``images``: [(name, quaternion QW QX
    QY QZ, translation TX TY TZ (world-to-camera), camera id, where)]; ``points``: (N, 3) or None. ``extra``: more
    :class:`CameraSet` fields (``notes``, ``observations``)."""
    out = []
    intrinsics = {cid: colmap_intrinsics(m, p, where) + (size,) for cid, (m, size, p, where) in cams.items()}
    models = sorted({cams[cid][0] for _, _, _, cid, _ in images if cid in cams})
    for name, q, t, cid, where in sorted(images, key=lambda x: x[0]):
        if cid not in intrinsics:
            raise CaptureError(f"{where}: camera id {cid} is not in cameras{Path(path).suffix}")
        intr, dist, size = intrinsics[cid]
        if np.linalg.norm(q) < 1e-12 or not np.all(np.isfinite(q)):
            raise CaptureError(f"{where}: the rotation quaternion is not a rotation ({q})")
        R = _quat_to_rot(q)
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = R.T, -R.T @ np.asarray(t, np.float64)
        out.append((Path(name).stem, FileCamera(c2w, intr.copy(), size, dist)))
    stems = [n for n, _ in out]
    if len(set(stems)) != len(stems):
        dup = sorted({n for n in stems if stems.count(n) > 1})
        raise CaptureError(f"{path}: two images share a name stem ({dup[:3]})")
    if points is not None and len(points) and "observations" not in extra:  # rows of observations must stay put
        points = points[np.all(np.isfinite(points), 1)]
    notes = {"colmap_models": models, **extra.pop("notes", {})}
    return CameraSet(
        path,
        fmt,
        out,
        points=points if points is not None and len(points) else None,
        notes=notes,
        **extra,
    )


# -- LLFF, IDR / NeuS --------------------------------------------------------------------------------------


def read_llff(path: Path) -> CameraSet:
    """LLFF ``poses_bounds.npy`` -> :class:`CameraSet` (module docstring)."""
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise CaptureError(f"{path}: cannot read as a .npy array ({str(e).splitlines()[0][:200]})") from None
    if arr.ndim != 2 or arr.shape[1] != 17 or not np.issubdtype(arr.dtype, np.number):
        raise CaptureError(f"{path}: LLFF poses_bounds.npy holds an N x 17 array; this one is {arr.shape} {arr.dtype}")
    out = []
    for k, row in enumerate(np.asarray(arr, np.float64)):
        P = row[:15].reshape(3, 5)
        h, w, f = P[:, 4]
        if not (h > 0 and w > 0 and f > 0):
            raise CaptureError(f"{path}: row {k}: height, width and focal (column 4) must be > 0, got {P[:, 4]}")
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = P[:, 1], P[:, 0], -P[:, 2], P[:, 3]
        out.append((f"{k:05d}", FileCamera(c2w, np.array([f, f, w / 2.0, h / 2.0]), (int(round(w)), int(round(h))))))
    return CameraSet(path, "LLFF", out, by_order=True, notes={"bounds": arr[:, 15:17].tolist()})


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 3 x 4 projection P = lambda K [R | t] -> (K (3, 3) with K[2, 2] = 1 and a positive diagonal, OpenCV c2w)."""
    from scipy.linalg import rq

    P = np.asarray(P, np.float64)[:3, :4]
    if np.linalg.det(P[:, :3]) < 0:
        P = -P
    K, R = rq(P[:, :3])
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R
    t = np.linalg.solve(K, P[:, 3])
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = R.T, -R.T @ t
    return K / K[2, 2], c2w


def read_idr(path: Path) -> CameraSet:
    """IDR / NeuS ``cameras_sphere.npz`` (or ``cameras.npz``) -> :class:`CameraSet` (module docstring)."""
    try:
        data = dict(np.load(path, allow_pickle=False))
    except (ValueError, OSError) as e:
        raise CaptureError(f"{path}: cannot read as a .npz archive ({str(e).splitlines()[0][:200]})") from None
    # world_mat_{i} only: NeuS's archives also hold world_mat_inv_{i} (and camera_mat_{i}, scale_mat_inv_{i})
    ids = sorted(
        int(n) for n in (k.removeprefix("world_mat_") for k in data if k.startswith("world_mat_")) if n.isdigit()
    )
    if not ids:
        raise CaptureError(f"{path}: no world_mat_0.. in the archive (keys {sorted(data)[:5]}); not IDR / NeuS cameras")
    if ids != list(range(len(ids))):
        raise CaptureError(f"{path}: world_mat_i numbered {ids[:5]}..; expected 0..{len(ids) - 1}")
    out = []
    scaled = all(f"scale_mat_{i}" in data for i in ids)
    for i in ids:
        W = np.asarray(data[f"world_mat_{i}"], np.float64)
        S = np.asarray(data[f"scale_mat_{i}"], np.float64) if scaled else np.eye(4)
        if W.shape not in ((4, 4), (3, 4)) or S.shape != (4, 4):
            raise CaptureError(f"{path}: world_mat_{i} / scale_mat_{i} have shapes {W.shape} / {S.shape}")
        if W.shape == (3, 4):
            W = np.vstack([W, [0, 0, 0, 1]])
        P = (W @ S)[:3, :4]
        if not np.all(np.isfinite(P)) or abs(np.linalg.det(P[:, :3])) < 1e-12:
            raise CaptureError(f"{path}: world_mat_{i} (times scale_mat_{i}) is not a camera projection (singular)")
        K, c2w = decompose_projection(P)
        out.append((f"{i:05d}", FileCamera(c2w, np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]), None)))
    return CameraSet(
        path,
        "IDR/NeuS",
        out,
        by_order=True,
        centre=np.zeros(3) if scaled else None,
        centre_source="scale_mat (the object's unit sphere)" if scaled else "",
    )


# -- undistortion of a capture -----------------------------------------------------------------------------


def undistort_photos(photos, assigned: dict[str, FileCamera], where: Path) -> dict[str, dict]:
    """Undistort every photo (``.name``, ``.size``, ``.rgb`` premultiplied, ``.alpha``) whose camera in
    ``assigned`` has a distortion, in place, and drop the distortion from the camera (its intrinsics are now the
    photo's pinhole K, rescaled to the photo's size). Returns name -> {model, params} of what was undone."""
    done = {}
    for p in photos:
        cam = assigned.get(p.name)
        if cam is None or cam.distortion is None:
            continue
        intr = np.asarray(cam.intr, np.float64)
        if cam.size is not None and tuple(cam.size) != tuple(p.size):
            sx, sy = p.size[0] / cam.size[0], p.size[1] / cam.size[1]
            intr = intr * np.array([sx, sy, sx, sy])
        d = cam.distortion
        d.check(intr, p.size, f"{where}: camera of {p.name}")
        rgba = np.concatenate([p.rgb, p.alpha[..., None]], -1) if p.alpha is not None else p.rgb
        out = undistort_image(rgba, intr, d)
        if p.alpha is not None:
            p.rgb, p.alpha = np.ascontiguousarray(out[..., :3]), np.clip(out[..., 3], 0.0, 1.0)
        else:
            p.rgb = out
        assigned[p.name] = FileCamera(cam.c2w, intr, tuple(p.size), None)
        done[p.name] = {"model": d.model, **d.named()}
    return done


__all__ = [
    "COLMAP_MODELS",
    "CameraSet",
    "Distortion",
    "FileCamera",
    "MAX_TANGENTIAL",
    "colmap_camera_set",
    "colmap_folder",
    "colmap_intrinsics",
    "decompose_projection",
    "read_camera_set",
    "read_colmap",
    "read_idr",
    "read_llff",
    "undistort_image",
    "undistort_photos",
]
