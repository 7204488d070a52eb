"""``frng render-asset ASSET --env MAP --out DIR`` (stage :mod:`frng.commands.render_asset`, no rule: run by hand, and
the viewer's "Save frame"): render a relightable asset folder
(:mod:`frng.apps.asset`, e.g. from ``frng reconstruct`` or ``frng relight``'s ``asset/``) under any equirect map, with
only the asset's files and its decoder (:class:`frng.apps.asset.AssetRenderer`: no F-RNG model, no training code), on
the CPU or CUDA.

Cameras: ``--cameras FILE`` (the formats of :func:`frng.apps.capture.read_cameras`, taken as they are, in the asset's
world), or ``--turntable N`` (default 24 when no file): N views around world Z at ``--elevation`` degrees, at the
training rig's distance and field of view recorded in the asset (``--distance``, ``--fov`` override), looking at the
origin. Bounded before anything is allocated: image sides up to :data:`MAX_RESOLUTION`, at most :data:`MAX_VIEWS`
views and :data:`MAX_SPP` light samples (one line otherwise). ``--out`` is written through
:func:`frng.confine.staged_output` (a non-empty folder that is not a previous render-asset output is refused
unless ``--force``; a failure leaves the previous output whole). Writes per view ``{view}.exr`` (linear premultiplied RGBA) and ``{view}.png`` (sRGB, straight alpha),
``cameras.json``, and for a turntable ``turntable.gif`` (imageio, Pillow writer; frames composited over white and
upscaled by an integer nearest-neighbour factor to at least :data:`VIDEO_MIN_SIZE` px; ``--video mp4`` uses the
imageio-ffmpeg plugin, pinned in requirements.lock (its own static FFmpeg binary, H.264); a clear error where neither
it nor PyAV is installed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

VIDEO_MIN_SIZE = 128  # turntable video frames are upscaled (nearest neighbour, integer factor) to at least this
MAX_RESOLUTION = 2048  # the largest image side rendered (--resolution or a camera file's sizes): memory grows with it
MAX_VIEWS = 1000  # the most views one call renders (--turntable N or a camera file)
MAX_SPP = 4096  # the most light samples per pixel (--spp, or the asset's shading.spp_infer)
DEFAULT_TURNTABLE = 24  # views of a turntable when neither --turntable nor --cameras is given


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``frng render-asset`` (its stage, and the viewer's "Save frame", which runs it in-process)."""
    parser.add_argument("asset", help="asset folder (asset.json, gaussians.ply, decoder.safetensors)")
    parser.add_argument("--env", required=True, help="equirect environment map (EXR/HDR, 2:1)")
    parser.add_argument("--out", required=True, help="output folder")
    cams = parser.add_mutually_exclusive_group()
    cams.add_argument("--cameras", help="camera file (transforms.json, OpenCV, frng cameras.json)")
    cams.add_argument("--turntable", type=int, help=f"N views around the object (default {DEFAULT_TURNTABLE})")
    parser.add_argument("--elevation", type=float, default=20.0, help="turntable elevation, degrees")
    parser.add_argument("--distance", type=float, help="turntable camera distance (default: the asset's rig)")
    parser.add_argument("--fov", type=float, help="turntable horizontal field of view (default: the asset's rig)")
    parser.add_argument("--resolution", type=int, help="image size (default: the asset's rig / the camera file)")
    parser.add_argument("--spp", type=int, help="light samples (default: the asset's shading.spp_infer)")
    parser.add_argument("--seed", type=int, default=0, help="light-sample seed")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or auto")
    parser.add_argument("--video", choices=["gif", "mp4", "none"], default="gif", help="turntable video format")
    parser.add_argument("--fps", type=float, default=12.0, help="turntable frames per second")
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace a non-empty --out that is not a previous render-asset output (only its files; others kept)",
    )


def _rig_number(rig: dict, key: str, default: float, source: Path, low: float, high: float) -> float:
    """``rig[key]`` of an asset (its training rig), checked: a finite number in (low, high] (a NaN field of view
    rendered all-zero frames); the default where absent."""
    from frng.apps.capture import CaptureError

    v = rig.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and low < v <= high):
        raise CaptureError(f"{source}: field 'rig.{key}' is {v!r}; must be a number in ({low:g}, {high:g}]")
    return float(v)


def turntable(n: int, elevation: float, distance: float, fov: float, res: int) -> list[dict]:
    from frng import camera

    out = []
    for i in range(n):
        eye = camera.spherical_to_cartesian(360.0 * i / n, elevation, distance)
        out.append(
            {
                "name": f"turn_{i:03d}",
                "c2w": camera.look_at(eye).tolist(),
                "intrinsics": camera.intrinsics_from_fov(fov, res, res).tolist(),
                "width": res,
                "height": res,
            }
        )
    return out


def write_video(path: Path, frames: list[np.ndarray], fps: float) -> Path:
    import imageio.v3 as iio

    from frng.apps.capture import CaptureError

    k = max(1, -(-VIDEO_MIN_SIZE // max(frames[0].shape[:2])))  # small renders: nearest-neighbour upscaled
    frames = [np.kron(f, np.ones((k, k, 1), np.uint8)) if k > 1 else f for f in frames]
    if path.suffix == ".gif":
        iio.imwrite(path, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0)
        return path
    try:
        iio.imwrite(path, np.stack(frames), fps=fps, extension=".mp4")
    except Exception as e:
        raise CaptureError(f"{path}: cannot write MP4 ({str(e).splitlines()[0][:120]})") from None
    return path


def check_video(kind: str) -> None:
    """Before rendering: an MP4 needs an imageio plugin that encodes video (imageio-ffmpeg or PyAV)."""
    import importlib.util

    from frng.apps.capture import CaptureError

    if kind == "mp4" and not any(importlib.util.find_spec(m) for m in ("imageio_ffmpeg", "av")):
        raise CaptureError("--video mp4: needs imageio-ffmpeg or PyAV (av) installed; use --video gif")


def render(args: argparse.Namespace) -> dict:
    import torch

    from frng import confine
    from frng.apps.capture import CaptureError, read_cameras, read_light
    from frng.apps.gltf_asset import open_renderer

    try:
        confine.check_output(args.out, "render-asset", args.force, recognise=lambda d: (d / "cameras.json").exists())
    except confine.OutputError as e:
        raise CaptureError(str(e)) from None
    if args.resolution is not None and not 1 <= args.resolution <= MAX_RESOLUTION:
        raise CaptureError(f"--resolution {args.resolution}: must be 1..{MAX_RESOLUTION} (MAX_RESOLUTION)")
    if args.spp is not None and not 1 <= args.spp <= MAX_SPP:
        raise CaptureError(f"--spp {args.spp}: must be 1..{MAX_SPP} (MAX_SPP)")
    if not (np.isfinite(args.fps) and args.fps > 0) or not np.isfinite(args.elevation):
        raise CaptureError("--fps must be > 0 and --elevation finite")
    for flag, v in (("--distance", args.distance), ("--fov", args.fov)):
        if v is not None and not (np.isfinite(v) and v > 0 and (flag != "--fov" or v < 180)):
            raise CaptureError(f"{flag} {v}: must be a finite number > 0" + (" and < 180" if flag == "--fov" else ""))
    env = read_light(args.env)  # 2:1, finite, bounded: or one line naming the file
    if not args.cameras:
        check_video(args.video)
    device = args.device
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise CaptureError("--device cuda: no CUDA device available")
    r = open_renderer(args.asset, device)
    rig = r.rig
    res = args.resolution or int(_rig_number(rig, "resolution", 64, Path(args.asset) / "asset.json", 0, 1e9))
    if args.cameras:
        cams = []
        for name, c in read_cameras(Path(args.cameras)):
            size = c.size or (res, res)
            intr = c.intr
            if args.resolution and c.size:
                s = args.resolution / c.size[0]
                intr, size = intr * s, (args.resolution, round(c.size[1] * s))
            cams.append(
                {
                    "name": name,
                    "c2w": c.c2w.tolist(),
                    "intrinsics": list(map(float, intr)),
                    "width": int(size[0]),
                    "height": int(size[1]),
                }
            )
        if len({(c["width"], c["height"]) for c in cams}) != 1:
            raise CaptureError(f"{args.cameras}: cameras of different image sizes; render them separately")
    else:
        n = DEFAULT_TURNTABLE if args.turntable is None else args.turntable
        if not 1 <= n <= MAX_VIEWS:
            raise CaptureError(f"--turntable {n}: N must be 1..{MAX_VIEWS}")
        meta = Path(args.asset) / "asset.json"
        distance = args.distance or _rig_number(rig, "camera_distance", 4.0, meta, 0.0, 1e4)
        fov = args.fov or _rig_number(rig, "fov_deg", 40.0, meta, 0.0, 180.0)
        cams = turntable(n, args.elevation, distance, fov, res)
    W, H = cams[0]["width"], cams[0]["height"]
    where = args.cameras or "the asset's rig (asset.json 'rig.resolution')"
    if not (1 <= W <= MAX_RESOLUTION and 1 <= H <= MAX_RESOLUTION):
        raise CaptureError(
            f"{where}: image size {W}x{H} is outside 1..{MAX_RESOLUTION} (MAX_RESOLUTION); pass --resolution"
        )
    if len(cams) > MAX_VIEWS:
        raise CaptureError(f"{args.cameras}: {len(cams)} cameras; at most {MAX_VIEWS} per call")
    spp = args.spp or int(r.shading.spp_infer)
    if not 1 <= spp <= MAX_SPP:
        raise CaptureError(
            f"{Path(args.asset) / 'asset.json'}: field 'render.shading.spp_infer' is {spp}; must be 1..{MAX_SPP}"
        )
    with confine.staged_output(
        args.out, "render-asset", args.force, recognise=lambda d: (d / "cameras.json").exists()
    ) as out:
        video = _render_into(out, r, env, cams, args)
    return {"views": len(cams), "size": [W, H], "device": str(r.device), "video": video}


def _render_into(out: Path, r, env: np.ndarray, cams: list[dict], args: argparse.Namespace) -> str | None:
    """Render ``cams`` into the (staging) folder ``out``; returns the video's final path, or None."""
    import torch

    from frng import io

    W, H = cams[0]["width"], cams[0]["height"]
    c2w = torch.tensor(np.array([c["c2w"] for c in cams]), dtype=torch.float32)
    intr = torch.tensor(np.array([c["intrinsics"] for c in cams]), dtype=torch.float32)
    env_t = torch.from_numpy(env)
    frames = []
    seen = lit = False
    for i0 in range(0, len(cams), 8):  # a few views at a time: bounded memory at large sizes
        g = torch.Generator().manual_seed(int(args.seed))
        rgba = r.render(env_t, c2w[i0 : i0 + 8], intr[i0 : i0 + 8], H, W, args.spp, g).cpu().numpy()
        check_render(rgba, [c["name"] for c in cams[i0 : i0 + 8]], args.asset)
        seen = seen or bool((rgba[..., 3] > 0).any())
        lit = lit or bool((rgba[..., :3] > 0).any())
        for c, img in zip(cams[i0 : i0 + 8], rgba):
            io.write_exr(out / f"{c['name']}.exr", img, channels=["R", "G", "B", "A"])
            a = np.clip(img[..., 3:4], 0, 1)
            straight = np.where(a > 1e-6, img[..., :3] / np.maximum(a, 1e-6), 0.0)
            io.write_png(out / f"{c['name']}.png", np.concatenate([io.srgb_encode(straight), a], -1))
            frames.append((np.clip(io.srgb_encode(io.composite(img)), 0, 1) * 255 + 0.5).astype(np.uint8))
    check_lit(seen, lit, float(env.max(initial=0.0)), args)
    io.write_json(out / "cameras.json", {"cameras": cams})
    if not args.cameras and args.video != "none":
        video = write_video(out / f"turntable.{args.video}", frames, args.fps)
        return str(Path(args.out) / video.name)
    return None


def check_render(rgba: np.ndarray, names: list[str], asset) -> None:
    """A rendered batch is finite, else one line naming the asset and the view (never a NaN image written)."""
    from frng.apps.capture import CaptureError

    bad = ~np.isfinite(rgba).reshape(len(rgba), -1).all(axis=1)
    if bad.any():
        raise CaptureError(
            f"{asset}: the render of view {names[int(np.argmax(bad))]!r} has non-finite values (NaN or inf); nothing "
            f"was written"
        )


def check_lit(seen: bool, lit: bool, light_max: float, args) -> None:
    """After every view: a turntable (cameras around the object, looking at it) that sees nothing of the asset, or
    an asset that renders black in every view it covers under a light that is not black, is an error, not a folder
    of empty or black images. (A camera file may look away from the object: its empty frames are written.)"""
    from frng.apps.capture import CaptureError

    if not seen and not args.cameras:
        raise CaptureError(
            f"{args.asset}: no turntable view sees the asset (every pixel empty; check --distance / --fov and the "
            f"asset's rig); nothing was written"
        )
    if light_max > 0 and not lit:
        raise CaptureError(
            f"{args.asset}: every view renders black under {args.env}, a light that is not black (its decoder or "
            f"features give no light back); nothing was written"
        )
