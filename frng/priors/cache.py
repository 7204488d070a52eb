"""Per-object caches of the frozen priors: what F-RNG training reads instead of running them.

Stages (one job per object): ``frng backbone-cache --object OBJ`` (:mod:`frng.stages.backbone_cache`) ->
``{results}/backbone/cache/{obj}.safetensors`` and ``frng idm-priors --object OBJ`` (:mod:`frng.stages.idm_priors`)
-> ``{results}/priors/idm/{obj}.safetensors``.

Backbone cache schema (safetensors; version :data:`BACKBONE_CACHE_VERSION`)
--------------------------------------------------------------------------------
String metadata: ``version``, ``backbone_sha256`` (sha256 of the ``model.pt`` it was made with), ``object``,
``input_light`` (the object's first input light: the photos'), ``lights`` (JSON list: index j -> light name; j = 0 is
the reference light E_0 (:data:`REFERENCE_LIGHT`, :func:`frng.render.envmap.reference_light`, the same for every
object: the input views' light is unknown at test time), j >= 1 extra TRAINING lights (L_ind's E_1) drawn from the
training env-map pool with a seed derived from ``seed`` and the object id), ``view_counts`` (JSON list of the V cached), ``view_names`` (JSON: V -> names of the input views used,
the first V input views: rig order, then extras), ``sh_degree``, ``patch``, ``width``, ``near``, ``far``,
``resolution``. Tensors (float32 unless noted), for every cached V:

=============================== =============== ===============================================================
key                             shape           meaning
=============================== =============== ===============================================================
``v{V}.t_geo``                  (V, h, w, D)    geometry tokens T_geo (h = w = resolution / patch)
``v{V}.raw``                    (V, H, W, 9)    raw Gaussian parameters (decode with frng.gaussians.pixel_gaussians)
``v{V}.raw_prior``              (V, H, W, 9)    the multi-view prior's part of raw (frng.priors.multiview)
``v{V}.means`` / ``quats`` /    (N, 3)/(N, 4)/  decoded per-pixel Gaussians, N = V*H*W in (view, row, col)
``scales`` / ``opacities``      (N, 3)/(N,)     order (quats (w, x, y, z), scales = std devs); opacity 0 where
                                                another view covers the pixel more squarely (backbone.view_select)
                                                or sees it on its background (backbone.silhouette_cull)
``v{V}.keep``                   (N,) uint8      1 where the input pixel is foreground (alpha >= 0.5)
``v{V}.c2w`` / ``v{V}.intr``    (V, 4, 4)/(V,4) the input cameras
``v{V}.back_means`` / ``quats``  (M, 3)/(M, 4)/  far-side copies of per-pixel Gaussians where no input view sees
/ ``scales`` / ``opacities``    (M, 3)/(M,)     the hull's far side (frng.priors.multiview.back_gaussians)
``v{V}.back_src``               (M,) int64      each copy's source pixel (index into N)
``v{V}.back_dirs``              (M, 3)          the source pixel's unit ray (to mirror the copied normal)
``v{V}.light{j}.t_app``         (V, h, w, D)    appearance tokens T_app of the final DDIM step under light j
``v{V}.light{j}.sh``            (N, K, 3)       final SH coefficients (K = (sh_degree + 1)^2) under light j
=============================== =============== ===============================================================

Training objects cache V = 6 (the rig); test objects also the number-of-views sweep (2, 4, 6, 8, 10 where the
object has that many input views). The DDIM noise is seeded from ``seed``, the object and the light.

IDM priors schema (version :data:`IDM_CACHE_VERSION`)
-----------------------------------------------------
Metadata: ``version``, ``idm_kind``, ``idm_sha256`` (learned: the model file's hash, else ``""``), ``object``,
``light`` (the input light the views were rendered under), ``view_names`` (JSON list). Tensors: one per pass of
:mod:`frng.priors.intrinsics` (``normal``, ``depth``, ``albedo``, ``roughness``, ``metallic``, ``mask``), each
(V, H, W, C) for ALL input views (rig + extras) in order.

Stale caches: :func:`load_backbone_cache` / :func:`load_idm_priors` compare the recorded hash (and version) with
the current model file and raise :class:`StaleCacheError` on mismatch; they are never silently reused.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from frng import io
from frng.hashing import file_sha256
from frng.plan import catalog
from frng.plan.layout import Layout
from frng.plan.variants import SWEEP_VIEWS, view_counts  # noqa: F401
from frng.priors import build_idm, load_backbone, view_priors
from frng.priors.intrinsics import IntrinsicPriors
from frng.render import envmap

BACKBONE_CACHE_VERSION = "7"  # 7: light 0 is the reference light, not the input light
IDM_CACHE_VERSION = "1"


REFERENCE_LIGHT = "reference"  # cache light 0's name: the reference light E_0


def told_input_light(backbone) -> bool:
    """Whether a backbone reads the input views' light (``light_cue_input: known``: an oracle setting, not the
    paper's task; models saved before ``fit`` became the default)."""
    return bool(backbone.cfg.light_cue and backbone.cfg.light_cue_input == "known")


def reference_env(backbone) -> torch.Tensor:
    """The reference light E_0 (He, We, 3) at the backbone's env-encoding height (at least 16 rows)."""
    return envmap.reference_light(max(16, int(backbone.cfg.env_height)))


class StaleCacheError(RuntimeError, io.CorruptFileError):
    """A cache was made with another model (or an older cache version); re-run the cache rule. A
    :class:`frng.io.CorruptFileError` too: a stage ends in one line naming the cache file (``frng.cli.run_stage``)."""


def _save(tensors: dict[str, torch.Tensor], meta: dict[str, str], path: Path) -> None:
    io.save_safetensors(tensors, path, meta)  # canonical header: the same cache gives the same bytes


def _load(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    from safetensors import safe_open

    if not path.exists():
        raise FileNotFoundError(f"{path}: cache file does not exist")
    try:
        with safe_open(str(path), framework="pt") as f:
            return {k: f.get_tensor(k) for k in f.keys()}, dict(f.metadata() or {})
    except Exception as e:  # noqa: BLE001 -- SafetensorError (incomplete metadata, ...) names no file
        raise io.CorruptFileError(
            f"{path}: cannot read cache: truncated or corrupt ({type(e).__name__}: {e}); "
            f"delete it and rerun the rule that makes it"
        ) from None


def extra_training_lights(
    envmaps: Sequence[catalog.EnvMapSpec], seed: int, oid: str, exclude: str, count: int
) -> list[str]:
    """``count`` random training env maps of the planned ``envmaps`` (not ``exclude``), seeded by the config's data
    ``seed`` and the object id."""
    pool = sorted(e.name for e in envmaps if e.split == "train" and e.name != exclude)
    if len(pool) < count:
        raise ValueError(f"only {len(pool)} training env maps besides {exclude}; need {count} extra lights")
    rng = catalog.rng_for(seed, "cache-lights", oid)
    return [pool[i] for i in rng.choice(len(pool), count, replace=False)]


# -- backbone cache ------------------------------------------------------------------------------------


def geometry_entry(model, recon: tuple, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> dict:
    """The light-independent part of one view set's cache entry (the table above, without the ``v{V}.`` prefix):
    ``t_geo``, ``raw``, ``raw_prior``, the decoded Gaussians, ``keep``, ``c2w``, ``intr`` and the far-side copies
    ``back_*``. ``recon``: what ``model.reconstruct(rgb, alpha, c2w, intr)`` returned for alpha (V, H, W, 1),
    c2w (V, 4, 4), intr (V, 4) of V input views. The cache stage, live relighting and the relighting benchmark
    all build their entries here, so the three cannot drift apart."""
    t_geo, raw, gauss, keep, raw_prior, _ = recon
    V = c2w.shape[0]
    assert alpha.shape[0] == V and c2w.shape == (V, 4, 4) and intr.shape == (V, 4), (alpha.shape, c2w.shape, intr.shape)
    # ``keep`` is every foreground pixel's Gaussian (F-RNG reads their features and the far-side copies' sources);
    # the ones the backbone does not render (frontal view selection, ``backbone.view_select``; off the visual hull,
    # ``backbone.silhouette_cull``) get opacity 0
    fg = alpha.reshape(-1) >= 0.5
    return {
        "t_geo": t_geo[0].float(),
        "raw": raw.float(),
        "raw_prior": raw_prior.float(),
        "means": gauss.means,
        "quats": gauss.quats,
        "scales": gauss.scales,
        "opacities": torch.where(fg & ~keep, torch.zeros_like(gauss.opacities), gauss.opacities),
        "keep": fg.to(torch.uint8),
        "c2w": c2w,
        "intr": intr,
        **{"back_" + k: t for k, t in model.back_gaussians(gauss, alpha, c2w, intr).items()},
    }


def make_backbone_cache(
    results: str | Path,
    seed: int,
    envmaps: Sequence[catalog.EnvMapSpec],
    extra_lights: int,
    oid: str,
    model_path: Path,
    out: Path,
    device="cpu",
) -> Path:
    """Cache object ``oid`` (curated under ``results``) through the backbone ``model_path`` into ``out``: the
    reference light and ``extra_lights`` (``backbone.cache_extra_lights``) training lights of the planned ``envmaps``
    (:func:`extra_training_lights`); ``seed``: the config's data seed (DDIM seeds)."""
    from frng.priors.dataset import load_object

    model = load_backbone(model_path, device)
    sha = file_sha256(model_path)
    obj = load_object(results, oid, with_targets=False, with_gbuffer=False)
    light_in = obj.input_lights[0]
    extra = extra_training_lights(envmaps, seed, oid, light_in, extra_lights)
    lights = [REFERENCE_LIGHT] + extra
    envs = {l: torch.from_numpy(envmap.read(Layout(results).envmap(l))) for l in extra}
    envs[REFERENCE_LIGHT] = reference_env(model)
    # the input light only where the backbone itself is told it (light_cue_input: known, an oracle setting)
    env_told = torch.from_numpy(envmap.read(Layout(results).envmap(light_in))) if told_input_light(model) else None
    views = obj.inputs[light_in]
    H, W = views.rgb.shape[1:3]
    tensors: dict[str, torch.Tensor] = {}
    vcounts = view_counts(obj.split, len(views))
    names = {}
    for V in vcounts:
        v = views.select(range(V))
        names[V] = v.names
        rgb, a, c2w, intr = (x.to(device) for x in (v.rgb, v.alpha, v.c2w, v.intr))
        recon = model.reconstruct(rgb, a, c2w, intr, None if env_told is None else env_told.to(device))
        t_geo, _, gauss, keep, _, pixels = recon
        p = f"v{V}."
        tensors.update({p + k: t for k, t in geometry_entry(model, recon, a, c2w, intr).items()})
        nd = model.cfg.den_views
        for j, light in enumerate(lights):
            g = torch.Generator(device=device).manual_seed(catalog.derive_seed(seed, "cache", oid, light))
            sh, t_app = model.denoise(
                t_geo, gauss, keep, envs[light].to(device)[None], c2w[:nd], intr[:nd], H, W, generator=g, pixels=pixels
            )
            tensors[f"{p}light{j}.t_app"] = t_app[0].float()
            tensors[f"{p}light{j}.sh"] = sh.float()
    tensors = {k: t.detach().cpu() for k, t in tensors.items()}
    c = model.cfg
    meta = {
        "version": BACKBONE_CACHE_VERSION,
        "backbone_sha256": sha,
        "object": oid,
        "input_light": light_in,
        "lights": json.dumps(lights),
        "view_counts": json.dumps(vcounts),
        "view_names": json.dumps({str(k): n for k, n in names.items()}),
        "sh_degree": str(c.sh_degree),
        "patch": str(c.patch),
        "width": str(c.width),
        "near": str(c.near),
        "far": str(c.far),
        "resolution": str(H),
    }
    _save(tensors, meta, out)
    return out


@dataclass
class BackboneCache:
    """A loaded backbone cache; ``tensors`` keyed as in the module docstring, ``meta`` decoded."""

    tensors: dict[str, torch.Tensor]
    meta: dict
    lights: list[str]

    def views(self, V: int) -> dict[str, torch.Tensor]:
        """All tensors of the V-view entry with the ``v{V}.`` prefix stripped."""
        p = f"v{V}."
        out = {k[len(p) :]: t for k, t in self.tensors.items() if k.startswith(p)}
        if not out:
            raise KeyError(f"cache of {self.meta['object']} has no {V}-view entry (has {self.meta['view_counts']})")
        return out


def load_backbone_cache(path: str | Path, model_path: str | Path) -> BackboneCache:
    """Load a backbone cache, refusing it when it was made with another backbone file (or cache version)."""
    tensors, meta = _load(Path(path))
    if meta.get("version") != BACKBONE_CACHE_VERSION:
        raise StaleCacheError(f"{path}: cache version {meta.get('version')!r}, expected {BACKBONE_CACHE_VERSION}")
    sha = file_sha256(model_path)
    if meta.get("backbone_sha256") != sha:
        raise StaleCacheError(
            f"{path}: made with backbone {meta.get('backbone_sha256', '?')[:12]}, but {model_path} "
            f"is {sha[:12]}; re-run `frng backbone-cache`"
        )
    decoded = dict(meta)
    for k in ("lights", "view_counts", "view_names"):
        decoded[k] = json.loads(meta[k])
    return BackboneCache(tensors, decoded, decoded["lights"])


# -- IDM priors ------------------------------------------------------------------------------------------


def make_idm_priors(
    idm_section, backbone_section, results: str | Path, oid: str, out: Path, device="cpu", kind: str | None = None
) -> Path:
    """The IDM's priors of object ``oid`` (curated under ``results``) into ``out``; the IDM of ``kind`` (default
    ``idm.kind``) from the config's ``idm`` and ``backbone`` sections (:func:`frng.priors.build_idm`).

    The IDM sees the rig's views only (the paper's 6), what training and the default relighting give F-RNG: it
    attends across the views it is given (:func:`frng.priors.registry.view_priors`). Other view counts take live
    priors (:func:`frng.training.frng_trainer.load_objects`, :mod:`frng.apps.relight`)."""
    from frng.priors.dataset import load_object

    idm = build_idm(idm_section, backbone_section, results, device, kind)
    obj = load_object(results, oid, with_targets=False, with_gbuffer=idm.kind == "oracle")
    light = obj.input_lights[0]
    views = obj.inputs[light].select(range(obj.rig_views))
    pri = view_priors(idm, obj, light, range(obj.rig_views))
    sha = file_sha256(idm.model_path) if idm.kind == "learned" else ""
    meta = {
        "version": IDM_CACHE_VERSION,
        "idm_kind": idm.kind,
        "idm_sha256": sha,
        "object": oid,
        "light": light,
        "view_names": json.dumps(views.names),
    }
    _save({k: v.float().cpu() for k, v in pri.as_dict().items()}, meta, out)
    return out


def load_idm_priors(path: str | Path, model_path: str | Path | None = None) -> tuple[IntrinsicPriors, dict]:
    """Load IDM priors (+ metadata). For learned priors pass the IDM ``model_path``: a hash mismatch is refused."""
    tensors, meta = _load(Path(path))
    if meta.get("version") != IDM_CACHE_VERSION:
        raise StaleCacheError(f"{path}: IDM cache version {meta.get('version')!r}, expected {IDM_CACHE_VERSION}")
    if meta.get("idm_kind") == "learned" and model_path is not None:
        sha = file_sha256(model_path)
        if meta.get("idm_sha256") != sha:
            raise StaleCacheError(f"{path}: made with another IDM model than {model_path}; re-run `frng idm-priors`")
    meta = dict(meta)
    meta["view_names"] = json.loads(meta["view_names"])
    return IntrinsicPriors.from_dict(tensors), meta
