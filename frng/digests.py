"""What each rule reads: the config digests that rerun it.

Every rule of the workflow declares ``params: config_digest=digests.rule_digest(config, "<rule>")``: a digest of
exactly the config keys its stage reads (:data:`RULE_CONFIG_KEYS`). Snakemake's ``params`` rerun trigger then reruns a
rule whose keys were edited, and its downstream rules because their inputs are rebuilt; the other rules stay. Digests
read the validated config mapping (no typed sections, no torch: the rule files call this while planning).
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

from frng import io
from frng.config import OVERWRITE_SWITCH
from frng.sections import ConfigError, load_schema

# A key is a dotted path (a whole section or one leaf); ``"!section.key"`` removes a part of a section listed before
# it. Missing keys digest as null. ``results`` and the overwrite switch are never part of a digest.
#
# The lists follow what each stage's entry point reads (``config[...]``, ``X.from_config(config)``, helpers
# included). A key a stage reads but its list lacks leaves stale results; a key listed needlessly only costs an
# extra rerun. Sections an upstream rule already covers may be listed whole downstream at no cost (editing them
# reruns the upstream rule, hence this one).

PLAN_KEYS: tuple[str, ...] = ("seed", "objects", "envmaps", "render.input_lights", "render.target_lights")
"""What the dataset plan reads (frng/data/catalog.py ``plan``): env maps and their split, objects, their split,
materials and lights. Every stage that asks the plan for a split or the object list reads these."""

ENVMAP_PLAN_KEYS: tuple[str, ...] = ("seed", "envmaps")
"""What the env-map plan reads (frng/data/catalog.py ``envmap_plan``)."""

# idm.* keys only the diffusion-renderer IDM reads (frng/priors/__init__.py), plus idm.kind: not the learned IDM's
# architecture or training
_IDM_NOT_TRAINED = ("!idm.kind", "!idm.diffusion_renderer_dir", "!idm.normal_space", "!idm.depth_invert")

# frng/relight.py: the runs (frng.*, idm.kind, render.extra_input_views, train.seeds), resolution check, build_idm,
# shading.spp_infer + inference shading, seeds, device; RELIGHT_KEYS adds the split check's dataset plan. The rule
# `relight` relights the main group only (frng.variants.MAIN_GROUP: the models' seed and the backbone), whose runs do
# not depend on the other training seeds: it leaves train.seeds out, so that `make seeds` (train.seeds [0] -> [0, 1])
# adds the relight_seed jobs without rerunning the first seed's 21 relight jobs (their outputs were identical).
RELIGHT_MODEL_KEYS: tuple[str, ...] = (
    "device",
    "render.resolution",
    "render.extra_input_views",
    "idm",
    "!idm.train",
    "backbone.near",
    "backbone.far",
    "shading",
    "frng",
    "train.seeds",
    "train_seed",
)
RELIGHT_KEYS: tuple[str, ...] = (*PLAN_KEYS, *RELIGHT_MODEL_KEYS)
RELIGHT_MAIN_KEYS: tuple[str, ...] = tuple(k for k in RELIGHT_KEYS if k != "train.seeds")

RULE_CONFIG_KEYS: dict[str, tuple[str, ...]] = {
    # frng/data/envmaps.py: the env-map plan, envmaps.width/normalize, Blender threads of the sky bakes
    "envmaps": (*ENVMAP_PLAN_KEYS, "render.threads"),
    # frng/data/curate.py: render.* (rig, Cycles, fur) and envmaps.width; the object's own plan entry (its split,
    # mesh, material, seed and lights) is the rule's `spec` param, so adding an object reruns no other curation
    "curate": ("render", "!render.dense_views", "envmaps.width"),
    # frng/baselines/curate.py: the object's curation settings (render.*, envmaps.width), the plan (its lights,
    # split, material; which test objects get dense views: baselines.objects_per_class)
    "curate_baselines": (*PLAN_KEYS, "render", "envmaps.width", "baselines.objects_per_class"),
    # frng/baselines/perscene.py (frng baseline-fit): the object's views and lights (plan), the fit's budget and
    # schedule, the rasterizer and shading, seeds, device
    "baseline_fit": (*PLAN_KEYS, "train_seed", "device", "render", "baselines.fit", "raster", "shading"),
    # frng/baselines/image_based.py: the IDM (registry: idm.*, backbone.near/far), the shading, seeds, device
    "baseline_image": (*PLAN_KEYS, "train_seed", "device", "idm", "backbone.near", "backbone.far", "shading"),
    # frng/stages/baseline_frng_nvs.py: what frng relight reads
    "baseline_frng_nvs": RELIGHT_MAIN_KEYS,
    # frng/baselines/scoring.py: the runs planned (dense views, baselines.*), the protocol
    "baseline_eval": (*PLAN_KEYS, "eval", "render.dense_views", "baselines", "benchmarks"),
    # frng/report/baseline_tables.py: captions (tier), compositing (eval.background), the runs' images for figures
    "baseline_tables": (*PLAN_KEYS, "tier", "eval", "render.dense_views", "baselines", "benchmarks"),
    # frng/data/preview.py: the plan's object ids
    "dataset_preview": PLAN_KEYS,
    # frng/priors/backbone_train.py: the training split, architecture + backbone.train, patch size, the models'
    # seed (frng.training.train_seed: train_seed, else seed), device
    "backbone_train": (
        *PLAN_KEYS,
        "train_seed",
        "device",
        "backbone",
        "!backbone.cache_extra_lights",
        "model.patch_size",
    ),
    # frng/priors/idm_train.py: the training split, the learned IDM's architecture + idm.train, near/far, patch
    # size, the models' seed, device
    "idm_train": (
        *PLAN_KEYS,
        "train_seed",
        "device",
        "idm",
        *_IDM_NOT_TRAINED,
        "model.patch_size",
        "backbone.near",
        "backbone.far",
    ),
    # frng/priors/cache.py (backbone model from its file): extra training lights from the env-map plan, DDIM seeds
    "backbone_cache": (*ENVMAP_PLAN_KEYS, "device", "backbone.cache_extra_lights"),
    # frng/priors/cache.py + build_idm (learned IDM from its file): idm.kind and the diffusion-renderer settings
    "idm_priors": ("device", "idm", "!idm.train", "backbone.near", "backbone.far"),
    # frng/priors/evaluate.py: both splits, build_idm, seeds (backbone model from its file)
    "eval_backbone": (*PLAN_KEYS, "device", "idm", "!idm.train", "backbone.near", "backbone.far"),
    # rules/train.smk: indexes of the training split's files
    "training_set_caches": PLAN_KEYS,
    "training_set_priors": PLAN_KEYS,
    # frng/model/train.py + variant_config: train.*, the architecture (frng.* but the variant lists), decoder and
    # training shading (not the inference-only spp_infer / bf16_infer: relight takes those from the config),
    # rasterizer, idm.kind (which priors file), the training split, the models' seed, device
    "train": (
        *PLAN_KEYS,
        "train_seed",
        "device",
        "train",
        "!train.seeds",
        "frng",
        "!frng.variants",
        "!frng.k_sweep",
        "model.patch_size",
        "shading",
        "!shading.spp_infer",
        "!shading.bf16_infer",
        "raster",
        "idm.kind",
    ),
    # a copy of the full model: which K-sweep entry is the full model
    "model_alias": ("frng.top_k_percent",),
    "relight": RELIGHT_MAIN_KEYS,
    # the other training seeds' runs (rules/relight.smk): what `relight` reads
    "relight_seed": RELIGHT_KEYS,
    # frng/stages/evaluate.py: eval.protocol/background and the planned runs (frng/variants.py: the variants, the
    # training seeds, whether the Lambertian-base run exists)
    "evaluate": (
        "eval",
        "frng",
        "idm.kind",
        "render.extra_input_views",
        "train.seeds",
        "train_seed",
        "seed",
        "shading.decoder_cosine",
    ),
    # frng/report/paper_tables.py: tier and eval.background in the captions
    "tables": ("tier", "eval"),
    # frng/report/paper_figures.py: patch size (saliency), the ablation variants
    "figures": ("model.patch_size", "frng.variants"),
    # frng/benchmarks (rules/benchmarks.smk): the import converts to the resolution, map width and input-view count;
    # relighting an imported object reads what `relight` reads; the benchmark table reads the runs and eval
    "import_benchmark": ("benchmarks", "render.resolution", "render.extra_input_views", "envmaps.width"),
    "relight_benchmark": (*RELIGHT_MODEL_KEYS, "seed"),
    "evaluate_benchmarks": ("benchmarks", "eval", "tier"),
}
"""Rule name -> the config keys its stage reads (see the comment above)."""

RULES_WITHOUT_DIGEST = frozenset({"all", "config_digest"})
"""Rules that run no stage (``config_digest`` records the others' digests in the results folder)."""

_NEVER_DIGESTED = ("results", OVERWRITE_SWITCH)


def _lookup(config: Any, dotted: str) -> Any:
    node = config
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def config_digest(config: dict, keys, length: int = 16) -> str:
    """A short stable digest (sha256 of canonical JSON, ``length`` hex digits) of the config ``keys``: dotted keys
    or sections, each ``"!key"`` removing a part of a section listed. Key order does not matter; a missing key
    digests as null."""
    keys = list(keys)
    include = sorted({k for k in keys if not k.startswith("!")})
    selected = {k: copy.deepcopy(_lookup(config, k)) for k in include}
    for ex in sorted({k[1:] for k in keys if k.startswith("!")}):
        owners = [k for k in include if ex.startswith(k + ".")]
        if not owners:
            raise ValueError(f"config digest: '!{ex}' removes a key no listed section contains")
        for k in owners:
            node, *rest = selected[k], *ex[len(k) + 1 :].split(".")
            for part in rest[:-1]:
                node = node.get(part) if isinstance(node, dict) else None
            if isinstance(node, dict):
                node.pop(rest[-1], None)
    text = json.dumps(selected, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def rule_digest(config: dict, rule: str) -> str:
    """The digest of the config keys rule ``rule`` reads (:data:`RULE_CONFIG_KEYS`): its ``config_digest`` param."""
    if rule not in RULE_CONFIG_KEYS:
        raise ConfigError(f"rule {rule!r} has no entry in frng.digests.RULE_CONFIG_KEYS (the config keys it reads)")
    return config_digest(config, RULE_CONFIG_KEYS[rule])


def write_rule_digest(config: dict, rule: str, path: str | os.PathLike, log: str | os.PathLike | None = None) -> Path:
    """Write ``path`` (``{results}/.digests/{rule}-{digest}.txt``, :meth:`frng.layout.Layout.rule_digest`): the keys
    rule ``rule`` reads, their values and digest; and remove the rule's other digest files, so that going back to
    an earlier config finds its file missing again (and reruns the rule). ``log``: where to say so."""
    path = Path(path)
    digest = rule_digest(config, rule)
    if path.name != f"{rule}-{digest}.txt":
        raise ConfigError(f"{path}: not the digest file of rule {rule} for this config ({rule}-{digest}.txt)")
    keys = RULE_CONFIG_KEYS[rule]
    io.write_json(
        path,
        {
            "rule": rule,
            "digest": digest,
            "keys": list(keys),
            "values": {k: _lookup(config, k) for k in keys if not k.startswith("!")},
        },
    )
    for other in path.parent.glob(f"{rule}-*.txt"):
        if other != path and re.fullmatch(rf"{re.escape(rule)}-[0-9a-f]+\.txt", other.name):
            other.unlink(missing_ok=True)
    if log is not None:
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        Path(log).write_text(f"recorded {path}\n")
    return path


def remove_stale_digests(config: dict, folder: str | os.PathLike) -> list[Path]:
    """Remove the digest files ``{folder}/{rule}-{digest}.txt`` of other configs (a run that touched its jobs,
    ``--touch``, leaves them): called when jobs start, never while planning. Returns the files removed."""
    current = {f"{rule}-{rule_digest(config, rule)}.txt" for rule in RULE_CONFIG_KEYS}
    folder = Path(folder)
    removed = []
    if folder.is_dir():
        for f in sorted(folder.iterdir()):
            m = re.fullmatch(r"([a-z][a-z0-9_]*)-[0-9a-f]+\.txt", f.name)
            if m and m.group(1) in RULE_CONFIG_KEYS and f.name not in current:
                f.unlink(missing_ok=True)
                removed.append(f)
    return removed


def check_rule_digests(config: dict, declared: dict[str, Any]) -> None:
    """``declared``: rule name -> its ``config_digest`` param (None when it has none). Raises :class:`ConfigError`
    naming every rule without the right digest, and every map entry naming no rule."""
    problems = []
    for rule, value in sorted(declared.items()):
        if rule in RULES_WITHOUT_DIGEST:
            continue
        if rule not in RULE_CONFIG_KEYS:
            problems.append(f"rule {rule}: not in RULE_CONFIG_KEYS")
        elif value != rule_digest(config, rule):
            problems.append(
                f'rule {rule}: needs `params: config_digest=frng_digests.rule_digest(config, "{rule}")` (`**digest_params("{rule}")`)'
            )
    problems += [f"RULE_CONFIG_KEYS[{r!r}]: no such rule" for r in sorted(set(RULE_CONFIG_KEYS) - set(declared))]
    if problems:
        raise ConfigError("config digests: " + "; ".join(problems))


def _schema_leaves(node: dict, prefix: str = "") -> list[str]:
    out = []
    for name, sub in (node.get("properties") or {}).items():
        if isinstance(sub, dict) and sub.get("properties"):
            out += _schema_leaves(sub, f"{prefix}{name}.")
        else:
            out.append(f"{prefix}{name}")
    return out


def undigested_keys(schema: dict | None = None) -> list[str]:
    """Config keys of the schema that no rule's digest covers (besides ``results`` and the overwrite switch): a key
    added to the schema must be added to :data:`RULE_CONFIG_KEYS` for every rule whose stage reads it."""
    schema = schema if schema is not None else load_schema()

    def within(key: str, section: str) -> bool:
        return key == section or key.startswith(section + ".")

    def covers(keys, leaf: str) -> bool:
        return any(within(leaf, k) for k in keys if not k.startswith("!")) and not any(
            within(leaf, k[1:]) for k in keys if k.startswith("!")
        )

    return [
        leaf
        for leaf in _schema_leaves(schema)
        if leaf.split(".")[0] not in _NEVER_DIGESTED
        and not any(covers(keys, leaf) for keys in RULE_CONFIG_KEYS.values())
    ]


def unknown_digest_keys(schema: dict | None = None) -> list[str]:
    """Keys of :data:`RULE_CONFIG_KEYS` that name no config key of the schema (a typo would digest as null for
    ever), plus any that must never be digested (``results``, the overwrite switch)."""
    schema = schema if schema is not None else load_schema()
    bad = []
    for rule, keys in RULE_CONFIG_KEYS.items():
        for key in keys:
            node: Any = schema
            for part in key.lstrip("!").split("."):
                node = (node or {}).get("properties", {}).get(part)
            if node is None or key.lstrip("!").split(".")[0] in _NEVER_DIGESTED:
                bad.append(f"{rule}: {key}")
    return bad
