"""Cameras from the photos alone: structure from motion on the CPU (``frng reconstruct --sfm``, issue 88).

:func:`cameras_from_photos` runs COLMAP's classic pipeline through pycolmap (its Python bindings, pinned in
requirements.txt; no GPU, no download) on a folder of photos and returns the cameras as a
:class:`frng.apps.camera_formats.CameraSet`, the same records a COLMAP model read from files gives
(:func:`frng.apps.camera_formats.colmap_camera_set`), so undistortion, the upright and centred frame and the choice
of views (:mod:`frng.apps.capture_frame`) apply unchanged. One progress line per stage (``progress``):

1. **features**: SIFT on the CPU, each photo at most :data:`MAX_IMAGE_SIZE` px on its long side (COLMAP resizes
   for the extraction; keypoints are in the photo's pixels), at most :data:`MAX_FEATURES` per photo. One shared
   camera (``SIMPLE_RADIAL``: focal length, principal point, k1) when every photo has the same size, else one per
   photo; COLMAP takes the focal length's prior from the photo's EXIF where it has one (else 1.2 x the long side).
   JPEG and PNG photos are read where they are; a folder holding EXR photos is first written as 8-bit sRGB PNG
   copies into the scratch folder (COLMAP reads no EXR).
2. **matching**: every pair of photos (exhaustive), nearest neighbours with the ratio test and a cross check, then
   geometric verification (a two-view geometry with at least :data:`MIN_MATCHES` inlier matches).
3. **mapping**: incremental mapping (seeded, :data:`SEED`) from the best pair, bundle adjustment refining the
   focal length and k1; of several models the one with the most registered photos is kept.

The scratch folder (COLMAP's database, its model files, the PNG copies) is made in ``work`` (``frng reconstruct``:
beside or inside ``--out``, where its staging folder goes) or, without one, in the system's temporary folder, and
removed however the run ends. The cameras come out in the model's arbitrary frame (its scale, its up); the sparse
points and, per photo, the pixel positions of its keypoints that became sparse points come with them
(:attr:`CameraSet.observations`: what seeds the masks of photos that have none, :mod:`frng.apps.masks`).

What fails is one line naming the folder (:class:`frng.apps.capture_errors.CaptureError`): fewer than
:data:`MIN_PHOTOS` photos; too few matches (no pair of photos with :data:`MIN_MATCHES` verified matches, or a
photo with too few features: both named); no reconstruction (no pair to start from: the best pair named with its
inlier count); photos that did not register in the model kept, when fewer than ``need`` did (named, with their
verified matches; remove them or take photos between them). When at least ``need`` photos registered (``frng
reconstruct``: the views the model takes, ``--select N`` or the training rig's 6), the others are left out instead:
one progress line ``sfm: not registered, left out: a.jpg, b.jpg (...)`` and ``notes["sfm"]["not_registered"]``
(recorded in the asset's ``capture.sfm``). COLMAP's own log is silent unless ``frng --debug``.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from frng import confine
from frng.apps import camera_formats
from frng.apps.capture_errors import CaptureError

MIN_PHOTOS = 3  # structure from motion wants every part seen from three places
MAX_IMAGE_SIZE = 2000  # px, long side, for SIFT (COLMAP resizes; keypoints come back in the photo's pixels)
MAX_FEATURES = 8192
MIN_MATCHES = 15  # inlier matches of a verified pair (COLMAP's default)
MIN_FEATURES = 50  # a photo with fewer SIFT features than this is named as too plain
SEED = 0
READABLE = (".png", ".jpg", ".jpeg")  # what COLMAP reads in place; others are converted to PNG copies
FORMAT = "SfM (pycolmap)"


def say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


@contextlib.contextmanager
def scratch(work: str | Path | None, label: str = "sfm") -> Iterator[Path]:
    """A new empty folder ``.tmp-frng-{label}-*`` in ``work`` (an existing folder), else in the system's temporary
    folder; removed with everything in it when the block ends, however it ends."""
    if work is not None and Path(work).is_dir():
        tmp = confine.temp_dir(f".tmp-frng-{label}-", work)
    else:
        tmp = Path(tempfile.mkdtemp(prefix=f"frng-{label}-"))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def _colmap_log():
    """COLMAP's log silent (errors are ours, one line) unless ``frng --debug``; restored afterwards."""
    import pycolmap

    from frng import cli

    before = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if cli.DEBUG else 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = before


def _read_exr(path: Path) -> tuple[np.ndarray, None]:
    from frng import io

    try:
        return io.read_rgba(path)[..., :3], None
    except (io.ImageError, ValueError, OSError) as e:
        raise CaptureError(f"{path}: cannot read EXR ({e})") from None


def _image_folder(files: list[Path], tmp: Path, read) -> tuple[Path, list[str]]:
    """The folder COLMAP reads and the photos' names in it: the photos' own folder when COLMAP reads them all
    (:data:`READABLE`), else 8-bit sRGB PNG copies in ``tmp/images`` (premultiplied photos over black)."""
    folder = files[0].parent
    if all(f.suffix.lower() in READABLE and f.parent == folder for f in files):
        return folder, [f.name for f in files]
    from frng import io

    out = tmp / "images"
    out.mkdir()
    names = []
    for f in files:
        rgb, _ = (read or _read_exr)(f)
        io.write_png(out / f"{f.stem}.png", io.srgb_encode(np.clip(rgb, 0.0, None)))
        names.append(f"{f.stem}.png")
    return out, names


def _pairs(db, names_by_id: dict[int, str]) -> tuple[dict[tuple[str, str], int], dict[str, int]]:
    """Verified pairs: (name a, name b) -> inlier matches; per photo its SIFT feature count."""
    import pycolmap

    feats = {n: int(db.num_keypoints_for_image(i)) for i, n in names_by_id.items()}
    ids, geoms = db.read_two_view_geometries()
    pairs = {}
    for pid, g in zip(ids, geoms):
        a, b = pycolmap.pair_id_to_image_pair(pid)
        n = 0 if g.inlier_matches is None else int(len(g.inlier_matches))
        if a in names_by_id and b in names_by_id:
            pairs[(names_by_id[a], names_by_id[b])] = n
    return pairs, feats


def _best_pair(pairs: dict[tuple[str, str], int]) -> str:
    if not pairs:
        return "no pair of photos has any verified match"
    (a, b), n = max(pairs.items(), key=lambda kv: kv[1])
    return f"best pair {Path(a).stem} / {Path(b).stem}: {n} inlier matches"


def _to_camera_set(rec, folder: Path, stats: dict) -> camera_formats.CameraSet:
    """A pycolmap Reconstruction -> the COLMAP model's camera records (module docstring)."""
    cams = {
        int(cid): (c.model.name, (int(c.width), int(c.height)), [float(x) for x in c.params], f"{folder}: camera {cid}")
        for cid, c in rec.cameras.items()
    }
    images = []
    pid_rows = {}
    xyz = []
    for pid, pt in rec.points3D.items():
        pid_rows[int(pid)] = len(xyz)
        xyz.append(np.asarray(pt.xyz, np.float64))
    points = np.asarray(xyz, np.float64).reshape(-1, 3)
    observations = {}
    for im in rec.images.values():
        T = im.cam_from_world()
        x, y, z, w = (float(v) for v in T.rotation.quat)  # Eigen's order
        t = [float(v) for v in T.translation]
        where = f"{folder}: photo {im.name} (structure from motion)"
        images.append((im.name, [w, x, y, z], t, int(im.camera_id), where))
        seen = [(p.xy, pid_rows[int(p.point3D_id)]) for p in im.points2D if p.has_point3D()]
        observations[Path(im.name).stem] = (
            np.asarray([s[0] for s in seen], np.float64).reshape(-1, 2),
            np.asarray([s[1] for s in seen], np.int64),
        )
    return camera_formats.colmap_camera_set(
        folder, cams, images, points, fmt=FORMAT, notes={"sfm": stats}, observations=observations
    )


def cameras_from_photos(
    files: list[Path],
    folder: str | Path,
    *,
    work: str | Path | None = None,
    progress: Callable[[str], None] | None = say,
    single_camera: bool | None = None,
    read=None,
    need: int | None = None,
) -> camera_formats.CameraSet:
    """Structure from motion over ``files`` (the photos of ``folder``, which errors name) -> their cameras
    (module docstring). ``work``: where the scratch folder goes (:func:`scratch`); ``progress``: called with one
    line per stage (None: silent); ``single_camera``: one camera for all photos (default: when their sizes agree);
    ``read(path)`` -> (linear RGB (H, W, 3), alpha or None): how a photo COLMAP cannot read is decoded
    (:func:`frng.apps.capture.read_image`; default: EXR only). ``need``: with at least this many photos
    registered, the photos that did not register are left out (named in one progress line and in the returned
    set's ``notes["sfm"]["not_registered"]``, their file names); with fewer, or with ``need`` None, they are an
    error naming them."""
    import pycolmap

    say = progress or (lambda line: None)
    folder = Path(folder)
    files = [Path(f) for f in files]
    if len(files) < MIN_PHOTOS:
        raise CaptureError(
            f"{folder}: {len(files)} photo(s); structure from motion (--sfm) needs at least {MIN_PHOTOS} photos of "
            f"the object from different places (more is better: 20-100 around it)"
        )
    for f in files:  # the header's pixel count is bounded before COLMAP decodes anything
        try:
            confine.check_image_size(f)
        except confine.UntrustedInputError as e:
            raise CaptureError(str(e)) from None
    if single_camera is None:
        from PIL import Image

        sizes = set()
        for f in files:
            if f.suffix.lower() in READABLE:
                with Image.open(f) as im:
                    sizes.add(im.size)
            else:
                sizes.add(confine.check_image_size(f))
        single_camera = len(sizes) == 1
    stats: dict = {"pycolmap": pycolmap.__version__, "photos": len(files), "seconds": {}}
    with scratch(work) as tmp, _colmap_log():
        images, names = _image_folder(files, tmp, read)
        db_path = tmp / "database.db"
        t0 = time.perf_counter()
        say(f"sfm: extracting SIFT features from {len(files)} photos (CPU) ...")
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.max_image_size = MAX_IMAGE_SIZE
        extraction.sift.max_num_features = MAX_FEATURES
        extraction.use_gpu = False
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "SIMPLE_RADIAL"
        mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.PER_IMAGE
        pycolmap.set_random_seed(SEED)
        pycolmap.extract_features(
            db_path,
            images,
            image_names=names,
            camera_mode=mode,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        with pycolmap.Database.open(db_path) as db:
            names_by_id = {int(im.image_id): im.name for im in db.read_all_images()}
            feats = {n: int(db.num_keypoints_for_image(i)) for i, n in names_by_id.items()}
        missing = [n for n in names if n not in feats]
        if missing:
            raise CaptureError(f"{folder}: structure from motion could not read photo(s) {missing[:5]}")
        stats["seconds"]["features"] = round(time.perf_counter() - t0, 2)
        stats["features_median"] = int(np.median(list(feats.values())))
        say(
            f"sfm: {stats['features_median']} SIFT features per photo (median; fewest {min(feats.values())} in "
            f"{Path(min(feats, key=feats.get)).stem}) in {stats['seconds']['features']:.1f} s; matching "
            f"{len(files) * (len(files) - 1) // 2} pairs ..."
        )
        t0 = time.perf_counter()
        matching = pycolmap.FeatureMatchingOptions()
        matching.use_gpu = False
        verification = pycolmap.TwoViewGeometryOptions()
        verification.min_num_inliers = MIN_MATCHES
        pycolmap.match_exhaustive(
            db_path, matching_options=matching, verification_options=verification, device=pycolmap.Device.cpu
        )
        with pycolmap.Database.open(db_path) as db:
            pairs, feats = _pairs(db, names_by_id)
        good = {k: n for k, n in pairs.items() if n >= MIN_MATCHES}
        stats["seconds"]["matching"] = round(time.perf_counter() - t0, 2)
        stats["verified_pairs"] = len(good)
        if not good:
            plain = sorted((Path(n).stem for n, k in feats.items() if k < MIN_FEATURES))
            why = f"; too few features (< {MIN_FEATURES}) in {plain[:5]}" if plain else ""
            raise CaptureError(
                f"{folder}: structure from motion found too few matches: no pair of the {len(files)} photos shares "
                f"{MIN_MATCHES} verified feature matches ({_best_pair(pairs)}{why}); the photos must overlap and "
                f"show texture"
            )
        say(
            f"sfm: {len(good)} of {len(files) * (len(files) - 1) // 2} pairs verified ({_best_pair(good)}) in "
            f"{stats['seconds']['matching']:.1f} s; incremental mapping ..."
        )
        t0 = time.perf_counter()
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = SEED
        options.min_num_matches = MIN_MATCHES
        options.min_model_size = MIN_PHOTOS
        options.ba_use_gpu = False
        sparse = tmp / "sparse"
        sparse.mkdir()
        models = pycolmap.incremental_mapping(db_path, images, sparse, options)
        stats["seconds"]["mapping"] = round(time.perf_counter() - t0, 2)
        if not models:
            raise CaptureError(
                f"{folder}: structure from motion made no reconstruction: no pair of photos could start one "
                f"({_best_pair(good)}; a start needs {options.mapper.init_min_num_inliers} inlier matches between "
                f"photos taken from places far enough apart); walk around the object, not only turn the camera"
            )
        rec = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
        registered = {im.name for im in rec.images.values()}
        lost = [n for n in names if n not in registered]
        original = {n: f.name for n, f in zip(names, files)}  # COLMAP's name (a PNG copy's) -> the photo's file
        if lost:
            verified = {n: sum(1 for (a, b) in good if n in (a, b)) for n in lost}
            split = f"; the photos fell into {len(models)} separate models" if len(models) > 1 else ""
            enough = need is not None and len(registered) >= need
            if not enough:
                detail = ", ".join(f"{original[n]} ({verified[n]} verified pairs)" for n in lost[:8])
                more = f" and {len(lost) - 8} more" if len(lost) > 8 else ""
                short = f", fewer than the {need} views the model takes" if need is not None else ""
                raise CaptureError(
                    f"{folder}: structure from motion registered {len(registered)} of {len(names)} photos{short}; "
                    f"these did not register: {detail}{more}{split}; remove them from the folder or take photos "
                    f"between them"
                )
            stats["not_registered"] = [original[n] for n in lost]
            say(
                f"sfm: not registered, left out: {', '.join(original[n] for n in lost)} ({len(registered)} of "
                f"{len(names)} photos registered, {need} needed{split})"
            )
        stats |= {
            "registered": len(registered),
            "points": int(rec.num_points3D()),
            "reprojection_error_px": round(float(rec.compute_mean_reprojection_error()), 3),
            "models": len(models),
        }
        cset = _to_camera_set(rec, folder, stats)
    say(
        f"sfm: {stats['registered']} of {len(names)} photos registered, {stats['points']} sparse points, "
        f"reprojection error {stats['reprojection_error_px']:.2f} px, in {stats['seconds']['mapping']:.1f} s"
    )
    return cset


__all__ = ["FORMAT", "MIN_MATCHES", "MIN_PHOTOS", "cameras_from_photos", "scratch"]
