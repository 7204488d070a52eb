"""``frng export-asset ASSET --env MAP [--rotation DEG] [--exposure EV] --format ply|spz|glb --out FILE``: a
relightable asset (:mod:`frng.apps.asset`, a folder or a relightable GLB) relit under one environment light and
baked into plain 3D Gaussian splatting, the representation every splat tool opens.

The bake (:func:`bake`): each Gaussian's outgoing radiance is the asset's own decoder shading it under the map
(:func:`gaussian_radiance`: the sequence of :func:`frng.render.decoder.shade_decoder`, with the Gaussian's own
features in place of a pixel's blended ones, so the Monte-Carlo residual, the closed-form Lambertian base and the
specular base are those ``frng render-asset`` adds up; the screen-space steps, normal smoothing and the coverage
head, have no per-Gaussian counterpart and are left out), at :data:`FIT_DIRECTIONS` view directions on the sphere.
That radiance times 2^exposure, clipped to [0, 1] and sRGB-encoded (the display-referred colour 3DGS viewers
blend) is fitted per Gaussian as degree-3 real SH by least squares (:func:`frng.render.sh_fit.fit_sh`) and scored
on :data:`HELDOUT_DIRECTIONS` other directions: :attr:`Baked.fit_psnr_db` (opacity-weighted PSNR of the SH colour,
clamped as viewers clamp it, against the decoder's).

Formats and their conventions (each tested in tests/test_export.py):

``ply``   the reference 3DGS PLY (the INRIA code's ``save_ply``), written with plyfile: ``x y z nx ny nz f_dc_0..2
          f_rest_0..44 opacity scale_0..2 rot_0..3``, float32, binary little endian; f_rest channel-major
          (``f_rest_{c * 15 + k - 1}`` = channel c of SH coefficient k >= 1); opacity = logit, scale = log of the
          standard deviations, rot = unit quaternion (w, x, y, z). Axes: the asset's world as it is (right-handed,
          Z up, object in the unit sphere): 3DGS PLYs carry no axis convention; the SH are fitted in these axes.
``spz``   Niantic's SPZ, version 3 (gzip; 24-bit fixed-point positions with 12 fractional bits, uint8 alpha =
          opacity, colour = f_dc 0.15 + 0.5, scale = (log scale + 10) 16, smallest-three 10-bit quaternions, SH as
          128 + 128 coefficient, RGB interleaved per coefficient). Axes: SPZ's own, RUB (x right, y up, z back =
          the glTF axes): ``(x, y, z)_spz = (x, z, -y)_asset``; SH fitted in those axes. Hand-written
          (:func:`write_spz`): the SPZ packages on PyPI are a Rust sdist (``spz``, needs a Rust toolchain), a
          Cython/CMake sdist (``alspz``) and ``gsply`` (needs numba and numpy >= 2; this project pins numpy 1.26
          for bpy); tests/test_export_browser.py renders it in Spark, whose SPZ decoder reads RUB as three.js axes.
``glb``   glTF 2.0 binary, written with pygltflib: one POINTS primitive with KHR_gaussian_splatting (kernel
          ellipse, colorSpace srgb_rec709_display; POSITION, ROTATION (x, y, z, w), SCALE linear, OPACITY linear,
          SH_DEGREE_l_COEF_n, COLOR_0 fallback = the linear DC colour + opacity), glTF axes (Y up, +Z front):
          ``(x, y, z)_gltf = (x, z, -y)_asset``; plus the vendor extension FRNG_relightable_gaussians (the
          features and the decoder, docs/asset-gltf-extension.md) so ``frng render-asset`` / ``frng view`` relight
          the file itself (:mod:`frng.apps.gltf_asset`).

Colour: every format holds display-referred sRGB (BT.709) colour of the chosen light and exposure, as 3DGS does.
Bad input is one line naming the file and field (:class:`ExportError`, :class:`~frng.apps.asset.AssetError`,
:class:`~frng.apps.capture.CaptureError`); an existing ``--out`` file is refused unless ``--force``; the file is
written atomically.
"""

from __future__ import annotations

import argparse
import gzip
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from frng.apps.splat_axes import Y_UP, Y_UP_QUAT, quat_multiply
from frng.render.sh import num_coeffs
from frng.render.sh_fit import SH_DEGREE, eval_sh_dirs, fibonacci_sphere, fit_sh, held_out_directions

FORMATS = ("ply", "spz", "glb")
FIT_DIRECTIONS = 192  # view directions per Gaussian the SH are fitted to (16 coefficients: 12x over-determined)
HELDOUT_DIRECTIONS = 64  # other directions the fit is scored on
MAX_SPP = 4096  # as frng render-asset's
MAX_EXPOSURE_EV = 20.0
SPZ_VERSION = 3
SPZ_MAGIC = 0x5053474E  # "NGSP"
SPZ_FRACTIONAL_BITS = 12
SPZ_COLOR_SCALE = 0.15


class ExportError(ValueError):
    """Bad input to ``frng export-asset`` (an option, the output path); the message names the option or file."""


# -- the bake -----------------------------------------------------------------------------------------------------


@dataclass
class Baked:
    """An asset baked under one light, in the asset's frame: means (N, 3), quats (N, 4) (w, x, y, z), scales (N, 3)
    (standard deviations), opacities (N,), float64; ``fit_dirs`` (D, 3) the directions the colour was sampled at
    and ``fit_values`` (N, D, 3) the display colour there (3DGS view directions, camera -> Gaussian); the fit's
    held-out score; ``light``: what it was baked under (map, rotation, exposure, samples, seed)."""

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    fit_dirs: torch.Tensor
    fit_values: torch.Tensor
    fit_psnr_db: float
    light: dict = field(default_factory=dict)

    def __post_init__(self):
        n = self.means.shape[0]
        assert self.means.shape == (n, 3) and self.quats.shape == (n, 4) and self.scales.shape == (n, 3)
        assert self.opacities.shape == (n,) and self.fit_values.shape == (n, self.fit_dirs.shape[0], 3)

    def __len__(self) -> int:
        return self.means.shape[0]

    def sh(self, frame: np.ndarray | None = None) -> np.ndarray:
        """Degree-3 SH coefficients (N, 16, 3) of the display colour minus 0.5 (the 3DGS convention: colour =
        sum_k c_k Y_k(d) + 0.5) with directions expressed in ``frame`` (3, 3) (asset -> output axes; None: the
        asset's). Fitting in the output's axes is exact for a rotation: no SH rotation needed."""
        dirs = self.fit_dirs if frame is None else self.fit_dirs @ torch.from_numpy(frame).T.to(self.fit_dirs)
        return fit_sh(self.fit_values - 0.5, dirs, SH_DEGREE).numpy()

    def in_frame(self, frame: np.ndarray, frame_quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(means (N, 3), quats (N, 4) (w, x, y, z)) rotated into ``frame`` ((3, 3), its quaternion (w, x, y, z))."""
        return self.means @ frame.T, quat_multiply(frame_quat[None], self.quats)


def gaussian_radiance(renderer, env: np.ndarray, wo: torch.Tensor, spp: int, seed: int = 0) -> torch.Tensor:
    """Outgoing linear radiance (N, D, 3) of every Gaussian of an :class:`~frng.apps.asset.AssetRenderer` towards
    directions wo (D, 3) (unit, Gaussian -> viewer) under an equirect map env (He, We, 3): what
    :func:`frng.render.decoder.shade_decoder` computes for a pixel whose blended features are one Gaussian's, with
    ``spp`` light samples seeded as ``frng render-asset --seed``."""
    from frng.render import envmap
    from frng.render.prefilter import prefilter, specular_base, specular_split
    from frng.render.shading import sh_diffuse, shade_pixels

    dec, sc = renderer.decoder, renderer.shading
    feats = renderer.gaussians.features.float()
    n, c = feats.shape
    d = wo.shape[0]
    assert wo.shape == (d, 3), wo.shape
    dev = feats.device
    env_t = torch.as_tensor(env).float()
    seed = envmap.sample_seed(torch.Generator().manual_seed(int(seed)))
    samples = envmap.sample(envmap.importance_sampler(env_t.to(dev)), int(spp), sc.sampling, seed)
    closed_form = dec.cosine and sc.diffuse == "sh"
    reflectance, prefiltered = dec, False
    if closed_form:
        reflectance, prefiltered = specular_split(dec.residual, sc, renderer.specular)
    f = feats[:, None, :].expand(n, d, c).reshape(-1, c)
    w = wo.to(dev).float()[None].expand(n, d, 3).reshape(-1, 3)
    with torch.no_grad():
        rgb = shade_pixels(reflectance, [f], w, samples, None, sc.chunk_pixels, sc.chunk_pairs).float()
        rgb = rgb.reshape(n, d, 3)
        if closed_form:  # the Lambertian base does not depend on the view: once per Gaussian
            sh = envmap.sh_project(env_t.cpu()).float()
            ones = torch.ones(1, 1, n, 1, device=dev)
            base = sh_diffuse(feats[None, None, :, 3:6], feats[None, None, :, :3], ones, sh, sc.alpha_eps)
            rgb = rgb + base.reshape(n, 1, 3)
            if prefiltered:
                spec = specular_base(
                    f[None, None], torch.ones(1, 1, n * d, 1, device=dev), prefilter(env_t).to(dev), -w[None, None],
                    sc.alpha_eps, sc.specular_param,
                )  # fmt: skip
                rgb = rgb + spec.reshape(n, d, 3)
            if dec.attenuation:
                rgb = rgb.clamp_min(0.0)
    assert rgb.shape == (n, d, 3), rgb.shape
    return rgb.cpu()


def display_colour(radiance: torch.Tensor, exposure_ev: float) -> torch.Tensor:
    """Linear radiance (...) -> the display colour a 3DGS viewer blends: 2^EV x radiance, clipped to [0, 1],
    sRGB-encoded (IEC 61966-2-1)."""
    x = (radiance.double() * 2.0 ** float(exposure_ev)).clamp(0.0, 1.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(1e-12) ** (1 / 2.4) - 0.055)


def bake(
    renderer,
    env: np.ndarray,
    exposure_ev: float = 0.0,
    spp: int | None = None,
    seed: int = 0,
    fit_directions: int = FIT_DIRECTIONS,
    heldout_directions: int = HELDOUT_DIRECTIONS,
    light: dict | None = None,
) -> Baked:
    """Bake an :class:`~frng.apps.asset.AssetRenderer`'s asset under env (He, We, 3) (already rotated) at
    ``exposure_ev``: the display colour at ``fit_directions`` view directions per Gaussian, and the degree-3 SH
    fit's opacity-weighted PSNR over ``heldout_directions`` others (module docstring)."""
    g = renderer.gaussians
    spp = int(spp or renderer.shading.spp_infer)
    fit_dirs, held = fibonacci_sphere(fit_directions), held_out_directions(heldout_directions)
    # 3DGS evaluates SH at d = (Gaussian - camera) / |...|; the decoder's w_o points the other way
    both = display_colour(
        gaussian_radiance(renderer, env, -torch.cat([fit_dirs, held]).float(), spp, seed), exposure_ev
    )
    fit_values, held_values = both[:, :fit_directions], both[:, fit_directions:]
    coeffs = fit_sh(fit_values - 0.5, fit_dirs, SH_DEGREE)
    pred = (eval_sh_dirs(coeffs, held) + 0.5).clamp(0.0, 1.0)
    w = g.opacities.double().reshape(-1, 1, 1).cpu()
    mse = float(((pred - held_values) ** 2 * w).sum() / (w.sum() * held.shape[0] * 3).clamp_min(1e-12))
    score = math.inf if mse == 0.0 else -10.0 * math.log10(mse)
    as64 = lambda t: t.detach().cpu().double().numpy()  # noqa: E731
    return Baked(
        as64(g.means),
        as64(g.quats),
        as64(g.scales),
        as64(g.opacities).reshape(-1),
        fit_dirs,
        fit_values,
        score,
        {**(light or {}), "exposure_ev": float(exposure_ev), "spp": spp, "seed": int(seed)},
    )


# -- the reference 3DGS PLY ---------------------------------------------------------------------------------------


def ply_property_names(degree: int = SH_DEGREE) -> list[str]:
    """The reference 3DGS PLY's properties in order (the INRIA code's ``construct_list_of_attributes``)."""
    rest = 3 * (num_coeffs(degree) - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def ply_fields(baked: Baked) -> dict[str, np.ndarray]:
    """The reference 3DGS PLY's fields (name -> (N,) float32, :func:`ply_property_names` order) of a bake, in the
    asset's axes."""
    sh = baked.sh()  # (N, 16, 3)
    n, k = sh.shape[:2]
    op = np.clip(baked.opacities, 1e-7, 1.0 - 1e-7)
    cols = {"x": baked.means[:, 0], "y": baked.means[:, 1], "z": baked.means[:, 2]}
    cols.update({k_: np.zeros(n) for k_ in ("nx", "ny", "nz")})
    cols.update({f"f_dc_{c}": sh[:, 0, c] for c in range(3)})
    cols.update({f"f_rest_{c * (k - 1) + j}": sh[:, 1 + j, c] for c in range(3) for j in range(k - 1)})
    cols["opacity"] = np.log(op) - np.log1p(-op)
    cols.update({f"scale_{i}": np.log(baked.scales[:, i]) for i in range(3)})
    cols.update({f"rot_{i}": baked.quats[:, i] for i in range(4)})
    out = {name: np.ascontiguousarray(cols[name], dtype=np.float32) for name in ply_property_names(SH_DEGREE)}
    assert all(v.shape == (n,) for v in out.values())
    return out


def write_ply(path: str | os.PathLike, baked: Baked) -> None:
    """The reference 3DGS PLY of a bake (plyfile, binary little endian), written atomically."""
    from plyfile import PlyData, PlyElement

    from frng.io import atomic_path

    fields = ply_fields(baked)
    table = np.empty(len(baked), dtype=[(k, "<f4") for k in fields])
    for k, v in fields.items():
        table[k] = v
    light = baked.light
    comments = [
        "frng export-asset: 3DGS reference layout, SH degree 3, display-referred sRGB",
        f"light {Path(str(light.get('map', '?'))).name} rotation {light.get('rotation_deg', 0.0):g} deg "
        f"exposure {light.get('exposure_ev', 0.0):g} EV; axes: asset world (right-handed, Z up)",
    ]
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(table, "vertex")], text=False, byte_order="<", comments=comments).write(str(tmp))


# -- SPZ ----------------------------------------------------------------------------------------------------------


def spz_bytes(baked: Baked) -> bytes:
    """SPZ version 3 (uncompressed payload, then gzip) of a bake in SPZ's RUB axes (module docstring)."""
    means, quats = baked.in_frame(Y_UP, Y_UP_QUAT)
    sh = baked.sh(Y_UP)  # (N, 16, 3)
    n = len(baked)
    header = np.array([SPZ_MAGIC, SPZ_VERSION, n], "<u4").tobytes()
    header += bytes([SH_DEGREE, SPZ_FRACTIONAL_BITS, 0, 0])
    fixed = np.round(means * (1 << SPZ_FRACTIONAL_BITS)).astype(np.int64)
    if np.abs(fixed).max(initial=0) >= 1 << 23:
        raise ExportError(f"SPZ: a position beyond +-{(1 << 23) / (1 << SPZ_FRACTIONAL_BITS):g} (24-bit fixed point)")
    pos = (fixed & 0xFFFFFF).astype("<u4").view(np.uint8).reshape(n, 3, 4)[:, :, :3].reshape(-1)
    u8 = lambda a: np.clip(np.round(a), 0, 255).astype(np.uint8).reshape(-1)  # noqa: E731
    alpha = u8(baked.opacities * 255.0)
    colour = u8((sh[:, 0, :] * SPZ_COLOR_SCALE + 0.5) * 255.0)
    scale = u8((np.log(baked.scales) + 10.0) * 16.0)
    rot = _smallest_three(quats).astype("<u4").view(np.uint8)
    rest = u8(sh[:, 1:, :] * 128.0 + 128.0)  # (N, 15, 3): coefficient-major, RGB interleaved
    return (
        header + pos.tobytes() + alpha.tobytes() + colour.tobytes() + scale.tobytes() + rot.tobytes() + rest.tobytes()
    )


def _smallest_three(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) (w, x, y, z) -> SPZ v3's packed uint32 (N,): the index of the largest |component| of
    (x, y, z, w) in bits 30-31, the other three (in order, first in the highest bits) as 9-bit magnitude / sqrt(1/2)
    plus a sign bit, the largest made positive."""
    xyzw = np.concatenate([q[:, 1:], q[:, :1]], 1)
    xyzw = xyzw / np.linalg.norm(xyzw, axis=1, keepdims=True)
    largest = np.argmax(np.abs(xyzw), 1)
    xyzw = np.where(np.take_along_axis(xyzw, largest[:, None], 1) < 0, -xyzw, xyzw)
    packed = np.zeros(len(q), np.uint64)
    for i in range(4):
        keep = largest != i
        v = xyzw[:, i]
        mag = np.clip(np.round(np.abs(v) / math.sqrt(0.5) * 511.0), 0, 511).astype(np.uint64)
        comp = (np.uint64(512) * (v < 0).astype(np.uint64)) | mag
        packed = np.where(keep, (packed << np.uint64(10)) | comp, packed)
    return (packed | (largest.astype(np.uint64) << np.uint64(30))).astype(np.uint32)


def write_spz(path: str | os.PathLike, baked: Baked) -> None:
    """The SPZ file of a bake (gzip of :func:`spz_bytes`), written atomically."""
    from frng.io import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(gzip.compress(spz_bytes(baked), compresslevel=9, mtime=0))


# -- the command --------------------------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``frng export-asset`` (its stage, and the viewer's Export button)."""
    parser.add_argument(
        "asset", help="asset folder (asset.json, gaussians.ply, decoder.safetensors) or relightable GLB"
    )
    parser.add_argument("--env", required=True, help="equirect environment map to bake (EXR/HDR, 2:1)")
    parser.add_argument("--rotation", type=float, default=0.0, help="map rotation about world Z, degrees")
    parser.add_argument("--exposure", type=float, default=0.0, help="exposure, EV (radiance x 2^EV)")
    parser.add_argument("--format", help="ply, spz or glb (default: --out's suffix)")
    parser.add_argument("--out", required=True, help="output file")
    parser.add_argument("--spp", type=int, help="light samples (default: the asset's shading.spp_infer)")
    parser.add_argument("--seed", type=int, default=0, help="light-sample seed (as frng render-asset's)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or auto")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")


def check_format(fmt: str | None, out: str | os.PathLike) -> str:
    """The format to write: ``fmt`` (one of :data:`FORMATS`), else ``out``'s suffix; an :class:`ExportError`
    naming the option otherwise."""
    suffix = Path(out).suffix.lower().lstrip(".")
    if fmt is None:
        if suffix not in FORMATS:
            raise ExportError(f"{out}: --format not given and the suffix is not one of {', '.join(FORMATS)}")
        return suffix
    if fmt.lower() not in FORMATS:
        raise ExportError(f"--format {fmt}: unknown format; choose one of {', '.join(FORMATS)}")
    return fmt.lower()


def export(args: argparse.Namespace) -> dict:
    """Run ``frng export-asset``: check every input (one line each), bake, write. Returns a summary."""
    from frng.apps.capture import read_light
    from frng.apps.gltf_asset import open_renderer
    from frng.device import resolve_device
    from frng.render import envmap

    fmt = check_format(args.format, args.out)
    out = Path(args.out)
    if out.is_dir():
        raise ExportError(f"{out}: --out is a folder; give a file name (.{fmt})")
    if (out.exists() or out.is_symlink()) and not args.force:
        raise ExportError(f"{out}: --out exists; nothing was written (pass --force to replace it)")
    for flag, v, top in (("--rotation", args.rotation, 1e6), ("--exposure", args.exposure, MAX_EXPOSURE_EV)):
        if not (math.isfinite(v) and abs(v) <= top):
            raise ExportError(f"{flag} {v}: must be a finite number within +-{top:g}")
    if args.spp is not None and not 1 <= args.spp <= MAX_SPP:
        raise ExportError(f"--spp {args.spp}: must be 1..{MAX_SPP}")
    env = read_light(args.env)  # 2:1, finite, bounded: or one line naming the file
    try:
        device = resolve_device(args.device)
    except RuntimeError as e:
        raise ExportError(f"--device {args.device}: {e}") from None
    r = open_renderer(args.asset, device)
    env = env if args.rotation % 360.0 == 0.0 else envmap.rotate_z(env, args.rotation)
    light = {"map": str(args.env), "rotation_deg": float(args.rotation)}
    baked = bake(r, env, args.exposure, args.spp, args.seed, light=light)
    if fmt == "ply":
        write_ply(out, baked)
    elif fmt == "spz":
        write_spz(out, baked)
    else:
        from frng.apps.gltf_asset import write_glb

        write_glb(out, baked, r)
    return {"format": fmt, "gaussians": len(baked), "fit_psnr_db": baked.fit_psnr_db, "out": str(out)}


__all__ = [
    "FORMATS",
    "Baked",
    "ExportError",
    "add_arguments",
    "bake",
    "check_format",
    "display_colour",
    "export",
    "gaussian_radiance",
    "ply_fields",
    "ply_property_names",
    "spz_bytes",
    "write_ply",
    "write_spz",
]
