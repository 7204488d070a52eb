"""Train one F-RNG variant on the training split from the frozen priors' caches (stage :mod:`frng.stages.train`,
``frng train``).

Loss (supplement, "Model and training details")::

    L = lambda_1 L_2 + lambda_per L_per + L_ind,      (lambda_c, lambda_KLD, lambda_1, lambda_per) = (0.2, 0.2, 1.0, 0.5)

One step = ``train.batch`` objects (split over ranks under torchrun/srun, :mod:`frng.training.distributed`); per object:

1. read from memory what the caches hold (never the backbone): the V-view backbone entry (T_geo, per-pixel
   Gaussians, keep, cameras, T_app per cached light), its IDM priors (not even opened for ``no-idm``) and its
   input images (saliency + fine keep mask);
2. reconstruct from the appearance tokens under the reference light E_0 (cache light 0; the input views' light is
   never an input: the pixel head of F-RNG+ estimates it from the images); with L_ind on, the MaterialFormer also
   runs on the appearance tokens of a random extra cached light j >= 1, drawn anew every step (same T_geo, T_prior and salient patches; one
   batched pass) and ``L_ind = lambda_c C + lambda_KLD KL`` compares the two T_mat (:mod:`frng.model.light_independence`);
   for ``no-ind`` the second pass is skipped (its weights are zero);
3. target light: uniform over the object's target lights and its other input lights; ``train.target_views`` random
   views of it (target views, or input views for an input light); render under that light's env map with
   ``shading.spp_train`` importance samples of which ``shading.spp_grad`` carry gradients (paper 64 / 24);
4. both images are composited over ``train.background`` (default white, the evaluation's background: a render
   whose alpha falls short of the target's near the silhouette is then penalised for the background showing
   through, and the decoder learns colours that hold up where the frozen coarse geometry is thin);
   L_2: mean squared error over the target's foreground pixels (alpha > 0.5, the metric's mask; ``train.l2_pixels:
   union`` adds the render's foreground: those over-covered pixels pull every colour brighter) of the composited
   RGB after ``x -> (max(x, 0) + 1e-4)^(1/2.2)`` (a display-like encoding without an upper clamp, so over-bright
   predictions still get a gradient); L_per: LPIPS-vgg (real ImageNet weights,
   :class:`frng.perceptual.PerceptualLoss`) on the sRGB-encoded composited renders, from step
   ``train.perceptual_after`` on (0: from the start).

The frozen backbone is loaded once, only to copy its GeoDetokenizer into the FineGeoDetokenizer (and for its
architecture); it is never run and gets no gradient. Outputs in ``--out`` (default ``{results}/models/{variant}``):
``model.pt`` (:meth:`FRNG.save`), ``checkpoint.pt`` (resume: rerunning the same command continues an unfinished
run of the same config and data, :func:`frng.training.loop.fit`), ``loss.csv``, ``loss.png``, ``train.json`` (steps,
training seed, wall time, device, step time). Seeds are fixed
(``frng.training.loop.train_seed``: ``train_seed``, else ``seed``); AdamW with linear warm-up + cosine decay; bf16 autocast for the networks (``train.bf16``).
"""

from __future__ import annotations

import random
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch
from torch import nn

from frng import checkpoint, io
from frng.device import autocast, bf16_ok
from frng.hashing import data_digest, file_sha256
from frng.memo import TensorMemo
from frng.model.composed import FRNG
from frng.model.composed_config import FRNGConfig, FRNGSection
from frng.model.depth import DepthHead, at_distances
from frng.model.light_independence import LightIndependenceConfig, light_independence_loss
from frng.plan.layout import Layout
from frng.plan.sections import TypedConfig, section_dict
from frng.plan.variants import GEOMETRIES, canonical_for, paper_form, variant
from frng.priors.backbone_config import BackboneConfig, BackboneSection
from frng.render import envmap
from frng.render.raster import RasterConfig
from frng.render.shading import ShadingConfig
from frng.training import distributed
from frng.training import loop as tr
from frng.training.frng_trainer_config import LossConfig, TrainConfig

# the backbone cache tensors training reads, besides light{j}.t_app (raw: the opacity head's geometry inputs)
CACHE_KEYS = ("t_geo", "raw", "raw_prior", "means", "quats", "scales", "opacities", "keep", "c2w", "intr")
BACK_KEYS = tuple("back_" + k for k in ("means", "quats", "scales", "opacities", "src", "dirs"))  # when cached
LOSS_NAMES = ["total", "l2", "alpha", "depth", "perceptual", "ind", "ind_cos", "ind_kld"]


@dataclass(frozen=True)
class ModelSections:
    """The config sections an F-RNG variant's model is built from (:func:`variant_config`,
    :func:`frng.training.frng_trainer.build_model`); a stage picks them out of the typed config (:meth:`of`)."""

    frng: FRNGSection
    shading: ShadingConfig
    raster: RasterConfig
    patch_size: int  # model.patch_size
    backbone: BackboneSection  # the token width and near/far/max_radius_px when no frozen backbone is given
    loss: LossConfig  # train.loss: the L_ind weights

    @classmethod
    def of(cls, config: TypedConfig) -> ModelSections:
        """The sections of the typed config (``frng.typedconfig.Config``)."""
        return cls(
            frng=config.frng,
            shading=config.shading,
            raster=config.raster,
            patch_size=config.model.patch_size,
            backbone=config.backbone,
            loss=config.train.loss,
        )


def variant_config(
    sections: ModelSections, name: str, backbone_cfg: dict | None = None
) -> tuple[FRNGConfig, LightIndependenceConfig]:
    """(architecture, L_ind weights) of a variant from the config's model sections: the config's keys as they are
    for F-RNG+ (``plus``), the paper's form (:func:`frng.plan.variants.paper_form`: every addition off) for ``full``,
    its ablations and the K sweep.

    ``backbone_cfg``: the frozen backbone's architecture dict (its ``model.pt`` ``config``); the token width and
    near/far/max_radius_px come from it (default: the config's ``backbone`` section).
    """
    f, sh = sections.frng, sections.shading
    bb = BackboneConfig.from_saved(backbone_cfg) if backbone_cfg else sections.backbone

    def same(section, *keys: str) -> dict:  # FRNGConfig fields named as the section's keys
        return {k: getattr(section, k) for k in keys}

    cfg = FRNGConfig(
        **same(f, "prior_dim", "upsample", "hidden", "depth", "heads", "feature_dim", "pixel_head"),
        **same(f, "back_completion", "fine_in_hull", "opacity_head", "geometry_inputs", "depth_head", "coverage_head"),
        **same(f, "specular_start", "normal_start"),
        **same(sh, "decoder_width", "decoder_depth", "dir_freqs", "decoder_cosine"),
        **same(bb, "near", "far", "max_radius_px"),
        patch=sections.patch_size,
        geo_dim=bb.width,
        fine=True,
        top_k=f.top_k_percent / 100.0,
        head="neural",
        saliency=section_dict(f.saliency, "frng.saliency"),
        decoder_attenuation=sh.decoder_cosine and sh.decoder_attenuation,
        decoder_specular=sh.decoder_cosine and sh.decoder_specular,
    )
    loss = sections.loss
    ind = LightIndependenceConfig(
        lambda_c=loss.lambda_c, lambda_kld=loss.lambda_kld, temperature=loss.temperature, pixels=loss.ind_pixels
    )
    v = variant(canonical_for(name, f.top_k_percent))
    if not v.additions:  # the paper's form: every addition of frng.plan.variants.ADDITIONS off
        arch, loss_off = paper_form()
        cfg, ind = replace(cfg, **arch), replace(ind, **loss_off)
    return replace(cfg, **v.arch), replace(ind, **v.loss)


@dataclass
class TrainObject:
    """What training reads of one object (all CPU tensors)."""

    id: str
    views: dict  # CACHE_KEYS + light{j}.t_app of the V-view cache entry
    lights: int  # cached lights (0 = input light)
    priors: object | None  # IntrinsicPriors or None (no-idm: never read)
    images: torch.Tensor  # (V, H, W, 4) input views under the input light
    env_in: torch.Tensor  # (He, We, 3) the input light's env map
    alt_images: torch.Tensor | None  # (V, H, W, 4) the same input views under the object's second input light
    alt_env: torch.Tensor | None  # (He, We, 3) that light's env map (None: one input light, or not loaded)
    targets: list  # [(light name, env (He, We, 3), c2w (Vt, 4, 4), intr (Vt, 4), rgba (Vt, H, W, 4))]; the object's
    # other input lights last, with all its input views
    view_names: list  # the V input views' names (the cache's), in the order of ``images``
    depth_target: torch.Tensor | None = None  # (V*H*W,) each input pixel's surface distance along its ray (0 = none)


def load_objects(
    results: str | Path,
    idm_kind: str,
    ids: list[str],
    backbone_path: Path,
    use_priors: bool,
    V: int,
    alt_light: bool = False,
    idm=None,
    with_depth: bool = False,
    geometry: str = "backbone",
) -> list[TrainObject]:
    """Read caches + curated images of ``ids`` under ``results``. IDM priors are opened only when ``use_priors``
    (``idm_kind``: the config's ``idm.kind``; the learned IDM's priors are checked against its model file); where the
    cached priors are of other views than the V read here (the cache holds the rig's, :func:`frng.priors.cache.
    make_idm_priors`), they are made live by ``idm`` (a :func:`frng.priors.build_idm` prior) from exactly those V
    views, since the IDM's priors of a view depend on the other views it is given; without ``idm`` that is an error.
    ``alt_light``: also the input views under the object's second input light (L_ind's re-lit evidence).
    ``with_depth``: also the V input views' surface distances from their G-buffers (L_depth's target).
    ``geometry``: ``backbone`` (the cache's Gaussians as they are) or a diagnostic: the pixel Gaussians put at
    (:func:`frng.model.depth.at_distances`) their G-buffer surface distances (``gbuffer``), their six-view visual
    hull's (``hull``, :func:`frng.priors.multiview.geometry_cues`) or the hull refined by multi-view stereo
    (``stereo``, :func:`frng.priors.stereo.stereo_distance`), made from the V input views read here; the
    far-side copies stay where the cache has them."""
    from frng.data.dataset import open_object
    from frng.priors import view_priors
    from frng.priors.cache import load_backbone_cache, load_idm_priors
    from frng.priors.dataset import load_object

    if geometry not in GEOMETRIES:
        raise ValueError(f"geometry must be one of {GEOMETRIES}, got {geometry!r}")
    L = Layout(results)
    idm_model = L.idm_model() if idm_kind == "learned" else None
    envs: dict[str, torch.Tensor] = {}
    out = []
    for oid in ids:
        cache = load_backbone_cache(L.backbone_cache(oid), backbone_path)
        allv = cache.views(V)
        lights = len(cache.lights)
        views = {k: allv[k] for k in CACHE_KEYS + tuple(k for k in BACK_KEYS if k in allv)}
        views.update({f"light{j}.t_app": allv[f"light{j}.t_app"] for j in range(lights)})
        priors = None
        obj = open_object(L.root, oid)
        light_in = cache.meta["input_light"]
        names = cache.meta["view_names"][str(V)]
        if use_priors:
            priors, pmeta = load_idm_priors(L.idm_priors(oid), idm_model)
            if list(pmeta["view_names"]) != list(names):
                if idm is None:
                    raise ValueError(
                        f"{L.idm_priors(oid)}: IDM priors of views {pmeta['view_names']}, not of the {V} views "
                        f"{list(names)} read here; pass an IDM to make them live"
                    )
                pobj = load_object(results, oid, with_targets=False, with_gbuffer=idm.kind == "oracle")
                rows = [pobj.inputs[light_in].names.index(n) for n in names]
                with torch.no_grad():
                    priors = view_priors(idm, pobj, light_in, rows).to("cpu")
        images = obj.images("inputs", light_in, names, torch=True)
        if light_in not in envs:
            envs[light_in] = torch.from_numpy(envmap.read(obj.envmap_path(light_in, L.root))).float()
        targets = []
        other_inputs = [l for l in obj.input_lights if l != light_in]
        kinds = [("targets", l) for l in obj.target_lights] + [("inputs", l) for l in other_inputs]
        for kind, light in kinds:
            if light not in envs:
                envs[light] = torch.from_numpy(envmap.read(obj.envmap_path(light, L.root))).float()
            c2w, K = obj.cameras(kind, None, torch=True)
            targets.append((light, envs[light], c2w, K, obj.images(kind, light, None, torch=True)))
        alt_images = alt_env = None
        if alt_light and other_inputs:  # the V input views under the second input light: rows of its target entry
            rows = [obj.view_names("inputs").index(n) for n in names]
            alt_images = targets[len(obj.target_lights)][4][rows]
            alt_env = envs[other_inputs[0]]
        surface = None  # each input pixel's G-buffer surface distance along its ray (0 = none), read once for both uses
        if with_depth or geometry == "gbuffer":
            from frng.priors.backbone import ray_distance_target

            gb_depth = obj.gbuffer("inputs", names, torch=True)["depth"]
            surface = ray_distance_target(gb_depth, views["c2w"].float(), views["intr"].float()).reshape(-1)
        if geometry == "gbuffer":
            views["means"] = at_distances(views["means"].float(), views["c2w"].float(), surface)
        elif geometry in ("hull", "stereo"):
            views["means"] = at_distances(
                views["means"].float(), views["c2w"].float(), view_geometry(geometry, images, views)
            )
        depth = surface if with_depth else None
        out.append(
            TrainObject(
                oid, views, lights, priors, images, envs[light_in], alt_images, alt_env, targets, list(names), depth
            )
        )
    return out


def view_geometry(kind: str, images: torch.Tensor, views: dict) -> torch.Tensor:
    """Surface distances (V*H*W,) of the input pixels along their rays, 0 off the object (alpha < 0.5), from the
    images alone: the visual hull's first crossing (``hull``) or that refined by multi-view stereo (``stereo``).
    images (V, H, W, 4) linear premultiplied RGBA; views: the cache's ``c2w`` (V, 4, 4) and ``intr`` (V, 4)."""
    from frng.priors.multiview import geometry_cues
    from frng.priors.stereo import stereo_distance

    assert kind in ("hull", "stereo"), kind
    rgb, alpha = images[..., :3].float().clamp_min(0), images[..., 3:4].float().clamp(0, 1)
    c2w, intr = views["c2w"].float(), views["intr"].float()
    cues = geometry_cues(rgb, alpha, c2w, intr, near=0.0, far=1.0)
    hull = cues["distance"][..., 0]
    dist = stereo_distance(rgb, alpha, c2w, intr, hull) if kind == "stereo" else hull
    on = (alpha[..., 0] >= 0.5) & (cues["hit"][..., 0] > 0.5)  # (a foreground ray that misses the hull: no distance)
    return torch.where(on, dist, torch.zeros_like(dist)).reshape(-1)


def encode_display(x: torch.Tensor) -> torch.Tensor:
    """The L_2 space: (max(x, 0) + 1e-4)^(1/2.2), no upper clamp (see the module docstring)."""
    return (x.clamp_min(0.0) + 1e-4) ** (1.0 / 2.2)


L2_SPACES = ("display", "linear")


L2_PIXELS = ("target", "union")


def l2_loss(
    out: torch.Tensor, tgt: torch.Tensor, background, space: str = "display", pixels: str = "target"
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """L_2 of a render against its target (module docstring, step 4).

    out, tgt: (B, H, W, 4) linear premultiplied RGBA; background: 3 floats (``train.background``); space:
    ``display`` (gamma-encoded, :func:`encode_display`) or ``linear``. A Monte-Carlo render is noisy, and the gamma
    curve is concave, so in display space the loss is minimised by a render whose MEAN is brighter than the target
    (the noise pulls the encoded value down); in linear space the noise adds a constant and the minimiser is the
    target itself. pixels: ``target`` = the mean over the target's foreground (alpha > 0.5, the evaluation's
    mask), ``union`` = also where the render's alpha > 0.5. Returns (L_2 scalar, out RGB (B, H, W, 3) and tgt RGB
    composited over the background).
    """
    if space not in L2_SPACES:
        raise ValueError(f"train.l2_space must be one of {L2_SPACES}, got {space!r}")
    if pixels not in L2_PIXELS:
        raise ValueError(f"train.l2_pixels must be one of {L2_PIXELS}, got {pixels!r}")
    fg = tgt[..., 3:4] > 0.5
    if pixels == "union":
        fg = fg | (out[..., 3:4].detach() > 0.5)
    fg = fg.to(out.dtype)
    rgb_out, rgb_tgt = io.composite(out, background), io.composite(tgt, background)
    enc = encode_display if space == "display" else (lambda x: x)
    diff = (enc(rgb_out) - enc(rgb_tgt)) ** 2 * fg
    return diff.sum() / (3 * fg.sum()).clamp_min(1.0), rgb_out, rgb_tgt


def depth_weight(model: FRNG, loss: LossConfig) -> float:
    """L_depth's weight for this model: ``train.loss.lambda_depth``, 0 for a variant without a depth head."""
    return loss.lambda_depth if model.depth_head is not None else 0.0


def depth_loss(rec, views: dict, target: torch.Tensor) -> torch.Tensor:
    """L_depth: mean |distance - target| of the reconstruction's coarse Gaussians (after the depth head's move) from
    their input cameras, over the kept pixels with a surface in the G-buffer. rec: a :class:`frng.model.composed.
    Reconstruction`; views: the cache entry (keep (N,), c2w (V, 4, 4)); target (N,) ray distances (0 = no surface),
    N = V*H*W. Not in the paper: the depth head's only other signal is the rasterizer's gradient on the means,
    which moved them ~0.01 (the hull's error on a thin slab is ~0.2)."""
    keep = views["keep"].bool()
    assert target.shape == keep.shape, (target.shape, keep.shape)
    dev = rec.gaussians.means.device
    origins = DepthHead.origins(views["c2w"].float(), keep).to(dev)
    dist = (rec.gaussians.means[: rec.num_coarse].float() - origins).norm(dim=-1)
    tgt = target[keep].to(dev)
    valid = tgt > 0
    return (dist - tgt).abs()[valid].sum() / valid.sum().clamp_min(1)


def alpha_loss(out: torch.Tensor, tgt: torch.Tensor) -> torch.Tensor:
    """L_alpha: squared error of the render's alpha against the target's, summed over EVERY pixel (faint stray
    splats outside the silhouette included) and divided by the number of pixels either image covers (alpha > 0.5),
    so that small and large objects weigh alike. out, tgt: (B, H, W, 4) -> scalar.

    Not in the paper. L_2 only looks at the target's foreground, so nothing there stops fine Gaussians from
    drifting outside the silhouette (a faint halo around the object); this term does, through their opacity and
    position, the only geometry F-RNG trains."""
    assert out.shape == tgt.shape and out.shape[-1] == 4, (out.shape, tgt.shape)
    a_o, a_t = out[..., 3], tgt[..., 3].to(out.dtype)
    covered = ((a_t > 0.5) | (a_o.detach() > 0.5)).sum().clamp_min(1)
    return ((a_o - a_t) ** 2).sum() / covered


class StepLoss(nn.Module):
    """One training step's loss over a list of objects; a module so DDP can wrap it (its forward is the step)."""

    def __init__(
        self,
        model: FRNG,
        ind: LightIndependenceConfig,
        tcfg: TrainConfig,
        perceptual: nn.Module | None,
        bf16: bool,
        pixel_maps: TensorMemo | None = None,
    ):
        super().__init__()
        self.model, self.ind, self.tcfg, self.bf16 = model, ind, tcfg, bf16
        # the pixel head's per-pixel maps of each object (a fixed function of its data), made once per run: 4-5 %
        # of a step at 96 px (bit-identical either way, tests/test_train_frng.py)
        self.pixel_maps = pixel_maps
        self.perceptual = perceptual  # frozen (no parameters require grad)
        w = tcfg.loss
        self.lambda_1, self.lambda_per, self.lambda_alpha = w.lambda_1, w.lambda_per, w.lambda_alpha
        self.lambda_depth = depth_weight(model, w)
        self.step = 0  # set by the training loop (L_per starts at ``tcfg.perceptual_after``)

    @property
    def ind_on(self) -> bool:
        return self.ind.lambda_c > 0 or self.ind.lambda_kld > 0

    def forward(self, samples: list[tuple[TrainObject, int, int, list[int], int]]) -> tuple[torch.Tensor, dict]:
        """samples: [(object, extra light j, target index, target view indices, sample seed)] -> (loss, logs)."""
        m = self.model
        dev = m.device
        sc = m.shading_cfg
        total = torch.zeros((), device=dev)
        logs = {k: 0.0 for k in LOSS_NAMES}
        for obj, j, ti, vidx, seed in samples:
            lights = [0, j] if self.ind_on and obj.lights > 1 else [0]
            # the input light is never an input (the paper's task): the pixel head estimates it from the images
            images, envs = obj.images, None
            if len(lights) > 1 and self.ind.pixels and obj.alt_images is not None:
                images, envs = [obj.images, obj.alt_images], [None, None]
            with autocast(dev, self.bf16):
                maps = None
                if m.pixel_head is not None and self.pixel_maps is not None:
                    im_b = list(images) if isinstance(images, list) else [images] * len(lights)
                    env_b = list(envs) if isinstance(envs, list) else [envs] * len(lights)
                    maps = self.pixel_maps.get(
                        (obj.id, len(lights), isinstance(images, list)),
                        lambda o=obj, i=im_b, e=env_b: m.pixel_maps(o.views, i, e, o.priors),
                    )
                recs = m.reconstruct(
                    obj.views, lights, obj.priors, images, keep_tokens=True, input_env=envs, pixel_maps=maps
                )
            _, _, c2w, K, rgba = obj.targets[ti]
            vi = torch.as_tensor(vidx)
            H, W = rgba.shape[1:3]
            gen = torch.Generator().manual_seed(seed)
            raster = m.rasterize(recs[0], c2w[vi], K[vi], H, W)
            loss = torch.zeros((), device=dev)
            tis = same_view_lights(obj, ti, self.tcfg.target_lights, seed)
            for t in tis:  # the same views under each light: one rasterization, shaded per light
                env, tgt = obj.targets[t][1], obj.targets[t][4][vi].to(dev)
                out = m.shade(raster, env, sc.spp_train, gen, sc.spp_grad)
                l2, rgb_out, rgb_tgt = l2_loss(out, tgt, self.tcfg.background, self.tcfg.l2_space, self.tcfg.l2_pixels)
                loss = loss + self.lambda_1 * l2 / len(tis)
                logs["l2"] += float(l2.detach()) / len(tis)
                if self.lambda_alpha > 0:
                    a = alpha_loss(out, tgt)
                    loss = loss + self.lambda_alpha * a / len(tis)
                    logs["alpha"] += float(a.detach()) / len(tis)
                if self.perceptual is not None and self.lambda_per > 0 and self.step >= self.tcfg.perceptual_after:
                    per = self.perceptual(rgb_out.permute(0, 3, 1, 2), rgb_tgt.permute(0, 3, 1, 2))
                    loss = loss + self.lambda_per * per / len(tis)
                    logs["perceptual"] += float(per.detach()) / len(tis)
            if self.lambda_depth > 0:
                if obj.depth_target is None:
                    raise ValueError(f"train.loss.lambda_depth > 0 but {obj.id} was loaded without its G-buffer depths")
                dl = depth_loss(recs[0], obj.views, obj.depth_target)
                loss = loss + self.lambda_depth * dl
                logs["depth"] += float(dl.detach())
            if len(recs) > 1:
                mats = (recs[0].material, recs[1].material) if self.ind.pixels else (None, None)
                ind, parts = light_independence_loss(recs[0].t_mat, recs[1].t_mat, self.ind, *mats)
                loss = loss + ind
                logs["ind"] += float(ind.detach())
                logs["ind_cos"] += float(parts["cos"])
                logs["ind_kld"] += float(parts["kld"])
            total = total + loss / len(samples)
            logs["total"] += float(loss.detach())
        return total, {k: v / len(samples) for k, v in logs.items()}


def same_view_lights(obj: TrainObject, ti: int, n: int, seed: int) -> list[int]:
    """``ti`` and up to ``n - 1`` other target lights of ``obj`` rendered at the same cameras (``train.target_lights``),
    drawn with ``seed``: one rasterization shaded under each (a light-independent appearance cannot fit them all)."""
    if n <= 1:
        return [ti]
    c2w = obj.targets[ti][2]
    same = [t for t in range(len(obj.targets)) if t != ti and obj.targets[t][2].shape == c2w.shape]
    same = [t for t in same if torch.equal(obj.targets[t][2], c2w)]
    return [ti, *random.Random(seed).sample(same, min(n - 1, len(same)))]


def sample(obj: TrainObject, rng: random.Random, n_views: int) -> tuple[int, int, list[int]]:
    """(extra light j, target index, target view indices) of one object (see the module docstring)."""
    j = rng.randrange(1, obj.lights) if obj.lights > 1 else 0
    ti = rng.randrange(len(obj.targets))
    nv = obj.targets[ti][2].shape[0]
    vidx = sorted(rng.sample(range(nv), min(n_views, nv)))
    return j, ti, vidx


def build_model(
    sections: ModelSections, variant: str, backbone_path: Path, device
) -> tuple[FRNG, LightIndependenceConfig]:
    """A fresh variant model, FineGeoDetokenizer initialised from the frozen backbone's GeoDetokenizer."""
    from frng.priors import load_backbone

    backbone = load_backbone(backbone_path, "cpu")
    cfg, ind = variant_config(sections, variant, backbone.cfg.to_dict())
    model = FRNG.from_backbone(cfg, backbone, sections.raster, sections.shading)
    return model.to(device), ind


@dataclass(frozen=True)
class TrainRun:
    """What one training run reads besides the sections: the results folder, the models' seed
    (``frng.typedconfig.Config.model_seed``), the config's ``device`` and ``idm.kind``, and the training split's
    object ids (the dataset plan's; read only when :func:`train` is not handed the objects)."""

    results: str
    seed: int
    device: str
    idm_kind: str
    train_ids: tuple[str, ...] = ()


def train(
    sections: ModelSections,
    tcfg: TrainConfig,
    job: TrainRun,
    variant: str,
    out: Path,
    backbone_path: Path | None = None,
    steps: int | None = None,
    stop_after: int | None = None,
    objects: list[TrainObject] | None = None,
    pixel_memo: bool = True,
    geometry: str = "backbone",
) -> Path:
    """Train (or resume) one variant; returns ``out/model.pt`` (or the checkpoint when stopped by ``stop_after``,
    which tests use to simulate an interruption). ``sections``: the model's config sections, ``tcfg``: the config's
    ``train`` section. ``pixel_memo``: keep each object's pixel maps between steps (the same weights either way;
    False only for the test that checks so). ``geometry``: what the objects' coarse Gaussians sit on
    (:func:`load_objects`; ``gbuffer`` is a diagnostic, recorded in train.json)."""
    variant = canonical_for(variant, sections.frng.top_k_percent)
    backbone_path = Path(backbone_path or Layout(job.results).backbone_model())
    total = steps or tcfg.steps_for(variant)
    info = distributed.init(job.device)
    device = info.device
    distributed.seed_everything(job.seed, info, per_rank=False)  # identical init on every rank
    model, ind = build_model(sections, variant, backbone_path, device)
    if objects is None:
        ids = distributed.shard_items(list(job.train_ids), info)
        alt = ind.pixels and (ind.lambda_c > 0 or ind.lambda_kld > 0)
        depth = depth_weight(model, tcfg.loss) > 0
        objects = load_objects(
            job.results,
            job.idm_kind,
            ids,
            backbone_path,
            model.cfg.uses_priors,
            tcfg.views,
            alt,
            with_depth=depth,
            geometry=geometry,
        )
    if not objects:
        raise ValueError("frng train: no training objects on this rank")
    perceptual = None
    if tcfg.loss.lambda_per > 0:
        from frng.perceptual import PerceptualLoss

        perceptual = PerceptualLoss(
            "lpips",
            net=tcfg.perceptual_net,
            srgb=True,
            autocast_bf16=tcfg.bf16 and device.type == "cpu" and bf16_ok(device),
        ).to(device)
    step_loss = StepLoss(model, ind, tcfg, perceptual, tcfg.bf16, TensorMemo() if pixel_memo else None)
    ddp = distributed.wrap(step_loss, info, find_unused_parameters=True)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=tcfg.lr, betas=(0.9, 0.99), weight_decay=tcfg.weight_decay)
    hooks = distributed.fit_hooks(info)
    fingerprint = checkpoint.fingerprint(
        model.cfg.to_dict(),
        tcfg,
        total,
        job.seed,
        variant=variant,
        shading=asdict(model.shading_cfg),
        world=info.world_size,
        backbone_sha256=file_sha256(backbone_path),
        data=hooks.gather(data_digest(objects)),
    )
    rng = random.Random(distributed.rank_seed(job.seed, info))
    local_batch = max(1, tcfg.batch // info.world_size)

    def step_fn(step: int) -> dict[str, float]:
        samples = []
        for b in range(local_batch):
            obj = objects[rng.randrange(len(objects))]
            j, ti, vidx = sample(obj, rng, tcfg.target_views)
            seed = (job.seed * 1_000_003 + step * 1009 + info.rank * 31 + b) % (2**31 - 1)
            samples.append((obj, j, ti, vidx, seed))
        step_loss.step = step
        loss, logs = ddp(samples)
        loss.backward()
        return logs

    def save_model(path: Path) -> None:
        model.save(path, {"variant": variant, "steps": total, "backbone_sha256": fingerprint["backbone_sha256"]})

    def summary(run: tr.FitRun) -> dict:
        return {
            "variant": variant,
            "seed": job.seed,  # the training seed (a {variant}@s{seed} run's seed; its variant is the base name)
            "steps": total,
            "wall_s": round(run.wall_s, 1),
            "device": str(device),
            "world_size": info.world_size,
            "bf16": tcfg.bf16,
            "objects": len(objects) * info.world_size,
            "geometry": geometry,
            "step_s_mean_this_run": round(run.step_s_mean, 3),
            "parameters": sum(p.numel() for p in model.parameters()),
        }

    trainer = tr.Trainer(
        model=model,
        optimizer=opt,
        step=step_fn,
        save_model=save_model,
        summary=summary,
        loss_names=LOSS_NAMES,
        title=f"F-RNG {variant} training loss",
        desc=f"train {variant}",
        params=params,
        postfix=("total", "l2"),
        rngs={"sample": rng},
        device=device,
        hooks=hooks,
    )
    return tr.fit(trainer, tcfg, out=out, total=total, fingerprint=fingerprint, stop_after=stop_after)
