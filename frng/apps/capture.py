"""Captures: your own photos in, views on the training rig out (the first half of ``frng reconstruct``; the asset
itself: :mod:`frng.apps.reconstruct`; its measurement: :mod:`frng.apps.capture_measure`; rendering:
``frng render-asset``).

A capture is 2-10 photos of one object (:data:`MIN_VIEWS`, :data:`MAX_VIEWS`), taken under one unknown light.
This module turns them into what the F-RNG reconstruction path reads (:func:`frng.apps.relight.backbone_views`, the IDM,
:meth:`frng.model.composed.FRNG.reconstruct`): square views at the model's resolution, their masks, OpenCV cameras on
the training rig's sphere, and an input light. Every bad input is a :class:`CaptureError` whose message names the
file at fault; nothing is written before all inputs passed.

Images (:func:`load_images`)
    PNG / JPEG (8 or 16 bit, sRGB, straight alpha if any) or EXR (linear, premultiplied alpha if any); all must
    have the same aspect ratio (1 % tolerance). ``grid=(rows, cols)`` splits one image holding a grid of views
    (what multi-view image generators write) into rows x cols tiles, row by row.

Masks (:func:`make_masks`), in this order of precedence
    1. ``--masks DIR``: one mask image per photo (matched by file stem, else by sorted order when the counts
       agree); its alpha channel if it has one, else the mean of its channels; the same size as its photo;
    2. the photo's own alpha channel (unless it is opaque everywhere);
    3. a uniform background keyed out: the median colour of a border ring (2 % of the shorter side, >= 1 px) is the
       background when 95 % of the ring's pixels lie within :data:`KEY_UNIFORM` of it (sRGB, max over channels);
       a pixel's alpha ramps from 0 to 1 as its distance to that colour goes from :data:`KEY_LOW` to
       :data:`KEY_HIGH`; holes inside the object are filled and specks smaller than 1 % of the largest part
       dropped; the background's share is removed from the edge colours (linear unmixing);
    4. a textured background (a table, a room): segmented by GrabCut, seeded by the image centre or, after
       structure from motion (``--sfm``), by the sparse points near the object's centre and on the table
       (:mod:`frng.apps.masks`; the source, ``grabcut:centre`` or ``grabcut:sfm-points``, is recorded).
    None of these (the segmentation refused: too small, no object, colours not told apart) -> an error naming the
    photo (among more photos than views: the photo is left out when enough remain, :mod:`frng.apps.capture_frame`;
    a held-out photo is skipped). A mask with fewer than max(4, 0.1 % of the pixels) above 0.5 is
    "empty" -> an error naming the mask (or photo).

Cameras (:func:`read_cameras`, :func:`rig_cameras`, :func:`normalise`)
    * ``--rig paper``: the paper's 6-view rig (:mod:`frng.data.rig` with azimuth offset 0): the photos in sorted
      order are azimuth 0, 90, 180, 270 deg at elevation 0 and 45, 225 deg at 45 deg (2-6 photos: the first ones),
      all at the training rig's distance and field of view (``render.camera_distance``, ``render.fov_deg``),
      looking at the origin, world Z up. Azimuth 0 looks at the object from +X; a ``--light`` map is read in this
      frame.
    * ``--cameras FILE``: a NeRF-style ``transforms.json`` (``frames[].file_path`` + ``transform_matrix``, Blender
      camera-to-world; ``camera_angle_x`` or ``fl_x``/``fl_y``/``cx``/``cy`` and ``w``/``h``), or an OpenCV camera
      file (JSON or YAML): ``{"cameras": [{"image": NAME, "K": 3x3, "R": 3x3, "t": [3]}]}`` (world-to-camera, as
      ``cv2.solvePnP``), or entries with ``c2w`` (4x4 OpenCV camera-to-world) + ``intrinsics`` (fx, fy, cx, cy)
      as :mod:`frng.data.rig` and ``meta.json`` write them (``width``/``height``: the size K refers to). Cameras
      are matched to photos by file stem; a file whose entries name no images (no ``file_path`` / ``image`` /
      ``name``) by sorted order when the counts agree; one naming other images is an error naming the file.
      Also a COLMAP model (text or binary), LLFF ``poses_bounds.npy`` and IDR / NeuS ``cameras_sphere.npz``, and
      lens distortion (transforms.json ``k1 k2 p1 p2``, COLMAP's models), undistorted before anything else
      (:mod:`frng.apps.camera_formats`); the world is turned upright and centred on the object, the transform
      recorded (``world_to_asset``), and among more than :data:`MAX_VIEWS` photos (or ``--select N``) the views
      are chosen and the rest held out (:mod:`frng.apps.capture_frame`).
      Normalisation to the training rig: the common centre (the point nearest every optical axis) moves to the
      origin and the world is scaled so the median camera distance is ``render.camera_distance``; each photo is
      then cropped to the window that has the training field of view (``render.fov_deg``) around the projection of
      the centre, and resampled to ``render.resolution`` (intrinsics follow exactly; outside the photo is
      transparent). A camera whose optical axis misses the common centre by more than :data:`MAX_AXIS_DEG`
      (or that has it behind) is an error naming the camera file and the photo.
    * ``--sfm``: no camera file; structure from motion on the CPU finds the cameras from the photos themselves
      (:mod:`frng.apps.sfm`, pycolmap) and they take the ``--cameras`` path from there: the same undistortion,
      upright and centred frame (the object's centre from the sparse points inside the masks) and choice of views,
      and the same normalisation to the training rig. Photos that do not register are left out (one stderr line
      naming them, ``info["sfm"]["not_registered"]``) when at least as many register as the model takes views
      (``select``, else the training rig's :data:`frng.apps.capture_frame.RIG_VIEWS`); else an error naming them.
    * held-out photos (``held_out=True``, ``frng reconstruct --measure-heldout``): the photos not chosen as views
      are prepared as the views are (:attr:`Capture.held_out`) and scored by :mod:`frng.apps.capture_heldout`.
    * framing of rig photos (``framing``): ``keep`` -- each photo is centre-cropped to a square (along its long
      side, centred on the object) and resized: the object keeps its size in the frame (right for renders made
      with the training rig, e.g. the exported test views); ``object`` -- every photo is cropped around its
      object's bounding box centre with one common scale chosen so the widest silhouette of all photos spans the
      unit sphere seen from the rig (diameter 2 tan(asin(1 / distance)) / (2 tan(fov / 2)) of the frame); ``auto``
      (default) = ``keep`` when every photo is square, else ``object``.
    Downscaling low-passes first (Gaussian, sigma = (factor - 1) / 2); a crop equal to the image at the same size
    is the identity.

Light (:func:`estimate_light`)
    Unless ``--light MAP`` gives it, the input light is estimated from the IDM's albedo and normals: over the
    confident foreground (alpha > 0.9, albedo > 0.02), shading = colour / albedo = E(n) / pi is fitted by
    ridge-regularised least squares with a degree-2 SH radiance (9 x 3 coefficients, the l >= 1 bands damped
    towards 0 so the directions no photo sees stay dim), which is expanded into an equirect map (negative lobes
    clamped). Light colour and albedo colour are ambiguous (a green object under white light or a white one under
    green light); by default (:data:`LIGHT_COLOUR` ``neutral``) the fitted light is made grey on average (each
    channel scaled so its DC term has the DC luminance; grey world), which scored better than the per-channel
    fit on the smoke tier. The SH fixes the irradiance, which is what the reconstruction's Lambertian path divides
    by; the light's high frequencies are lost (measured cost: README "Your own photos").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from frng import camera, confine, io
from frng.apps import camera_formats, capture_frame
from frng.apps.capture_errors import CaptureError
from frng.render import envmap

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".exr")
MIN_VIEWS, MAX_VIEWS = 2, 10
ASPECT_TOL = 0.01
KEY_UNIFORM, KEY_LOW, KEY_HIGH = 0.06, 0.06, 0.16  # sRGB, max over channels
MAX_AXIS_DEG = 15.0
EMPTY_FRACTION = 0.001
FRAMINGS = ("auto", "keep", "object")
LIGHT_COLOUR = "neutral"  # "neutral": grey-world light colour (default, measured); "fit": as fitted


@dataclass
class Photo:
    """One input photo at its original size: linear RGB premultiplied by ``alpha`` when it has one."""

    name: str
    path: Path
    rgb: np.ndarray  # (H, W, 3) float32 linear (premultiplied when alpha is not None)
    alpha: np.ndarray | None = None  # (H, W) float32 in [0, 1], or None (no alpha channel / opaque)
    mask_source: str = ""  # where the mask came from: "alpha", "masks:FILE", "keyed", "grabcut:centre|sfm-points"
    info: dict = field(default_factory=dict)

    @property
    def size(self) -> tuple[int, int]:
        return self.rgb.shape[1], self.rgb.shape[0]  # (W, H)


# -- images -----------------------------------------------------------------------------------------------


def image_files(folder: Path, what: str = "images", allow_outside: bool = True) -> list[Path]:
    """The image files of ``folder`` (sorted); unless ``allow_outside``, one that is a symlink out of the folder is
    a :class:`CaptureError` (:func:`frng.confine.inside`)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: {what} folder does not exist")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS)
    if not allow_outside:
        for p in files:
            try:
                confine.inside(p, folder)
            except confine.OutsideError as e:
                raise CaptureError(str(e)) from None
    return files


def _check_size(path: Path) -> None:
    """Before decoding: the content is the format the name says and the pixel count is bounded."""
    try:
        confine.check_image_size(path)
    except confine.UntrustedInputError as e:
        raise CaptureError(str(e)) from None


def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """A PNG/JPEG (sRGB, straight alpha) or EXR (linear, premultiplied) -> (linear premultiplied RGB, alpha|None).
    Greyscale is expanded; an alpha that is 1 everywhere counts as none."""
    path = Path(path)
    _check_size(path)
    if path.suffix.lower() == ".exr":
        try:
            ch = io.read_exr_channels(path)
        except (io.ImageError, ValueError, OSError) as e:
            raise CaptureError(f"{path}: cannot read EXR ({e})") from e
        if "R" in ch and "G" in ch and "B" in ch:
            rgb = np.stack([ch["R"], ch["G"], ch["B"]], -1)
        elif "Y" in ch:
            rgb = np.repeat(ch["Y"][..., None], 3, -1)
        else:
            raise CaptureError(f"{path}: EXR has no R, G, B (or Y) channels (has {sorted(ch)})")
        a = ch.get("A")
        rgb = np.maximum(rgb.astype(np.float32), 0.0)
    else:
        import imageio.v3 as iio

        try:
            img = np.asarray(iio.imread(path))
        except Exception as e:  # imageio raises many kinds
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise CaptureError(f"{path}: cannot read image ({first[:200]})") from None
        scale = 65535.0 if img.dtype == np.uint16 else 255.0 if img.dtype == np.uint8 else 1.0
        img = img.astype(np.float32) / scale
        if img.ndim == 2:
            img = img[..., None]
        if img.ndim != 3 or img.shape[-1] not in (1, 2, 3, 4):
            raise CaptureError(f"{path}: unsupported image shape {img.shape}")
        c = img.shape[-1]
        rgb = np.repeat(img[..., :1], 3, -1) if c in (1, 2) else img[..., :3]
        a = img[..., -1] if c in (2, 4) else None
        rgb = io.srgb_decode(rgb)
        if a is not None:
            rgb = rgb * a[..., None]
    if not np.all(np.isfinite(rgb)) or (a is not None and not np.all(np.isfinite(a))):
        raise CaptureError(f"{path}: image contains NaN or inf")
    if a is not None:
        a = np.clip(a.astype(np.float32), 0.0, 1.0)
        if a.min() >= 0.999:
            a = None
    return rgb.astype(np.float32), a


def parse_grid(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        r, c = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise CaptureError(f"--grid {text!r}: expected ROWSxCOLS, e.g. 2x3") from None
    if r < 1 or c < 1:
        raise CaptureError(f"--grid {text!r}: rows and columns must be >= 1")
    return r, c


def load_images(
    source: str | Path, grid: tuple[int, int] | None = None, allow_outside: bool = True, only=None
) -> list[Photo]:
    """The photos of a capture: every image file of a folder (sorted by name), or with ``grid`` the tiles of one
    image (a file, or a folder holding exactly one). Checks the count (2-10) and that the aspect ratios agree.
    ``allow_outside=False``: a symlink out of the folder is refused (``frng reconstruct`` without
    ``--allow-outside``). ``only``: the file stems to read (the chosen views, :mod:`frng.apps.capture_frame`)."""
    source = Path(source)
    if grid is not None:
        files = [source] if source.is_file() else image_files(source, allow_outside=allow_outside)
        if len(files) != 1:
            raise CaptureError(f"{source}: --grid splits one image; the folder holds {len(files)} image files")
        rgb, a = read_image(files[0])
        rows, cols = grid
        H, W = rgb.shape[:2]
        th, tw = H // rows, W // cols
        if th < 8 or tw < 8:
            raise CaptureError(f"{files[0]}: {W}x{H} is too small for a {rows}x{cols} grid")
        photos = []
        for i in range(rows):
            for j in range(cols):
                sl = (slice(i * th, (i + 1) * th), slice(j * tw, (j + 1) * tw))
                photos.append(
                    Photo(f"{files[0].stem}_r{i}c{j}", files[0], rgb[sl].copy(), None if a is None else a[sl].copy())
                )
                if photos[-1].alpha is not None and photos[-1].alpha.min() >= 0.999:
                    photos[-1].alpha = None
    else:
        if source.is_file():
            raise CaptureError(f"{source}: --images takes a folder of images (or one grid image with --grid)")
        files = image_files(source, allow_outside=allow_outside)
        files = files if only is None else [f for f in files if f.stem in set(only)]
        photos = []
        for f in files:
            rgb, a = read_image(f)
            photos.append(Photo(f.stem, f, rgb, a))
        if len({p.name for p in photos}) != len(photos):
            raise CaptureError(f"{source}: two image files share a name stem")
    if len(photos) < MIN_VIEWS:
        raise CaptureError(
            f"{source}: {len(photos)} image(s); a capture needs at least {MIN_VIEWS} views ({', '.join(IMAGE_EXTS)})"
        )
    if len(photos) > MAX_VIEWS:
        raise CaptureError(
            f"{source}: {len(photos)} images; a capture takes at most {MAX_VIEWS} views (with --cameras the "
            f"views are chosen among more photos)"
        )
    w0, h0 = photos[0].size
    for p in photos[1:]:
        w, h = p.size
        if abs((w / h) / (w0 / h0) - 1.0) > ASPECT_TOL:
            raise CaptureError(
                f"{p.path}: aspect ratio {w}x{h} differs from {photos[0].path.name} ({w0}x{h0}); "
                f"all views must have the same aspect ratio"
            )
    return photos


# -- masks ------------------------------------------------------------------------------------------------


def _read_mask(path: Path) -> np.ndarray:
    _check_size(path)
    if path.suffix.lower() == ".exr":
        ch = io.read_exr_channels(path)
        m = ch.get("A", ch.get("Y", ch.get("R")))
        if m is None:
            raise CaptureError(f"{path}: mask EXR has no A, Y or R channel")
        return np.clip(m.astype(np.float32), 0, 1)
    import imageio.v3 as iio

    try:
        img = np.asarray(iio.imread(path))
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CaptureError(f"{path}: cannot read mask ({first[:200]})") from None
    scale = 65535.0 if img.dtype == np.uint16 else 255.0 if img.dtype == np.uint8 else 1.0
    img = img.astype(np.float32) / scale
    if img.ndim == 3:
        img = img[..., -1] if img.shape[-1] in (2, 4) else img.mean(-1)
    return np.clip(img, 0.0, 1.0)


def _check_not_empty(m: np.ndarray, where: Path | str) -> None:
    need = max(4, int(EMPTY_FRACTION * m.size))
    if int((m > 0.5).sum()) < need:
        raise CaptureError(f"{where}: the mask is empty ({int((m > 0.5).sum())} pixels above 0.5, need {need})")


def key_background(photo: Photo) -> tuple[np.ndarray, np.ndarray] | None:
    """The uniform-background key (module docstring): (alpha (H, W), unmixed premultiplied RGB), or None when the
    border is not uniform."""
    from scipy import ndimage

    rgb = photo.rgb
    H, W = rgb.shape[:2]
    b = max(1, int(round(0.02 * min(H, W))))
    enc = io.srgb_encode(rgb)
    ring = np.concatenate(
        [enc[:b].reshape(-1, 3), enc[-b:].reshape(-1, 3), enc[:, :b].reshape(-1, 3), enc[:, -b:].reshape(-1, 3)]
    )
    bg = np.median(ring, 0)
    if np.quantile(np.abs(ring - bg).max(-1), 0.95) > KEY_UNIFORM:
        return None
    dist = np.abs(enc - bg).max(-1)
    alpha = np.clip((dist - KEY_LOW) / (KEY_HIGH - KEY_LOW), 0.0, 1.0)
    solid = alpha > 0.5
    lab, n = ndimage.label(solid)
    if n > 1:
        sizes = ndimage.sum(solid, lab, range(1, n + 1))
        small = np.isin(lab, 1 + np.nonzero(sizes < 0.01 * sizes.max())[0])
        alpha[small] = 0.0
        solid &= ~small
    holes = ndimage.binary_fill_holes(solid) & ~solid
    alpha[holes] = 1.0
    bg_lin = io.srgb_decode(bg)
    out = np.maximum(rgb - (1.0 - alpha[..., None]) * bg_lin, 0.0)
    return alpha.astype(np.float32), out.astype(np.float32)


def _mask_file(name: str, by_stem: dict[str, Path]) -> Path | None:
    """The mask file of the photo named ``name`` (its stem) among ``by_stem`` (stem -> file): the same stem, else
    the one whose stem is the same number (NeuS's DTU: image/000000.png, mask/000.png); None when there is none or
    the number is ambiguous."""
    if name in by_stem:
        return by_stem[name]
    if not name.isdigit():
        return None
    same = [f for stem, f in by_stem.items() if stem.isdigit() and int(stem) == int(name)]
    return same[0] if len(same) == 1 else None


def make_masks(
    photos: list[Photo],
    masks: str | Path | None = None,
    grid: tuple[int, int] | None = None,
    allow_outside: bool = True,
    seeds: dict | None = None,
) -> list[Photo]:
    """Give every photo a mask (module docstring: --masks, alpha, keyed background, segmentation); RGB becomes
    premultiplied. With ``grid``, a mask folder holding one image is split like the grid image.
    ``allow_outside=False``: a mask that is a symlink out of its folder is refused. ``seeds``: photo name ->
    :class:`frng.apps.masks.Seeds` for the segmentation (default: the image centre)."""
    if masks is not None:
        files = image_files(Path(masks), "masks", allow_outside)
        by_stem = {f.stem: f for f in files}
        tiles = None
        if grid is not None and len(files) == 1:
            m = _read_mask(files[0])
            th, tw = m.shape[0] // grid[0], m.shape[1] // grid[1]
            tiles = [m[i * th : (i + 1) * th, j * tw : (j + 1) * tw] for i in range(grid[0]) for j in range(grid[1])]
            chosen = files * len(photos)
        elif all(named := [_mask_file(p.name, by_stem) for p in photos]):
            chosen = named
        elif len(files) == len(photos) > 1:
            chosen = files
        else:
            raise CaptureError(
                f"{masks}: {len(files)} mask file(s) and no mask named like photo(s) "
                f"{[p.name for p, f in zip(photos, named) if f is None][:3]} (a mask takes its photo's name, "
                "or its number: 000.png for 000000.png)"
            )
        for k, (p, f) in enumerate(zip(photos, chosen)):
            m = _read_mask(f) if tiles is None else tiles[k]
            if m.shape != p.rgb.shape[:2]:
                raise CaptureError(
                    f"{f}: mask is {m.shape[1]}x{m.shape[0]}, its image {p.path.name} is {p.size[0]}x{p.size[1]}"
                )
            _check_not_empty(m, f)
            straight = p.rgb / np.maximum(p.alpha, 1e-6)[..., None] if p.alpha is not None else p.rgb
            p.rgb, p.alpha, p.mask_source = (straight * m[..., None]).astype(np.float32), m, f"masks:{f.name}"
        return photos
    for p in photos:
        if p.alpha is not None:
            p.mask_source = "alpha"
        else:
            keyed = key_background(p)
            if keyed is not None:
                p.alpha, p.rgb = keyed
                p.mask_source = "keyed"
            else:
                from frng.apps.masks import segment

                alpha, seg = segment(p.rgb, None if seeds is None else seeds.get(p.name))
                if alpha is None:
                    raise CaptureError(
                        f"{p.path}: no mask for this view: it has no alpha channel, no --masks folder was given, "
                        f"its border is not a uniform background to key out, and segmenting it failed "
                        f"({seg['reason']}); give --masks"
                    )
                p.alpha, p.rgb = alpha, (p.rgb * alpha[..., None]).astype(np.float32)
                p.mask_source = seg["source"]
                p.info["segmentation"] = seg
        _check_not_empty(p.alpha, p.path)
    return photos


# -- cameras ----------------------------------------------------------------------------------------------


@dataclass
class Cam:
    """An OpenCV camera: c2w (4, 4), intrinsics (fx, fy, cx, cy) in pixels of an image ``size`` (W, H)."""

    c2w: np.ndarray
    intr: np.ndarray
    size: tuple[int, int] | None = None


def _load_struct(path: Path):
    import yaml

    if not path.exists():
        raise CaptureError(f"{path}: camera file does not exist")
    try:
        return yaml.safe_load(path.read_text())  # JSON is YAML
    except yaml.YAMLError as e:
        raise CaptureError(f"{path}: cannot parse camera file ({str(e).splitlines()[0]})") from None


def read_cameras(path: str | Path, sizes: dict[str, tuple[int, int]] | None = None) -> list[tuple[str, Cam]]:
    """A camera file -> [(name, Cam)] in file order (module docstring: transforms.json, OpenCV K/R/t, c2w +
    intrinsics, or an frng ``meta.json``'s input views). ``sizes``: name -> (W, H) for files that give only a
    field of view. Names are file stems."""
    path = Path(path)
    data = _load_struct(path)
    out = []
    try:
        if isinstance(data, dict) and "frames" in data:  # NeRF / instant-ngp transforms.json
            for k, fr in enumerate(data["frames"]):
                name = Path(str(fr.get("file_path", f"frame_{k}"))).stem
                c2w = camera.c2w_from_blender(np.asarray(fr["transform_matrix"], np.float64).reshape(4, 4))
                get = lambda key, fr=fr: fr.get(key, data.get(key))  # noqa: E731
                w, h = get("w"), get("h")
                if (w is None or h is None) and sizes and name in sizes:
                    w, h = sizes[name]
                elif (w is None or h is None) and sizes:
                    w, h = next(iter(sizes.values()))
                if w is None or h is None:
                    raise CaptureError(f"{path}: frame {name!r} gives no image size (w, h)")
                fx = get("fl_x")
                if fx is None:
                    ang = get("camera_angle_x")
                    if ang is None:
                        raise CaptureError(f"{path}: frame {name!r} has neither fl_x nor camera_angle_x")
                    try:  # 0 divided by zero; pi gave fx = 2.6e-14 (frng.confine.angle: in (0, pi))
                        ang = confine.angle(ang, source=path, field=f"frames[{k}].camera_angle_x")
                    except confine.UntrustedInputError as e:
                        raise CaptureError(str(e)) from None
                    fx = 0.5 * float(w) / math.tan(0.5 * ang)
                fy = get("fl_y") or fx
                cx, cy = get("cx"), get("cy")
                intr = np.array([fx, fy, w / 2.0 if cx is None else cx, h / 2.0 if cy is None else cy], np.float64)
                out.append((name, Cam(c2w, intr, (int(w), int(h)))))
        else:
            entries = data
            if isinstance(data, dict):
                entries = data.get(
                    "cameras",
                    data.get("views", {}).get("inputs") if isinstance(data.get("views"), dict) else data.get("views"),
                )
            if not isinstance(entries, list):
                raise CaptureError(f"{path}: not a camera file (expected 'frames', 'cameras' or a list of cameras)")
            for k, e in enumerate(entries):
                name = Path(str(e.get("image", e.get("name", f"cam_{k}")))).stem
                if "K" in e:
                    K = np.asarray(e["K"], np.float64).reshape(3, 3)
                    intr = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
                else:
                    intr = np.asarray(e["intrinsics"], np.float64).reshape(4)
                if "c2w" in e:
                    c2w = np.asarray(e["c2w"], np.float64).reshape(4, 4)
                else:
                    R = np.asarray(e["R"], np.float64).reshape(3, 3)
                    t = np.asarray(e["t"], np.float64).reshape(3)
                    c2w = np.eye(4)
                    c2w[:3, :3], c2w[:3, 3] = R.T, -R.T @ t
                size = (int(e["width"]), int(e["height"])) if "width" in e and "height" in e else None
                out.append((name, Cam(c2w, intr, size)))
    except CaptureError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise CaptureError(f"{path}: malformed camera entry ({type(e).__name__}: {e})") from None
    for name, c in out:  # finite, not singular, not 1e30 away, a field of view (frng.confine.check_camera)
        try:
            confine.check_camera(c.c2w, c.intr, c.size, source=path, field=f"camera {name!r}")
        except confine.UntrustedInputError as e:
            raise CaptureError(str(e)) from None
    if not out:
        raise CaptureError(f"{path}: no cameras")
    return out


def match_cameras(photos: list[Photo], cams: list[tuple[str, Cam]], path: Path) -> list[Cam]:
    """One camera per photo (by stem, else by order when the counts agree); K rescaled to the photo's size."""
    by = dict(cams)
    if all(p.name in by for p in photos):
        chosen = [by[p.name] for p in photos]
    elif len(cams) == len(photos):
        chosen = [c for _, c in cams]
    else:
        missing = [p.name for p in photos if p.name not in by]
        raise CaptureError(f"{path}: no camera for image(s) {missing[:3]} ({len(cams)} cameras, {len(photos)} images)")
    out = []
    for p, c in zip(photos, chosen):
        intr = c.intr.copy()
        if c.size is not None and tuple(c.size) != p.size:
            sx, sy = p.size[0] / c.size[0], p.size[1] / c.size[1]
            if abs(sx / sy - 1.0) > ASPECT_TOL:
                raise CaptureError(
                    f"{path}: camera for {p.path.name} is for a {c.size[0]}x{c.size[1]} image; "
                    f"the image is {p.size[0]}x{p.size[1]}"
                )
            intr *= np.array([sx, sy, sx, sy])
        out.append(Cam(c.c2w.copy(), intr, p.size))
    return out


def rig_cameras(n: int, distance: float, fov_deg: float, resolution: int) -> list[Cam]:
    """The paper's rig (azimuth offset 0), first ``n`` views, at the training distance / field of view."""
    from frng.data import rig

    if n > len(rig.RIG_AZIMUTH_OFFSETS_DEG):
        raise CaptureError(f"--rig paper has {len(rig.RIG_AZIMUTH_OFFSETS_DEG)} views; got {n} images")
    return [
        Cam(v.c2w, v.intrinsics, (resolution, resolution))
        for v in (
            rig.make_view(f"in_{i:02d}", "input", az, el, distance, fov_deg, resolution)
            for i, (az, el) in enumerate(zip(rig.RIG_AZIMUTH_OFFSETS_DEG[:n], rig.RIG_ELEVATIONS_DEG[:n]))
        )
    ]


def _axis_angle(cam: Cam, c: np.ndarray) -> float:
    o, d = cam.c2w[:3, 3], cam.c2w[:3, 2] / np.linalg.norm(cam.c2w[:3, 2])
    to = c - o
    return math.degrees(math.acos(np.clip(to @ d / max(np.linalg.norm(to), 1e-12), -1, 1)))


def common_centre(cams: list[Cam], names: list[str], path: Path | str) -> np.ndarray:
    """The point nearest every optical axis; an error naming the camera that does not look at it (with 3+
    cameras, the one farthest off the centre of the others, so one bad camera does not get another blamed)."""
    from frng.benchmarks.common import optical_axes_centre

    c2ws = np.stack([k.c2w for k in cams])
    c = optical_axes_centre(c2ws)
    angles = [_axis_angle(k, c) for k in cams]
    if max(angles) <= MAX_AXIS_DEG:
        return c
    if len(cams) >= 3:
        angles = [_axis_angle(k, optical_axes_centre(np.delete(c2ws, i, 0))) for i, k in enumerate(cams)]
    i = int(np.argmax(angles))
    raise CaptureError(
        f"{path}: the camera of {names[i]} does not look at the common centre of the cameras "
        f"(its optical axis is {angles[i]:.1f} deg off it, limit {MAX_AXIS_DEG:g}); the object "
        f"must be centred in every view"
    )


# -- cropping / resampling ----------------------------------------------------------------------------------


def resample(img: np.ndarray, x0: float, y0: float, wc: float, hc: float, res: int) -> np.ndarray:
    """The window [x0, x0 + wc) x [y0, y0 + hc) of ``img`` (H, W, C) resampled to (res, res, C): bilinear at the
    output pixel centres after a Gaussian low-pass of sigma (factor - 1) / 2 per axis; outside the image is 0."""
    from scipy import ndimage

    kx, ky = wc / res, hc / res
    src = img.astype(np.float32)
    sig = (max(0.0, (ky - 1) / 2), max(0.0, (kx - 1) / 2))
    if sig[0] > 0 or sig[1] > 0:
        src = ndimage.gaussian_filter(src, sigma=(sig[0], sig[1], 0), mode="constant")
    c = np.arange(res) + 0.5
    xs = x0 + kx * c - 0.5
    ys = y0 + ky * c - 0.5
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    out = np.stack(
        [
            ndimage.map_coordinates(src[..., i], [yy, xx], order=1, mode="constant", cval=0.0)
            for i in range(src.shape[-1])
        ],
        -1,
    )
    return out.astype(np.float32)


def _bbox(alpha: np.ndarray) -> tuple[float, float, float, float]:
    ys, xs = np.nonzero(alpha > 0.5)
    return float(xs.min()), float(ys.min()), float(xs.max() + 1), float(ys.max() + 1)


def frame_rig(photos: list[Photo], framing: str, distance: float, fov_deg: float, res: int) -> list[dict]:
    """Crop windows (x0, y0, w, h) of rig photos (module docstring, ``framing``)."""
    if framing not in FRAMINGS:
        raise CaptureError(f"framing {framing!r}: choose from {FRAMINGS}")
    if framing == "auto":
        framing = "keep" if all(p.size[0] == p.size[1] for p in photos) else "object"
    wins = []
    if framing == "keep":
        for p in photos:
            W, H = p.size
            s = min(W, H)
            bx0, by0, bx1, by1 = _bbox(p.alpha)
            cx, cy = (bx0 + bx1) / 2, (by0 + by1) / 2
            x0 = min(max(cx - s / 2, 0.0), W - s)
            y0 = min(max(cy - s / 2, 0.0), H - s)
            wins.append({"x0": x0, "y0": y0, "w": float(s), "h": float(s), "framing": "keep"})
        return wins
    fill = math.tan(math.asin(min(1.0, 1.0 / distance))) / math.tan(math.radians(fov_deg) / 2)
    ext = max(max(b[2] - b[0], b[3] - b[1]) / p.size[0] for p, b in ((p, _bbox(p.alpha)) for p in photos))
    for p in photos:
        bx0, by0, bx1, by1 = _bbox(p.alpha)
        s = ext * p.size[0] / fill
        wins.append({"x0": (bx0 + bx1) / 2 - s / 2, "y0": (by0 + by1) / 2 - s / 2, "w": s, "h": s, "framing": "object"})
    return wins


@dataclass
class Capture:
    """A capture ready for reconstruction: views at the model's resolution and cameras on the training rig."""

    names: list[str]
    rgb: np.ndarray  # (V, R, R, 3) linear premultiplied
    alpha: np.ndarray  # (V, R, R, 1)
    c2w: np.ndarray  # (V, 4, 4) OpenCV
    intr: np.ndarray  # (V, 4)
    info: dict
    # ``prepare(held_out=True)``: the held-out photos prepared the same way (V', R, R, ...), in the asset's frame;
    # ``held_out.info["skipped"]``: photo name -> why it could not be
    held_out: Capture | None = None

    def views(self):
        """:class:`frng.priors.dataset.Views` (torch, float32)."""
        import torch

        from frng.priors.dataset import Views

        t = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
        return Views(
            list(self.names), t(self.rgb).clamp_min(0.0), t(self.alpha).clamp(0.0, 1.0), t(self.c2w), t(self.intr)
        )


def prepare(
    images: str | Path,
    *,
    resolution: int,
    distance: float,
    fov_deg: float,
    masks=None,
    cameras=None,
    rig: str | None = None,
    grid: tuple[int, int] | None = None,
    framing: str = "auto",
    allow_outside: bool = True,
    select: int | None = None,
    sfm: bool = False,
    work: str | Path | None = None,
    progress=None,
    held_out: bool = False,
) -> Capture:
    """Photos -> :class:`Capture` (module docstring). ``cameras`` (a file), ``sfm`` (structure from motion finds
    them: :mod:`frng.apps.sfm`, its scratch folder in ``work``, ``progress(line)`` per stage, default stderr) or
    ``rig`` (``"paper"``, the default). ``allow_outside=False``: photos and masks that are symlinks out of their
    folders are refused. With ``cameras`` (any format of :mod:`frng.apps.camera_formats`) or ``sfm`` the photos
    are undistorted and the world turned upright, and among more than :data:`MAX_VIEWS` photos (or with
    ``select``) the views are chosen (:mod:`frng.apps.capture_frame`). ``held_out``: also prepare the photos not
    chosen, as the views are (:attr:`Capture.held_out`; what ``--measure-heldout`` scores the asset on)."""
    sfm_set, seeds, left_out, held = None, None, set(), None
    if sfm:
        from frng.apps import sfm as structure_from_motion
        from frng.apps.masks import seeds_from_sfm

        if cameras is not None or rig is not None:
            raise CaptureError("--sfm finds the cameras from the photos: give it without --cameras or --rig")
        if grid is not None or Path(images).is_file():
            raise CaptureError(f"{images}: --sfm takes a folder of photos taken from different places (no --grid)")
        files = image_files(Path(images), allow_outside=allow_outside)
        sfm_set = structure_from_motion.cameras_from_photos(
            files,
            images,
            work=work,
            progress=progress or structure_from_motion.say,
            read=read_image,
            need=select or capture_frame.RIG_VIEWS,  # the views the model takes: so many must register
        )
        cameras, seeds = sfm_set.path, seeds_from_sfm(sfm_set)
        left_out = {Path(n).stem for n in sfm_set.notes["sfm"].get("not_registered", [])}

    def read_set(path, sizes):
        if sfm_set is not None:
            return sfm_set
        return camera_formats.read_camera_set(path, sizes, fallback=read_cameras)

    sel = None
    if cameras is not None and grid is None and not Path(images).is_file():
        files = [f for f in image_files(Path(images), allow_outside=allow_outside) if f.stem not in left_out]
        sel = capture_frame.select_photos(
            images,
            cameras,
            files,
            select=select,
            load=lambda f: make_masks([Photo(f.stem, f, *read_image(f))], masks, None, allow_outside, seeds)[0],
            read_set=read_set,
            min_views=MIN_VIEWS,
            max_views=MAX_VIEWS,
        )
    elif select is not None:
        raise CaptureError(f"--select {select}: views are chosen among a folder of photos with --cameras or --sfm")
    only = sel.chosen if sel is not None else [f.stem for f in files] if left_out else None  # registered
    photos = make_masks(load_images(images, grid, allow_outside, only), masks, grid, allow_outside, seeds)
    res = int(resolution)
    names = [p.name for p in photos]
    info: dict = {
        "images": str(images),
        "masks": [p.mask_source for p in photos],
        "resolution": res,
        "camera_distance": distance,
        "fov_deg": fov_deg,
    }
    segmented = {p.name: p.info["segmentation"] for p in photos if "segmentation" in p.info}
    if segmented:
        info["segmentation"] = segmented
    if cameras is not None:
        cset = sel.cset if sel is not None else None
        cset = cset or read_set(Path(cameras), {p.name: p.size for p in photos})
        frame = capture_frame.Frame.build(cset, photos, sel)  # undistorts the photos, turns the world upright
        cams = match_cameras(photos, frame.cameras, Path(cameras))
        centre = common_centre(cams, [p.path.name if p.path.stem == p.name else p.name for p in photos], cameras)
        centre = frame.object_centre(cams, photos, centre)
        dists = [np.linalg.norm(k.c2w[:3, 3] - centre) for k in cams]
        scale = distance / float(np.median(dists))
        out_c2w, out_intr, wins = [], [], []
        for k in cams:
            c2w, intr, win, _ = _rig_window(k, centre, scale, fov_deg, res)
            out_c2w.append(c2w)
            out_intr.append(intr)
            wins.append(win)
        info |= {"cameras": "sfm" if sfm_set else str(cameras), "centre": centre.tolist(), "scale": scale}
        if sfm_set is not None:
            info["sfm"] = sfm_set.notes["sfm"]
        info |= frame.record(centre, scale)
        if held_out and sel is not None and sel.held_out:
            kept = {f.stem: f for f in files}
            held = _held_out_views(
                [kept[n] for n in sel.held_out],
                frame,
                Path(cameras),
                centre,
                scale,
                fov_deg,
                res,
                masks,
                seeds,
                allow_outside,
            )
    else:
        if rig not in (None, "paper"):
            raise CaptureError(f"--rig {rig!r}: the only rig is 'paper'")
        try:
            cams = rig_cameras(len(photos), distance, fov_deg, res)
        except CaptureError as e:
            raise CaptureError(f"{images}: {e}") from None
        wins = frame_rig(photos, framing, distance, fov_deg, res)
        out_c2w = [k.c2w for k in cams]
        out_intr = [k.intr for k in cams]
        info |= {"cameras": "rig:paper", "world_to_asset": np.eye(4).tolist()}
    rgba = [
        resample(np.concatenate([p.rgb, p.alpha[..., None]], -1), w["x0"], w["y0"], w["w"], w["h"], res)
        for p, w in zip(photos, wins)
    ]
    rgba = np.stack(rgba)
    info["crops"] = [{k: (round(v, 3) if isinstance(v, float) else v) for k, v in w.items()} for w in wins]
    for p, a in zip(photos, rgba[..., 3]):
        _check_not_empty(a, f"{p.path} (after cropping to the object)")
    alpha = np.clip(rgba[..., 3:4], 0.0, 1.0)
    rgb = np.maximum(rgba[..., :3], 0.0)
    return Capture(names, rgb, alpha, np.stack(out_c2w), np.stack(out_intr), info, held)


def _rig_window(k: Cam, centre: np.ndarray, scale: float, fov_deg: float, res: int):
    """A camera ``k`` (upright frame, intrinsics in its photo's pixels) on the training rig: its c2w with the world
    moved by -``centre`` and scaled by ``scale``, the intrinsics (4,) of the ``res`` x ``res`` view cropped to the
    training field of view around the centre's projection, the crop window (x0, y0, w, h) in the photo's pixels,
    and the centre's camera-frame depth (<= 0: behind the camera)."""
    c2w = k.c2w.copy()
    c2w[:3, 3] = (c2w[:3, 3] - centre) * scale
    uv, z = camera.project(_t(np.zeros((1, 3))), _t(c2w)[None], _t(k.intr)[None])
    u, v = (float(x) for x in uv[0, 0])
    t = math.tan(math.radians(fov_deg) / 2)
    fx, fy, cx, cy = k.intr
    wc, hc = 2 * fx * t, 2 * fy * t
    x0, y0 = u - wc / 2, v - hc / 2
    intr = np.array([fx * res / wc, fy * res / hc, (cx - x0) * res / wc, (cy - y0) * res / hc])
    return c2w, intr, {"x0": x0, "y0": y0, "w": wc, "h": hc}, float(z[0, 0])


def _held_out_views(
    files, frame, path: Path, centre, scale, fov_deg, res, masks, seeds, allow_outside: bool
) -> Capture:
    """The held-out photos prepared exactly as the views (masked, undistorted, cropped to the training field of
    view around the object's centre and resampled to ``res``; cameras in the asset's frame), one photo in memory at
    a time. A photo that cannot be (its mask refused or empty after the crop, the centre behind its camera) is
    skipped: ``info["skipped"]`` names it with the reason."""
    names, rgbs, alphas, c2ws, intrs, skipped = [], [], [], [], [], {}
    assigned = dict(frame.assigned)  # undistortion replaces the entries; the frame's record keeps the file's
    for f in files:
        try:
            p = make_masks([Photo(f.stem, f, *read_image(f))], masks, None, allow_outside, seeds)[0]
            camera_formats.undistort_photos([p], assigned, path)
            k = match_cameras([p], [(p.name, assigned[p.name])], path)[0]
            c2w, intr, w, z = _rig_window(k, centre, scale, fov_deg, res)
            if z <= 0:
                raise CaptureError(f"{f}: the object's centre is behind this camera")
            rgba = resample(np.concatenate([p.rgb, p.alpha[..., None]], -1), w["x0"], w["y0"], w["w"], w["h"], res)
            _check_not_empty(rgba[..., 3], f"{f} (after cropping to the object)")
        except CaptureError as e:
            skipped[f.stem] = str(e)
            continue
        names.append(p.name)
        rgbs.append(np.maximum(rgba[..., :3], 0.0))
        alphas.append(np.clip(rgba[..., 3:4], 0.0, 1.0))
        c2ws.append(c2w)
        intrs.append(intr)
    if not names:
        return Capture(
            [],
            np.zeros((0, res, res, 3), np.float32),
            np.zeros((0, res, res, 1), np.float32),
            np.zeros((0, 4, 4)),
            np.zeros((0, 4)),
            {"skipped": skipped},
        )
    return Capture(names, np.stack(rgbs), np.stack(alphas), np.stack(c2ws), np.stack(intrs), {"skipped": skipped})


def _t(a):
    import torch

    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


# -- light --------------------------------------------------------------------------------------------------


def read_light(path: str | Path) -> np.ndarray:
    """An equirect map (EXR/HDR, 2:1, finite) or a :class:`CaptureError` naming it."""
    try:
        return envmap.read(path)
    except envmap.EnvMapError as e:
        raise CaptureError(str(e)) from e


def estimate_light(
    rgb, alpha, albedo, normal, height: int, ridge: float = 0.1, colour: str = LIGHT_COLOUR
) -> tuple[np.ndarray, dict]:
    """The input light fitted as a degree-2 SH radiance to shading = colour / albedo over the confident foreground
    (module docstring; :func:`frng.render.light_estimate.estimate_light_sh`, which F-RNG+'s pixel head also uses),
    expanded into an equirect map.

    rgb (V, H, W, 3) premultiplied, alpha (V, H, W, 1), albedo / normal (V, H, W, 3) (IDM priors, world normals).
    Returns (equirect map (height, 2 height, 3) float32, info)."""
    import torch

    from frng.render.light_estimate import LightEstimateError, estimate_light_sh, sh_to_env

    t = lambda x: torch.as_tensor(np.asarray(x))  # noqa: E731
    try:
        L, info = estimate_light_sh(t(rgb), t(alpha), t(albedo), t(normal), ridge=ridge, colour=colour)
    except LightEstimateError as e:
        raise CaptureError(f"{e}; give --light") from None
    return sh_to_env(L, height).numpy(), {**info, "sh": L.float().tolist()}


__all__ = [
    "Capture",
    "CaptureError",
    "Cam",
    "FRAMINGS",
    "MAX_VIEWS",
    "MIN_VIEWS",
    "Photo",
    "common_centre",
    "estimate_light",
    "frame_rig",
    "load_images",
    "make_masks",
    "match_cameras",
    "parse_grid",
    "prepare",
    "read_cameras",
    "read_image",
    "read_light",
    "resample",
    "rig_cameras",
]
