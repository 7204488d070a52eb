"""TensoIR synthetic (armadillo, ficus, hotdog, lego): reader and writer of its published layout.

Official code read (github.com/Haian-Jin/TensoIR):

- ``dataLoader/tensoIR_rotation_setting.py`` and ``dataLoader/tensoIR_relighting_test.py``: a scene folder holds
  one folder per view whose name starts with the split (``x.stem.startswith(split)``: ``train_000``, ``test_000``
  ...); each has ``metadata.json`` with ``imw``, ``imh``, ``cam_angle_x`` and ``cam_transform_mat`` (16
  comma-separated floats, row-major: Blender's camera-to-world), converted with
  ``pose = cam_trans @ blender2opencv``, ``blender2opencv = diag(1, -1, -1, 1)`` -- exactly
  :func:`frng.camera.c2w_from_blender`; ``focal = 0.5 * imw / tan(0.5 * cam_angle_x)``, principal point at the
  image centre. Images ``rgba_{light}.png`` (8-bit sRGB, straight alpha; the loader composites them on white as
  ``rgb * a + (1 - a)`` and takes ``a != 0`` as the mask), plus ``albedo.png`` and ``normal.png`` (not used here).
- ``scripts/relight_importance.py`` / ``models/relight_utils.py``: the relighting lights are ``{light}.hdr``
  equirect maps (a separate download, e.g. ``light_probes/``), world Z up, longitude from +pi at the left edge to
  -pi at the right with +X at the centre: the same convention as :mod:`frng.render.envmap` (Blender's), so the maps are
  used as read, no conversion.

Conversion (once, here): cameras through :func:`frng.camera.c2w_from_blender`; PNGs sRGB-decoded to linear,
alpha kept as the mask; the training light is the one ``rgba_{light}.png`` name common to the training folders
(or ``rgba.png`` with ``--input-light``, default ``sunset``); the targets are every test folder under every
other light found there (``--lights`` restricts them). World frame: Blender's, Z up, then the normalisation of
:mod:`frng.benchmarks.common`. Protocol: :func:`frng.benchmarks.protocols.tensoir`.

The writer (``frng export --layout tensoir``) produces the same files from a curated object: ``train_{k:03d}/``
for the rig (and extra) input views under the input light, ``test_{k:03d}/`` for the target views with one
``rgba_{light}.png`` per target light, and ``light_probes/{light}.hdr`` beside the scene folder.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from frng import camera, confine, io
from frng.benchmarks.common import (
    BenchmarkError,
    Curated,
    Scene,
    View,
    fov_x,
    need,
    read_json,
    read_map,
    read_srgba_png,
    write_srgba_png,
)

LAYOUT = "tensoir"
PROTOCOL = "tensoir"
DEFAULT_INPUT_LIGHT = "sunset"
_RGBA = re.compile(r"^rgba_(.+)\.png$")


def parse_metadata(path: Path) -> tuple[np.ndarray, np.ndarray, int, int]:
    """metadata.json -> (OpenCV c2w (4, 4), K (fx, fy, cx, cy), width, height); every number checked (finite,
    sizes positive integers, the field of view in (0, pi))."""
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise BenchmarkError(f"{path}: not a JSON object (TensoIR metadata.json)")
    for key in ("imw", "imh", "cam_angle_x", "cam_transform_mat"):
        if key not in meta:
            raise BenchmarkError(f"{path}: missing key {key!r} (TensoIR metadata.json)")
    try:
        m = np.array([float(x) for x in str(meta["cam_transform_mat"]).split(",")]).reshape(4, 4)
    except ValueError as e:
        raise BenchmarkError(f"{path}: cam_transform_mat is not 16 comma-separated floats") from e
    confine.finite(m, source=path, field="cam_transform_mat")
    for key in ("imw", "imh"):
        if isinstance(meta[key], bool) or not isinstance(meta[key], int) or not 0 < meta[key] <= 1 << 16:
            raise BenchmarkError(f"{path}: field {key!r} must be a positive integer, got {meta[key]!r}")
    w, h = int(meta["imw"]), int(meta["imh"])
    angle = confine.angle(meta["cam_angle_x"], source=path, field="cam_angle_x")
    focal = 0.5 * w / np.tan(0.5 * angle)
    return camera.c2w_from_blender(m), np.array([focal, focal, w / 2.0, h / 2.0]), w, h


def _lights_in(folder: Path) -> list[str]:
    return sorted(m.group(1) for f in folder.iterdir() if (m := _RGBA.match(f.name)))


def _view(
    folder: Path, light: str, file_light: str | None = None, root: Path | None = None, allow_outside=False
) -> View:
    png = folder / (f"rgba_{file_light}.png" if file_light else "rgba.png")
    if root is not None:  # a symlink out of the scene folder
        for f in (folder / "metadata.json", png):
            confine.inside(f, root, allow_outside=allow_outside)
    c2w, K, w, h = parse_metadata(folder / "metadata.json")
    rgb, a = read_srgba_png(png)
    if rgb.shape[:2] != (h, w):
        raise BenchmarkError(f"{png}: image is {rgb.shape[1]}x{rgb.shape[0]}, its metadata.json says {w}x{h}")
    return View(name=folder.name, c2w=c2w, K=K, rgb=rgb, mask=a, light=light, source=str(png))


def read(
    path: str | Path,
    envmaps: str | Path | None = None,
    input_light: str | None = None,
    lights: list[str] | None = None,
    allow_outside: bool = False,
) -> Scene:
    """The scene folder ``path``; its files must resolve inside it (a symlink out is refused unless
    ``allow_outside``); the light probes are read from ``envmaps`` (default: found beside the scene)."""
    root = need(Path(path), "TensoIR scene folder")
    if not root.is_dir():
        raise BenchmarkError(f"{root}: not a folder (expected a TensoIR scene with train_*/ and test_*/ folders)")
    train_dirs = sorted(d for d in root.iterdir() if d.is_dir() and d.name.startswith("train"))
    test_dirs = sorted(d for d in root.iterdir() if d.is_dir() and d.name.startswith("test"))
    if not train_dirs or not test_dirs or not any((d / "metadata.json").exists() for d in train_dirs):
        raise BenchmarkError(f"{root}: not the TensoIR layout (no train_*/ or test_*/ folders with metadata.json)")
    # the training light: the rgba_{light}.png common to every training folder, else rgba.png
    common = set(_lights_in(train_dirs[0]))
    for d in train_dirs[1:]:
        common &= set(_lights_in(d))
    if input_light is None:
        input_light = (
            sorted(common)[0]
            if len(common) == 1
            else (DEFAULT_INPUT_LIGHT if DEFAULT_INPUT_LIGHT in common or not common else None)
        )
        if input_light is None:
            raise BenchmarkError(
                f"{train_dirs[0]}: several training lights {sorted(common)}; choose one with --input-light"
            )
    train_file_light = input_light if input_light in common else None
    if train_file_light is None and not (train_dirs[0] / "rgba.png").exists():
        raise BenchmarkError(f"{train_dirs[0] / f'rgba_{input_light}.png'}: missing training image")
    train = [_view(d, input_light, train_file_light, root, allow_outside) for d in train_dirs]
    found = _lights_in(test_dirs[0])
    targets = [l for l in (lights or found) if l != input_light] or [input_light]
    test = [_view(d, l, l, root, allow_outside) for l in targets for d in test_dirs]
    # maps
    if envmaps is None:
        cands = [root.parent / "light_probes", root.parent / "envmaps", root / "light_probes"]
        envmaps = next((c for c in cands if c.is_dir()), cands[0])
    envmaps = Path(envmaps)
    maps = {l: read_map(envmaps / f"{l}.hdr") for l in dict.fromkeys([input_light, *targets])}
    return Scene(
        layout=LAYOUT,
        scene=root.name,
        path=str(root),
        protocol=PROTOCOL,
        train=train,
        test=test,
        lights=maps,
        input_light=input_light,
        notes={"envmaps": str(envmaps.resolve())},
    )


def _write_view(folder: Path, view: dict, images: dict[str, np.ndarray]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    c2w_blender = camera.c2w_to_blender(np.asarray(view["c2w"], dtype=np.float64))
    w, h = int(view["width"]), int(view["height"])
    io.write_json(
        folder / "metadata.json",
        {
            "imw": w,
            "imh": h,
            "cam_angle_x": fov_x(view["intrinsics"], w),
            "cam_transform_mat": ",".join(repr(float(x)) for x in c2w_blender.reshape(-1)),
        },
    )
    for light, rgba in images.items():
        write_srgba_png(folder / f"rgba_{light}.png", rgba)


def write(cur: Curated, out: str | Path, scene: str | None = None) -> Path:
    """Write a curated object in TensoIR's layout under ``out``; returns the scene folder (what ``frng import
    tensoir`` reads)."""
    out = Path(out)
    root = out / (scene or cur.oid)
    for k, v in enumerate(cur.inputs + cur.extra):
        _write_view(root / f"train_{k:03d}", v, {cur.input_light: cur.image("inputs", cur.input_light, v["name"])})
    for k, v in enumerate(cur.targets):
        _write_view(root / f"test_{k:03d}", v, {l: cur.image("targets", l, v["name"]) for l in cur.target_lights})
    probes = out / "light_probes"
    probes.mkdir(parents=True, exist_ok=True)
    for light in dict.fromkeys([cur.input_light, *cur.target_lights]):
        io.write_hdr(probes / f"{light}.hdr", cur.envmap(light))
    return root
