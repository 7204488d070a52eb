"""Objects With Lighting (OWL): reader and writer of its published layout (``dataset/{object}/test/``).

Official code and documentation read (github.com/isl-org/objects-with-lighting):

- ``README.md`` "Dataset format": ``inputs/image_xxxx.png`` (8-bit, tone-mapped), ``inputs/mask_xxxx.png``,
  ``inputs/camera_xxxx.txt``, ``inputs/exposure.txt``, ``inputs/object_bounding_box.txt``; ``env.hdr`` +
  ``world_to_env.txt`` (the input images' environment; "for debugging" in OWL's protocol, where methods estimate
  the light -- F-RNG's setting has a KNOWN input light, so the import uses it and says so in ``meta.json``);
  ``gt_image_xxxx.png``, ``gt_mask_xxxx.png``, ``gt_camera_xxxx.txt``, ``gt_exposure_xxxx.txt``,
  ``gt_env_xxxx.hdr``, ``gt_world_to_env_xxxx.txt`` per test view.
- Cameras (README "Camera parameters", ``utils/camera.py``): rows K (3), R (3), t, then ``width height
  channels``; ``x = K (R X + t)``: world-to-camera in OpenCV axes (cameras look along +z, y down, pixel centres
  at +0.5) -- the project's own convention, so ``c2w = inv([R | t])``, ``(fx, fy, cx, cy)`` from K.
- Tone mapping (README, ``utils/hdri.py`` ``apply_exposure_and_gamma``): ``y = 255 (x 2^exposure)^(1/2.2)``,
  clipped; inverted here once: ``x = (y / 255)^2.2 / 2^exposure`` (saturated pixels stay clipped).
- Env maps (README "Environment maps", ``utils/equirectangular.py``): ``u = 0.5 - atan2(y, x) / 2 pi``,
  ``v = asin(-z) / pi + 0.5`` = ``acos(z) / pi``: +Z at the top, +X at the centre, +Y at u = 0.25 -- exactly
  :mod:`frng.render.envmap`'s convention, in the frame of ``world_to_env`` (rotation part; directions only).
- Evaluation (``scripts/evaluate.py``, ``utils/metrics.py``): :func:`frng.benchmarks.protocols.owl`.

World frame of the import: OWL's world rotated by the input ``world_to_env`` rotation (the env frame, Z up by
OWL's convention), then normalised (:mod:`frng.benchmarks.common`). So the input map is used as stored, and a
test view's map ``gt_env_k`` becomes ``E(d) = E_k(R_k R_in^T d)``. Each test view keeps its own light.

The writer (``frng export --layout owl``) writes a curated object with identity ``world_to_env`` (the project's
world is Z up), the input light as ``env.hdr``, one ``gt_*`` set per (target light, target view), exposures
chosen so the brightest foreground value maps to 0.95 before the 8-bit quantisation.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from frng import confine, io
from frng.benchmarks.common import (
    BenchmarkError,
    Curated,
    Scene,
    View,
    need,
    read_map,
    read_mask_png,
    read_png,
    rotate_map,
)

LAYOUT = "owl"
PROTOCOL = "owl"
GAMMA = 2.2


def read_camera(path: Path) -> tuple[np.ndarray, np.ndarray, int, int]:
    """camera_xxxx.txt -> (OpenCV c2w (4, 4), K (fx, fy, cx, cy), width, height)."""
    need(path, "camera file")
    try:
        p = np.loadtxt(path)
    except ValueError as e:
        raise BenchmarkError(f"{path}: not a numeric OWL camera file ({e})") from e
    if p.shape != (8, 3):
        raise BenchmarkError(f"{path}: expected 8 rows of 3 numbers (K, R, t, width height channels), got {p.shape}")
    confine.finite(p, source=path, field="camera")
    if not (p[7, :2] > 0).all() or not (np.linalg.det(p[3:6]) != 0):
        raise BenchmarkError(f"{path}: camera has a size <= 0 or a singular rotation")
    K, R, t, (w, h, _) = p[:3], p[3:6], p[6], p[7].astype(int)
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, t
    return np.linalg.inv(w2c), np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]), int(w), int(h)


def read_scalar(path: Path) -> float:
    need(path)
    try:
        x = float(np.loadtxt(path).reshape(-1)[0])
    except (ValueError, IndexError) as e:
        raise BenchmarkError(f"{path}: expected one number") from e
    return float(confine.finite(x, source=path, field="value", minimum=-64, maximum=64))


def read_matrix(path: Path) -> np.ndarray:
    need(path)
    try:
        m = np.loadtxt(path).reshape(4, 4)
    except ValueError as e:
        raise BenchmarkError(f"{path}: expected a 4x4 matrix") from e
    return confine.finite(m, source=path, field="matrix")


def untonemap(img: np.ndarray, exposure: float) -> np.ndarray:
    return (np.power(np.clip(img[..., :3], 0, 1), GAMMA) / 2.0**exposure).astype(np.float32)


def tonemap(lin: np.ndarray, exposure: float) -> np.ndarray:
    return np.clip(np.power(np.clip(lin * 2.0**exposure, 0, None), 1 / GAMMA), 0, 1)


def _view(image: Path, mask: Path, cam: Path, exposure: float, light: str) -> View:
    c2w, K, w, h = read_camera(cam)
    rgb = untonemap(read_png(image), exposure)
    if rgb.shape[:2] != (h, w):
        raise BenchmarkError(f"{image}: image is {rgb.shape[1]}x{rgb.shape[0]}, {cam.name} says {w}x{h}")
    return View(
        name=image.stem,
        c2w=c2w,
        K=K,
        rgb=rgb,
        mask=read_mask_png(mask),
        light=light,
        source=str(image),
        exposure=exposure,
    )


def _ids(folder: Path, prefix: str) -> list[str]:
    pat = re.compile(rf"^{prefix}(\d+)\.png$")
    return sorted(m.group(1) for f in folder.iterdir() if (m := pat.match(f.name)))


def read(path: str | Path, envmap_height: int | None = None, allow_outside: bool = False) -> Scene:
    """The test folder ``path``; its files must resolve inside it (a symlink out is refused unless
    ``allow_outside``)."""
    root = need(Path(path), "OWL test folder (dataset/{object}/test)")
    if not allow_outside and root.is_dir():
        for f in sorted(root.rglob("*")):
            confine.inside(f, root)
    inputs = need(root / "inputs", "inputs/ folder (OWL layout)")
    e_in = read_scalar(inputs / "exposure.txt")
    ids = _ids(inputs, "image_")
    if not ids:
        raise BenchmarkError(f"{inputs}: no image_xxxx.png (OWL layout)")
    train = [
        _view(inputs / f"image_{i}.png", inputs / f"mask_{i}.png", inputs / f"camera_{i}.txt", e_in, "input")
        for i in ids
    ]
    R_in = read_matrix(root / "world_to_env.txt")[:3, :3]
    lights = {"input": _resize(read_map(root / "env.hdr"), envmap_height)}
    test = []
    for i in _ids(root, "gt_image_"):
        e = read_scalar(root / f"gt_exposure_{i}.txt")
        light = f"gt_{i}"
        test.append(_view(root / f"gt_image_{i}.png", root / f"gt_mask_{i}.png", root / f"gt_camera_{i}.txt", e, light))
        R_k = read_matrix(root / f"gt_world_to_env_{i}.txt")[:3, :3]
        # E'(d) = E_k(R_k R_in^T d): rotate_map(E, R) gives E(R^T d), so R = (R_k R_in^T)^T
        lights[light] = rotate_map(_resize(read_map(root / f"gt_env_{i}.hdr"), envmap_height), (R_k @ R_in.T).T)
    # the maps are already in the rotated (env) frame: hand the rotation to the normalisation for the cameras only
    obj = root.parent.name if root.name == "test" else root.name
    scene = Scene(
        layout=LAYOUT,
        scene=obj,
        path=str(root),
        protocol=PROTOCOL,
        train=train,
        test=test,
        lights=lights,
        input_light="input",
        world_rotation=R_in,
        notes={
            "input_light": "env.hdr (OWL: for debugging; F-RNG's setting has a known input light)",
            "lights_in_world_frame": True,
        },
    )
    return scene


def _resize(img: np.ndarray, height: int) -> np.ndarray:
    from frng.render import envmap

    return envmap.resize(img, 2 * height) if height and img.shape[0] != height else img


def _exposure(rgb: np.ndarray, mask: np.ndarray) -> float:
    fg = rgb[mask > 0]
    peak = float(fg.max()) if fg.size else 1.0
    return math.log2(0.95**GAMMA / peak) if peak > 0 else 0.0


def _write_camera(path: Path, v: dict) -> None:
    w2c = np.linalg.inv(np.asarray(v["c2w"], dtype=np.float64))
    fx, fy, cx, cy = v["intrinsics"]
    rows = [
        [fx, 0, cx],
        [0, fy, cy],
        [0, 0, 1],
        *w2c[:3, :3].tolist(),
        w2c[:3, 3].tolist(),
        [int(v["width"]), int(v["height"]), 3],
    ]
    with io.atomic_path(path) as tmp:
        tmp.write_text(
            "\n".join(" ".join(repr(float(x)) if j < 7 else str(int(x)) for x in r) for j, r in enumerate(rows)) + "\n"
        )


def _write_image(folder: Path, stem: str, mask_stem: str, rgba: np.ndarray, exposure: float | None) -> float:
    a = rgba[..., 3]
    rgb = np.where(a[..., None] > 1e-6, rgba[..., :3] / np.maximum(a, 1e-6)[..., None], 0.0)
    e = _exposure(rgb, a) if exposure is None else exposure
    io.write_png(folder / f"{stem}.png", tonemap(rgb, e))
    io.write_png(folder / f"{mask_stem}.png", np.repeat(np.clip(a, 0, 1)[..., None], 3, -1))
    return e


def write(cur: Curated, out: str | Path, scene: str | None = None) -> Path:
    out = Path(out)
    root = out / (scene or cur.oid) / "test"
    inputs = root / "inputs"
    views = cur.inputs + cur.extra
    imgs = [cur.image("inputs", cur.input_light, v["name"]) for v in views]
    # one exposure for all input images (exposure.txt), from the brightest
    e_in = min(
        _exposure(np.where(i[..., 3:] > 1e-6, i[..., :3] / np.maximum(i[..., 3:], 1e-6), 0), i[..., 3]) for i in imgs
    )
    for k, (v, img) in enumerate(zip(views, imgs)):
        _write_image(inputs, f"image_{k:04d}", f"mask_{k:04d}", img, e_in)
        _write_camera(inputs / f"camera_{k:04d}.txt", v)
    _text(inputs / "exposure.txt", f"{e_in!r}\n")
    _text(inputs / "object_bounding_box.txt", "-1 1 -1 1 -1 1\n")
    eye = "\n".join(" ".join(str(float(x)) for x in r) for r in np.eye(4)) + "\n"
    io.write_hdr(root / "env.hdr", cur.envmap(cur.input_light))
    _text(root / "world_to_env.txt", eye)
    k = 0
    for light in cur.target_lights:
        env = cur.envmap(light)
        for v in cur.targets:
            e = _write_image(
                root, f"gt_image_{k:04d}", f"gt_mask_{k:04d}", cur.image("targets", light, v["name"]), None
            )
            _write_camera(root / f"gt_camera_{k:04d}.txt", v)
            _text(root / f"gt_exposure_{k:04d}.txt", f"{e!r}\n")
            io.write_hdr(root / f"gt_env_{k:04d}.hdr", env)
            _text(root / f"gt_world_to_env_{k:04d}.txt", eye)
            k += 1
    return root


def _text(path: Path, text: str) -> None:
    with io.atomic_path(path) as tmp:
        tmp.write_text(text)
