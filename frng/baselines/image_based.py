"""The image-based relighting baseline ``idm-reshade`` (the paper's Table 3 family; stage ``frng baseline-image``).

The family it stands for: Neural Gaffer (Jin et al. 2024, ``Haian-Jin/Neural_Gaffer``), DiLightNet (Zeng et al.
2024, ``iamNCJ/DiLightNet``), DiffusionRenderer (Liang et al. 2025, ``nv-tlabs/diffusion-renderer``): ONE photograph
of the target view (taken under the input light) plus the target environment map -> the relit photograph, one image
at a time, with no 3D reconstruction. F-RNG instead reconstructs from 6 other views and renders the unseen target
view; these methods are handed the target view itself.

What it does, per target view of the object (``{results}/baselines/views/{obj}/targets/{light}/{view}.exr``, the
object's own target cameras under its first input light, written by the rule ``curate_baselines``):

1. decompose the single image with the project's IDM (:func:`frng.priors.build_idm`, the kind ``idm.kind`` selects:
   ``learned`` loads ``{results}/idm/model.pt``, exactly as ``frng relight`` builds it) run on ONE view (V = 1; the
   learned IDM's visual-hull cues then come from that view's mask alone) -> world-space normal, albedo, roughness,
   metallic. ``gbuffer="oracle"`` (:data:`GBUFFERS`) replaces the IDM by the curated ground-truth G-buffer of the
   target view (``{results}/objects/{obj}/gbuffer/{view}.exr``): the upper bound of this family at this shading
   model, and the check that re-shading under the input light reproduces the photo (tests);
2. re-shade that G-buffer under each of the object's target lights with the project's analytic Cook-Torrance GGX
   shading (:func:`frng.render.shading.ggx_shade`, the shading of F-RNG's "w/o neural appearance" ablation):
   the diffuse lobe in closed form from the map's degree-2 SH irradiance, the GGX specular lobe by Monte Carlo with
   ``shading.spp_infer`` importance samples of the map (``shading.sampling``), normals faced to the camera, parameters
   clamped to the ablation's ranges. Not the prefiltered split-sum of :mod:`frng.render.prefilter` (that is the
   neural decoder's specular base, parameterised by decoder features, not by a roughness);
3. write the photo's alpha as the mask: RGBA linear premultiplied ``{light}/{view}.exr`` per target light, and
   ``run.json`` with the timings (:func:`reshade_object`).

What it does not reproduce: the generative part of those methods. A diffusion model hallucinates plausible
cast shadows, inter-reflections and view-dependent detail the G-buffer cannot carry; this baseline has no
shadowing or occlusion at all (a local shading model on a per-pixel G-buffer), its quality is bounded by a small
IDM trained on this project's few hundred objects (not Stable Diffusion's prior), it works at the dataset's
resolution (Neural Gaffer 256^2, DiLightNet 512^2), and it takes the map in the world frame (Neural Gaffer rotates the
map into the camera frame: :mod:`frng.baselines.export_inputs`). The real methods' outputs can be scored beside it
from files (:mod:`frng.baselines.external`).
"""

from __future__ import annotations

import os
import platform
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from frng import io
from frng.baselines.plan import IMAGE_BASED_RUN, TARGETS_KIND
from frng.plan.layout import Layout, ObjectFolder, RelightFolder
from frng.priors.intrinsics import IntrinsicPriors
from frng.render import envmap
from frng.render.shading import ShadingConfig, ggx_shade

GBUFFERS = ("idm", "oracle")  # where the re-shaded G-buffer comes from (see the module docstring)
SHADING_NOTE = (
    "frng.render.shading.ggx_shade: Cook-Torrance GGX, diffuse lobe in closed form (SH irradiance), specular by "
    "Monte Carlo (shading.spp_infer importance samples)"
)


class ImageBaselineError(ValueError):
    """Bad input to ``frng baseline-image`` (names the file); nothing was written."""


@dataclass(frozen=True)
class ImageJob:
    """What the image-based baseline reads of the config (:meth:`of`): the results folder, the data ``seed`` (light
    sample seeds), the ``device``, the ``shading`` section (spp_infer, sampling, alpha_eps, chunking), the ``idm`` and
    ``backbone`` sections (:func:`frng.priors.build_idm`)."""

    results: str
    seed: int
    device: str
    shading: ShadingConfig
    idm: object
    backbone: object

    @classmethod
    def of(cls, config) -> ImageJob:
        return cls(config.results, int(config.seed), config.device, config.shading, config.idm, config.backbone)


@dataclass
class TargetInputs:
    """The inputs of one object: ``light`` (the input light), ``views`` (target view records), ``images``
    {view: (H, W, 4) linear premultiplied RGBA}, ``lights`` (the object's target lights), ``envs`` {light: (He, We, 3)},
    ``split`` of the object."""

    light: str
    views: list[dict]
    images: dict[str, np.ndarray]
    lights: list[str]
    envs: dict[str, np.ndarray]


def read_inputs(results: str | Path, oid: str) -> TargetInputs:
    """Check and read what the baseline takes of object ``oid``: the baseline views' meta.json (``light``,
    ``views.targets``), each target view's RGBA EXR under that light, the object's meta.json (``target_lights``,
    ``lights``) and each target light's env map. Raises :class:`ImageBaselineError` naming the file."""
    L = Layout(results)
    bmeta_path = Path(L.baseline_views_meta(oid))
    try:
        bmeta = io.read_json(bmeta_path)
        light = str(bmeta["light"])
        views = list(bmeta["views"][TARGETS_KIND])
    except (FileNotFoundError, ValueError) as e:
        raise ImageBaselineError(f"{bmeta_path}: cannot read the baseline views' metadata ({e})") from e
    except (KeyError, TypeError) as e:
        raise ImageBaselineError(f"{bmeta_path}: missing key {e} (need 'light' and 'views.{TARGETS_KIND}')") from e
    if not views:
        raise ImageBaselineError(f"{bmeta_path}: no target views under 'views.{TARGETS_KIND}'")
    meta_path = Path(L.object_meta(oid))
    try:
        meta = io.read_json(meta_path)
        lights = list(meta["target_lights"])
        files = {l: Path(results) / meta["lights"][l]["file"] for l in lights}
    except (FileNotFoundError, ValueError) as e:
        raise ImageBaselineError(f"{meta_path}: cannot read object metadata ({e})") from e
    except (KeyError, TypeError) as e:
        raise ImageBaselineError(f"{meta_path}: missing key {e}") from e
    folder = ObjectFolder(L.baseline_views_dir(oid))
    images = {}
    for v in views:
        path = folder.image(TARGETS_KIND, light, v["name"])
        img = io.read_rgba(path, require_alpha=True)
        if img.shape[:2] != (int(v["height"]), int(v["width"])):
            raise ImageBaselineError(
                f"{path}: {img.shape[1]}x{img.shape[0]}, the camera says {v['width']}x{v['height']}"
            )
        if not np.all(np.isfinite(img)):
            raise ImageBaselineError(f"{path}: contains NaN or inf")
        images[v["name"]] = img
    envs = {}
    for l, f in files.items():
        try:
            envs[l] = envmap.read(f)
        except envmap.EnvMapError as e:
            raise ImageBaselineError(f"environment map: {e}") from e
    return TargetInputs(light, views, images, lights, envs)


def fill_background(passes: dict[str, torch.Tensor], mask: torch.Tensor, steps: int = 2) -> dict[str, torch.Tensor]:
    """Extend per-pixel passes (each (V, H, W, C), zero where ``mask`` (V, H, W, 1) is 0) ``steps`` pixels outwards by
    the mask-weighted 3x3 mean of their neighbours: IDM priors are zeroed where alpha <= 0.5
    (:meth:`IntrinsicPriors.masked`), and the silhouette's soft pixels (0 < alpha <= 0.5) still need a G-buffer to
    shade. Inside the mask nothing changes. Returns the dict of filled passes."""
    m = mask.float().permute(0, 3, 1, 2)
    out = {k: v.float().permute(0, 3, 1, 2) for k, v in passes.items()}
    for _ in range(steps):
        w = F.avg_pool2d(m, 3, 1, 1)
        grown = (w > 0).float()
        for k, v in out.items():
            avg = F.avg_pool2d(v * m, 3, 1, 1) / w.clamp_min(1e-6)
            out[k] = m * v + (1 - m) * grown * avg
        m = torch.maximum(m, grown)
    return {k: v.permute(0, 2, 3, 1) for k, v in out.items()}


def gbuffer_maps(priors: IntrinsicPriors, alpha: torch.Tensor) -> torch.Tensor:
    """The premultiplied Cook-Torrance maps :func:`ggx_shade` takes, (V, H, W, 8) = [albedo 3, roughness 1, metallic
    1, world normal 3] x alpha, from priors (V, H, W, C each; zero outside their mask) and the photo's alpha
    (V, H, W, 1); the passes are first extended over the silhouette's soft pixels (:func:`fill_background`)."""
    assert alpha.shape == priors.mask.shape, (alpha.shape, priors.mask.shape)
    fg = (priors.mask > 0.5).float()
    p = fill_background({k: getattr(priors, k) for k in ("albedo", "roughness", "metallic", "normal")}, fg)
    maps = torch.cat([p["albedo"], p["roughness"], p["metallic"], p["normal"]], -1)
    return maps * alpha


def oracle_gbuffer(results: str | Path, oid: str, view: str) -> IntrinsicPriors:
    """The curated ground-truth G-buffer of target view ``view`` (``objects/{obj}/gbuffer/{view}.exr``), (1, H, W, C)
    passes as :class:`IntrinsicPriors` (mask = its coverage)."""
    from frng.data.dataset import open_object
    from frng.priors.dataset import read_gbuffer

    return read_gbuffer(open_object(results, oid), "targets", [view])


def reshade(
    maps: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    env: torch.Tensor,
    shading: ShadingConfig,
    seed: int,
) -> torch.Tensor:
    """Shade maps (V, H, W, 8) (:func:`gbuffer_maps`) with alpha (V, H, W, 1) at cameras c2w (V, 4, 4), intr (V, 4)
    under env (He, We, 3) with :func:`ggx_shade` (``shading.spp_infer`` samples drawn with ``seed``). Returns RGBA
    (V, H, W, 4) linear premultiplied."""
    V, H, W = alpha.shape[:3]
    assert maps.shape == (V, H, W, 8) and c2w.shape == (V, 4, 4) and intr.shape == (V, 4), (maps.shape, c2w.shape)
    sampler = envmap.importance_sampler(env)
    samples = envmap.sample(sampler, int(shading.spp_infer), shading.sampling, int(seed))
    rgb = ggx_shade(
        maps,
        alpha,
        c2w,
        intr,
        env,
        samples,
        None,
        shading.alpha_eps,
        "sh",
        chunk=shading.chunk_pixels,
        chunk_pairs=shading.chunk_pairs,
    )
    return torch.cat([rgb.float().clamp_min(0.0), alpha.float()], -1)


def reshade_object(job: ImageJob, oid: str, out: Path, gbuffer: str = "idm", device: str | None = None) -> dict:
    """Relight every target view of ``oid`` under every target light from its own photo (module docstring); write a
    :class:`frng.plan.layout.RelightFolder` at ``out`` (staged next to it, renamed into place at the end). ``gbuffer``:
    ``idm`` (the configured IDM) or ``oracle`` (the curated target-view G-buffers). Returns run.json's record."""
    from frng.device import resolve_device, synchronize
    from frng.plan import catalog
    from frng.priors import build_idm
    from frng.priors.dataset import Views

    if gbuffer not in GBUFFERS:
        raise ImageBaselineError(f"--gbuffer must be one of {GBUFFERS}, got {gbuffer!r}")
    if gbuffer == "idm" and getattr(job.idm, "kind", None) == "diffusion-renderer":
        raise ImageBaselineError(
            "config key 'idm.kind': diffusion-renderer priors are files of the input views (frame order), not of the "
            "target views this baseline decomposes; use --gbuffer oracle or a learned IDM"
        )
    inp = read_inputs(job.results, oid)
    dev = resolve_device(device or job.device)
    idm = build_idm(job.idm, job.backbone, job.results, dev) if gbuffer == "idm" else None
    envs = {l: torch.from_numpy(e).float().to(dev) for l, e in inp.envs.items()}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".staging-{out.name}-", dir=out.parent))
    idm_s, shade_s = 0.0, 0.0
    try:
        for v in inp.views:
            name = v["name"]
            img = torch.from_numpy(inp.images[name])[None]
            views = Views(
                [name],
                img[..., :3].clamp_min(0.0).contiguous(),
                img[..., 3:4].clamp(0.0, 1.0).contiguous(),
                torch.tensor(np.asarray(v["c2w"]), dtype=torch.float32)[None],
                torch.tensor(np.asarray(v["intrinsics"]), dtype=torch.float32)[None],
            )
            synchronize(dev)
            t0 = time.perf_counter()
            with torch.no_grad():
                if idm is None:
                    pri = oracle_gbuffer(job.results, oid, name)
                else:
                    pri = idm.priors(
                        oid, views, oracle_gbuffer(job.results, oid, name) if idm.kind == "oracle" else None
                    )
                maps = gbuffer_maps(pri.to(dev), views.alpha.to(dev))
            synchronize(dev)
            idm_s += time.perf_counter() - t0
            for light in inp.lights:
                t0 = time.perf_counter()
                with torch.no_grad():
                    rgba = reshade(
                        maps,
                        views.alpha.to(dev),
                        views.c2w.to(dev),
                        views.intr.to(dev),
                        envs[light],
                        job.shading,
                        catalog.derive_seed(job.seed, IMAGE_BASED_RUN, oid, light, name),
                    )
                synchronize(dev)
                shade_s += time.perf_counter() - t0
                io.write_exr(RelightFolder(staging).image(light, name), rgba[0].cpu().numpy(), ["R", "G", "B", "A"])
        n_img = len(inp.views) * len(inp.lights)
        info = {
            "run": IMAGE_BASED_RUN,
            "name": IMAGE_BASED_RUN,
            "method": IMAGE_BASED_RUN,
            "object": oid,
            "views": 1,
            "input": f"each target view's own image under the input light {inp.light!r}",
            "source": "trained here",
            "gbuffer": "IDM (idm.kind " + str(getattr(job.idm, "kind", "?")) + ")" if gbuffer == "idm" else "oracle",
            "shading": SHADING_NOTE,
            "spp": int(job.shading.spp_infer),
            "input_light": inp.light,
            "lights": inp.lights,
            "target_views": [v["name"] for v in inp.views],
            "fit_seconds": None,
            "idm_seconds_per_view": idm_s / len(inp.views),
            "relight_seconds_per_image": (idm_s + shade_s) / n_img,
            "relight_ms_per_image": 1000.0 * (idm_s + shade_s) / n_img,
            "threads": torch.get_num_threads(),
            "device": str(dev),
            "host": platform.node(),
        }
        io.write_json(RelightFolder(staging).record(), info)
        if out.exists():
            shutil.rmtree(out)
        os.replace(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return info
