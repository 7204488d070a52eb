"""Equirectangular environment maps: the direction <-> uv convention, I/O, rotation.

Convention (matches Blender's Environment Texture node with default mapping, world Z up; verified by
``tests/test_envmap_blender.py`` with a Cycles mirror sphere):

- ``u`` runs left -> right and ``v`` top -> bottom over [0, 1); pixel (col, row) has its centre at
  ``u = (col + 0.5) / W``, ``v = (row + 0.5) / H``.
- ``phi = pi * (1 - 2u)`` (azimuth from +X towards +Y), ``theta = pi * (0.5 - v)`` (elevation),
  ``direction = (cos(theta) cos(phi), cos(theta) sin(phi), sin(theta))``.
- Inverse: ``u = 0.5 - atan2(y, x) / (2 pi)  (mod 1)``, ``v = acos(z) / pi``.
- The image centre looks along +X, ``u = 0.25`` along +Y, the top row is +Z.

Maps are linear HDR float32 RGB with ``width == 2 * height``. ``E(direction)`` is the radiance arriving
*from* that direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from frng import io
from frng.lazytorch import torch


class EnvMapError(ValueError):
    """An environment map is missing, unreadable or not a 2:1 equirect RGB image; names the file."""


MAX_RADIANCE = 1e7  # a map with a larger value is refused (read): its light sums overflow float32 in rendering
MAX_PIXELS = 8192 * 16384  # a map with more pixels is refused before it is decoded (1.6 GB as float32 RGB)


def uv_to_dir(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Equirect (u, v) in [0, 1) -> unit world direction (..., 3)."""
    phi = math.pi * (1.0 - 2.0 * u)
    theta = math.pi * (0.5 - v)
    ct = torch.cos(theta)
    return torch.stack([ct * torch.cos(phi), ct * torch.sin(phi), torch.sin(theta)], dim=-1)


def dir_to_uv(d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit world direction (..., 3) -> equirect (u, v), each (...), u in [0, 1), v in [0, 1]."""
    u = torch.remainder(0.5 - torch.atan2(d[..., 1], d[..., 0]) / (2.0 * math.pi), 1.0)
    v = torch.acos(d[..., 2].clamp(-1.0, 1.0)) / math.pi
    return u, v


def pixel_uv(height: int, width: int, device=None, dtype=None) -> tuple[torch.Tensor, torch.Tensor]:
    """(u, v) of every pixel centre, each (H, W); dtype default float32."""
    dtype = torch.float32 if dtype is None else dtype
    v = (torch.arange(height, device=device, dtype=dtype) + 0.5) / height
    u = (torch.arange(width, device=device, dtype=dtype) + 0.5) / width
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return uu, vv


def pixel_directions(height: int, width: int, device=None, dtype=None) -> torch.Tensor:
    """Unit direction of every pixel centre (H, W, 3); dtype default float32."""
    return uv_to_dir(*pixel_uv(height, width, device, dtype))


def pixel_solid_angles(height: int, width: int, device=None, dtype=None) -> torch.Tensor:
    """Exact solid angle of each pixel (H, W); sums to 4 pi; dtype default float64."""
    dtype = torch.float64 if dtype is None else dtype
    edges = torch.linspace(0.0, math.pi, height + 1, device=device, dtype=dtype)  # polar angle edges
    band = (torch.cos(edges[:-1]) - torch.cos(edges[1:])) * (2.0 * math.pi / width)
    return band[:, None].expand(height, width)


def check_shape(image: np.ndarray, name: str = "environment map") -> None:
    if image.ndim != 3 or image.shape[-1] < 3:
        raise EnvMapError(f"{name}: expected an (H, W, 3) RGB image, got shape {image.shape}")
    h, w = image.shape[:2]
    if w != 2 * h:
        raise EnvMapError(f"{name}: equirect maps must be 2:1 (width = 2 x height), got {w}x{h}")


def read(path: str | Path) -> np.ndarray:
    """Read an equirect map (EXR, or Radiance HDR) as linear float32 (H, W, 3), negatives clamped to 0.

    Refused with one line naming the file: a missing, truncated or mislabelled file, a map of more than
    :data:`MAX_PIXELS` pixels (checked from the header, before decoding), a non-2:1 map, NaN/inf, a value above
    :data:`MAX_RADIANCE`, or a map with negative values and no positive one (clamped, it would light nothing)."""
    from frng import confine

    path = Path(path)
    if not path.exists():
        raise EnvMapError(f"{path}: environment map does not exist")
    try:
        if path.suffix.lower() not in (".exr", ".hdr"):
            raise EnvMapError(f"{path}: unsupported environment map format (use .exr or .hdr)")
        confine.check_image_size(path, MAX_PIXELS)
        if path.suffix.lower() == ".exr":
            img = io.read_exr(path, ["R", "G", "B"])
        else:
            try:
                img = io.read_hdr(path)
            except Exception as e:  # noqa: BLE001 -- a truncated .hdr: SyntaxError, ValueError, OSError ...
                first = str(e).strip().splitlines()[0] if str(e).strip() else ""
                raise EnvMapError(
                    f"{path}: cannot read Radiance HDR: truncated or corrupt ({type(e).__name__}: {first[:200]})"
                ) from None
    except (io.ImageError, confine.UntrustedInputError) as e:
        raise EnvMapError(str(e)) from e
    check_shape(img, str(path))
    if not np.all(np.isfinite(img)):
        raise EnvMapError(f"{path}: environment map contains NaN or Inf")
    if img.size and float(img.max()) > MAX_RADIANCE:
        raise EnvMapError(
            f"{path}: environment map has a value of {float(img.max()):.3g}, above the limit "
            f"{MAX_RADIANCE:g} (frng.render.envmap.MAX_RADIANCE; scale the map down)"
        )
    if img.size and float(img.min()) < 0.0 and float(img.max()) <= 0.0:  # clamped, it would light nothing
        raise EnvMapError(
            f"{path}: environment map has only negative or zero values (down to {float(img.min()):.3g}); radiance is "
            f">= 0 (a sign-flipped map?)"
        )
    return np.maximum(img, 0.0).astype(np.float32)


def write(path: str | Path, image: np.ndarray) -> None:
    """Write a linear float32 equirect map as EXR (atomically)."""
    check_shape(image, str(path))
    io.write_exr(path, np.asarray(image, dtype=np.float32)[..., :3])


def rotate_z(image: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rotate a map about world Z by ``angle_deg`` (counter-clockwise seen from +Z).

    The rotated map satisfies ``E'(R d) = E(d)``: light from azimuth phi now arrives from phi + angle.
    With ``u = (1 - phi / pi) / 2`` this is a periodic shift of u by ``-angle / 360`` (linear interpolation).
    """
    h, w = image.shape[:2]
    shift = -angle_deg / 360.0 * w  # in pixels, sub-pixel allowed
    # E'(col) = E(col - shift): sample the source at col - shift
    src = (np.arange(w) - shift) % w
    i0 = np.floor(src).astype(int)
    t = (src - i0)[None, :, None].astype(np.float32)
    i1 = (i0 + 1) % w
    return ((1.0 - t) * image[:, i0] + t * image[:, i1]).astype(np.float32)


def resize(image: np.ndarray, width: int) -> np.ndarray:
    """Area-preserving resize of an equirect map to ``width`` x ``width/2`` (scikit-image, anti-aliased)."""
    from skimage.transform import resize as sk_resize

    out = sk_resize(image, (width // 2, width, image.shape[-1]), order=1, anti_aliasing=True, preserve_range=True)
    return np.maximum(out, 0.0).astype(np.float32)


def luminance(rgb: np.ndarray | torch.Tensor):
    """Rec. 709 luminance of linear RGB (..., 3)."""
    w = (0.2126, 0.7152, 0.0722)
    return rgb[..., 0] * w[0] + rgb[..., 1] * w[1] + rgb[..., 2] * w[2]


# -- importance sampling and SH projection (rendering core; see frng/render/shading.py) ------------------------
#
# The map is piecewise constant over its pixels. The sampler picks pixel (row, col) with probability
# P = w / sum(w), w = luminance x solid angle (luminance x sin(theta) up to the exact band integral), through a
# marginal CDF over rows and a conditional CDF over columns, then a point uniform in solid angle inside the
# pixel (uniform in azimuth and in cos(polar angle)). The pdf in solid-angle measure is therefore P / Omega_pixel,
# proportional to luminance: for a grey map L / pdf is the same for every sample (zero-variance integral).


class EnvSamples(NamedTuple):
    """A fixed set of K light samples shared by all pixels of an image."""

    dirs: torch.Tensor  # (K, 3) unit world directions the light arrives from
    pdf: torch.Tensor  # (K,) solid-angle pdf
    radiance: torch.Tensor  # (K, 3) map value in that direction


@dataclass(frozen=True)
class EnvSampler:
    """Marginal/conditional CDFs of an equirect map (build with :func:`importance_sampler`)."""

    image: torch.Tensor  # (H, W, 3)
    pmf: torch.Tensor  # (H, W) pixel probabilities, sum 1
    row_cdf: torch.Tensor  # (H + 1,)
    col_cdf: torch.Tensor  # (H, W + 1), each row normalised
    solid_angle: torch.Tensor  # (H, W)


def importance_sampler(image, floor: float = 1e-3) -> EnvSampler:
    """Sampler for an (H, W, 3) map (numpy or torch). ``floor`` x mean luminance is added to every pixel's
    luminance so that dark pixels keep a non-zero pdf (estimates stay unbiased for any integrand)."""
    img = torch.as_tensor(np.asarray(image) if not isinstance(image, torch.Tensor) else image)
    img = img[..., :3].to(torch.float64)
    H, W = img.shape[:2]
    omega = pixel_solid_angles(H, W, device=img.device, dtype=torch.float64)
    lum = luminance(img.clamp(min=0.0))
    mean = (lum * omega).sum() / (4 * math.pi)
    lum = lum + (floor * mean if mean > 0 else 1.0)
    w = lum * omega
    pmf = w / w.sum()
    p_row = pmf.sum(1)
    row_cdf = torch.cat([p_row.new_zeros(1), torch.cumsum(p_row, 0)])
    row_cdf = row_cdf / row_cdf[-1]
    col_cdf = torch.cat([pmf.new_zeros(H, 1), torch.cumsum(pmf, 1)], 1)
    col_cdf = col_cdf / col_cdf[:, -1:]
    return EnvSampler(image=img, pmf=pmf, row_cdf=row_cdf, col_cdf=col_cdf, solid_angle=omega)


def unit_square_samples(n: int, method: str = "sobol", seed: int = 0, device=None) -> torch.Tensor:
    """(n, 2) points in [0, 1)^2: ``random`` (iid), ``stratified`` (Latin hypercube: each axis split in n
    strata, one jittered point per stratum) or ``sobol`` (scrambled Sobol' low-discrepancy)."""
    g = torch.Generator().manual_seed(seed)
    if method == "random":
        u = torch.rand(n, 2, generator=g, dtype=torch.float64)
    elif method == "stratified":
        strata = torch.stack([torch.randperm(n, generator=g) for _ in range(2)], 1).to(torch.float64)
        u = (strata + torch.rand(n, 2, generator=g, dtype=torch.float64)) / n
    elif method == "sobol":
        u = torch.quasirandom.SobolEngine(2, scramble=True, seed=seed).draw(n, dtype=torch.float64)
    else:
        raise ValueError(f"unknown sampling method {method!r} (random, stratified, sobol)")
    return u.clamp(0.0, 1.0 - 1e-12).to(device)


def sample_seed(generator: torch.Generator | None) -> int:
    """The seed of one image's light-sample set (:func:`sample`) drawn from ``generator`` (0 without one), on the
    generator's own device (a CUDA generator cannot draw on the CPU)."""
    if generator is None:
        return 0
    return int(torch.randint(0, 2**31 - 1, (1,), generator=generator, device=generator.device))


def sample(sampler: EnvSampler, n: int, method: str = "sobol", seed: int = 0) -> EnvSamples:
    """Draw n light directions by importance (one fixed set for a whole image). Float64 on the map's device."""
    H, W = sampler.pmf.shape
    u = unit_square_samples(n, method, seed, device=sampler.pmf.device)
    row = (torch.searchsorted(sampler.row_cdf, u[:, 0].contiguous(), right=True) - 1).clamp(0, H - 1)
    r0, r1 = sampler.row_cdf[row], sampler.row_cdf[row + 1]
    t_row = ((u[:, 0] - r0) / (r1 - r0).clamp(min=1e-300)).clamp(0.0, 1.0)
    cdf = sampler.col_cdf[row]  # (n, W + 1)
    col = (torch.searchsorted(cdf, u[:, 1:2].contiguous(), right=True).squeeze(1) - 1).clamp(0, W - 1)
    c0, c1 = cdf.gather(1, col[:, None])[:, 0], cdf.gather(1, col[:, None] + 1)[:, 0]
    t_col = ((u[:, 1] - c0) / (c1 - c0).clamp(min=1e-300)).clamp(0.0, 1.0)
    # uniform in solid angle inside the pixel: azimuth linear in u, cos(polar) linear across the band
    uu = (col + t_col) / W
    cos0, cos1 = torch.cos(math.pi * row / H), torch.cos(math.pi * (row + 1) / H)
    z = cos0 + t_row * (cos1 - cos0)
    s = torch.sqrt((1 - z * z).clamp(min=0.0))
    phi = math.pi * (1.0 - 2.0 * uu)
    dirs = torch.stack([s * torch.cos(phi), s * torch.sin(phi), z], -1)
    pdf = sampler.pmf[row, col] / sampler.solid_angle[row, col]
    return EnvSamples(dirs=dirs, pdf=pdf, radiance=sampler.image[row, col])


def _pixel_of(dirs: torch.Tensor, H: int, W: int) -> tuple[torch.Tensor, torch.Tensor]:
    u, v = dir_to_uv(dirs)
    return (v * H).long().clamp(0, H - 1), (u * W).long().clamp(0, W - 1)


def pdf(sampler: EnvSampler, dirs: torch.Tensor) -> torch.Tensor:
    """Solid-angle pdf (...) of :func:`sample` at unit directions (..., 3)."""
    row, col = _pixel_of(dirs.to(sampler.pmf.dtype), *sampler.pmf.shape)
    return sampler.pmf[row, col] / sampler.solid_angle[row, col]


def lookup(image: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Radiance (..., 3) of an (H, W, 3) map arriving from unit directions (..., 3) (nearest pixel: the map is
    treated as piecewise constant, consistently with the sampler)."""
    row, col = _pixel_of(dirs, image.shape[0], image.shape[1])
    return image[row, col]


# Ramamoorthi & Hanrahan (2001): clamped-cosine convolution weights per band (l = 0, 1, 2)
SH_IRRADIANCE_BANDS = (math.pi, 2.0 * math.pi / 3.0, math.pi / 4.0)


def sh_project(image, degree: int = 2) -> torch.Tensor:
    """Project an (H, W, 3) map onto real SH (``frng.render.sh`` basis): coefficients ((degree + 1)^2, 3),
    c_lm = sum over pixels of L Y_lm Omega (exact pixel solid angles)."""
    from frng.render.sh import sh_basis

    img = torch.as_tensor(np.asarray(image) if not isinstance(image, torch.Tensor) else image)[..., :3].double()
    H, W = img.shape[:2]
    d = pixel_directions(H, W, device=img.device, dtype=torch.float64)
    omega = pixel_solid_angles(H, W, device=img.device, dtype=torch.float64)
    Y = sh_basis(degree, d)  # (H, W, K)
    return torch.einsum("hwk,hwc->kc", Y * omega[..., None], img)


def sh_irradiance(coeffs: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Irradiance E(n) = int L(w) max(0, n.w) dw (..., 3) from degree-2 SH coefficients (9, 3) of L, at unit
    normals (..., 3). Exact for maps band-limited to l <= 2; a Lambertian surface of albedo a reflects a E / pi."""
    from frng.render.sh import sh_basis

    Y = sh_basis(2, normals.to(coeffs.dtype))
    band = coeffs.new_tensor([SH_IRRADIANCE_BANDS[0]] + [SH_IRRADIANCE_BANDS[1]] * 3 + [SH_IRRADIANCE_BANDS[2]] * 5)
    with torch.autocast(device_type=normals.device.type, enabled=False):  # in the coefficients' precision
        return (Y * band) @ coeffs[:9]


def reference_light(height: int = 16, device=None) -> torch.Tensor:
    """The reference light E_0 (H, 2H, 3) the backbone is conditioned on for F-RNG's appearance tokens T_app, the same
    map for every object at training and at test time: a CIE standard overcast sky, radiance proportional to
    (1 + 2 cos theta) / 3 above the horizon (theta from the zenith, +Z), the ground a uniform 0.3 of the zenith's,
    scaled to mean radiance 1.

    Paper Sec. 4.2.2 feeds RelitLRM "an extra random environment light E_1" beside the one T_app comes from and does
    not say which that is; its task gives no input light (the photos' light is unknown), so E_0 cannot be the input
    views' map. A fixed soft sky is in the training pool's family (skies, soft studios) and shows every side of the
    object; L_ind makes T_mat indifferent to it."""
    d = pixel_directions(height, 2 * height, device=device, dtype=torch.float64)
    up = (1.0 + 2.0 * d[..., 2].clamp_min(0.0)) / 3.0
    rad = torch.where(d[..., 2] > 0, up, torch.full_like(up, 0.3))
    w = pixel_solid_angles(height, 2 * height, device=device, dtype=torch.float64)
    rad = rad / ((rad * w).sum() / w.sum())
    return rad[..., None].expand(height, 2 * height, 3).float().contiguous()
