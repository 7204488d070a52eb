"""What gets trained and what gets relit: the F-RNG variants and the relighting runs a config implies.

Torch-free on purpose: the Snakemake rule files import this while planning the DAG (importing torch there costs
about a second of every ``snakemake`` call, dry runs included).

Variants (``{results}/models/{variant}/``): ``frng.variants`` (``full`` and the ablations of :data:`BASE_VARIANTS`)
then the K sweep ``k{P}`` (``frng.k_sweep``, P in % of a view's patches). The K-sweep entry equal to
``frng.top_k_percent`` is the full model itself (``k2`` with the paper's 2%): it is not trained twice.

Training seeds (``train.seeds``): the plain variant names are trained with the models' seed (``train_seed``, else
``seed``); every other seed in ``train.seeds`` trains ``full`` and each ablation of ``frng.variants`` once more as
``{variant}@s{seed}`` (:func:`seed_variant`; ``train_seed`` = that seed, everything else equal). The K sweep and the
#views sweep are not repeated per seed.

Runs (``{results}/relight/{run}/{obj}/``, :func:`runs`): every variant at the 6-view rig (and its other training
seeds), the K sweep, the #views sweep ``full-v{V}`` (the full model fed V input views), ``full-oracle`` (the full
model fed the test object's rendered G-buffers instead of the IDM's priors: how much a perfect IDM would add),
``plus-base`` (F-RNG+'s closed-form Lambertian base alone, the decoder's residual, attenuation and specular
base dropped; only with ``shading.decoder_cosine``), ``plus-known-light`` (oracle: F-RNG+ told the input views' light,
which the paper's task does not give; every other run estimates it or does not read it) and the ``backbone``
baseline.

Relighting groups (:func:`run_groups`, one ``relight`` job per group and test object): ``main`` holds every run of
the models' seed and the backbone (and the timing); each other training seed ``S`` is its own group ``"S"`` (its
``{variant}@s{S}`` runs), so that those runs relight as soon as that seed's models exist instead of waiting for
every model; ``all`` selects every run (``frng relight`` without ``--group``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from frng.plan.sections import TypedConfig, as_dict


@dataclass(frozen=True)
class Variant:
    """One F-RNG variant: what the paper's ablation table calls it and how it differs from the full model.

    arch: FRNGConfig fields replaced (:func:`frng.training.frng_trainer.variant_config`); loss: LightIndependenceConfig fields
    replaced; reads_priors: whether its reconstruction reads the IDM's priors (the ``train`` rule of a variant that
    does not never waits for them)."""

    label: str
    arch: dict = field(default_factory=dict)
    loss: dict = field(default_factory=dict)
    additions: bool = False  # True: the project's additions (:data:`ADDITIONS`) stay on (F-RNG+); False: paper form

    @property
    def reads_priors(self) -> bool:
        return self.arch.get("prior_dim", 1) != 0


@dataclass(frozen=True)
class Addition:
    """One of the project's departures from the paper's F-RNG, kept as a named switch: the config key that turns it
    on (its settings live under that key), the paper section it departs from, and the FRNGConfig fields (``arch``)
    and LightIndependenceConfig fields (``loss``) that give the paper form instead."""

    key: str
    departs_from: str
    arch: dict = field(default_factory=dict)
    loss: dict = field(default_factory=dict)


# The project's additions (F-RNG+, variant ``plus``): every other variant is the paper's form, these switched off.
# Each is measured as an addition over the paper form (docs/model-and-training.md "Paper form and F-RNG+").
ADDITIONS: dict[str, Addition] = {
    "pixel_head": Addition(
        "frng.pixel_head",
        "Sec. 4.2.1 (MatDetokenizer: one linear layer from T_mat): every Gaussian also reads its input pixel (colour, "
        "alpha, the IDM's priors) and starts at the Lambertian relighting c / E(n) of its photo, with E the input "
        "light estimated from the photos",
        arch={
            "pixel_head": 0,
            "opacity_head": False,
            "geometry_inputs": False,
            "depth_head": 0.0,
            "specular_start": False,
        },
    ),
    "decoder_bases": Addition(
        "shading.decoder_cosine (+ decoder_attenuation, decoder_specular)",
        "Sec. 4.3 (rho = Theta(f | w_o, w_i), an MLP): a closed-form Lambertian base and a GGX lobe beside the MLP",
        arch={"decoder_cosine": False, "decoder_attenuation": False, "decoder_specular": False},
    ),
    "coverage_head": Addition(
        "frng.coverage_head",
        "Sec. 4.3 (deferred shading of the rasterized features): a silhouette-rim coverage CNN",
        arch={"coverage_head": 0},
    ),
    "back_completion": Addition(
        "frng.back_completion",
        "Sec. 4.1 (the backbone's per-pixel Gaussians): copies on the hull's unseen far side",
        arch={"back_completion": False},
    ),
    "fine_in_hull": Addition(
        "frng.fine_in_hull",
        "Sec. 4.1 (FineGeoDetokenizer): fine Gaussians outside a silhouette dropped",
        arch={"fine_in_hull": False},
    ),
    "normal_start": Addition(
        "frng.normal_start",
        "Sec. 4.2.1 (MatDetokenizer: one linear layer from T_mat): every Gaussian's feature also gets its input "
        "pixel's normal in a fixed random projection, so the decoder Theta sees the orientation from the start",
        arch={"normal_start": 0.0},
    ),
    "ind_pixels": Addition(
        "train.loss.ind_pixels",
        "Sec. 4.2.2 (L_ind on T_mat): also on the per-Gaussian material, from the views under a second input light",
        loss={"pixels": False},
    ),
}


def paper_form() -> tuple[dict, dict]:
    """(FRNGConfig fields, LightIndependenceConfig fields) that switch every addition off: the paper's F-RNG."""
    arch, loss = {}, {}
    for a in ADDITIONS.values():
        arch.update(a.arch)
        loss.update(a.loss)
    return arch, loss


PLUS = "plus"  # F-RNG+: the paper form with the project's additions on
PLUS_METHOD = "F-RNG+"  # its key in a relighting job's timing record (beside "F-RNG" and "backbone")
LEAVE_OUT_PREFIX = "plus-no-"  # plus-no-{addition}: F-RNG+ with that one addition off (the additions table)


def leave_out_variant(addition: str) -> str:
    """Name of F-RNG+ without one addition of :data:`ADDITIONS` (``pixel_head`` -> ``plus-no-pixel-head``)."""
    return LEAVE_OUT_PREFIX + addition.replace("_", "-")


# The one table of the variants (the schema's frng.variants enum is checked against it by a test): the paper's full
# model and its ablations (Table 4), all in the paper's form, F-RNG+, and F-RNG+ without each addition (what that
# addition is worth: the additions table; trained when frng.variants lists them).
VARIANTS: dict[str, Variant] = {
    "full": Variant("full model"),
    "no-fine": Variant("w/o fine-grained Gaussians", arch={"fine": False}),
    "no-idm": Variant("w/o IDM priors", arch={"prior_dim": 0}),
    "no-ind": Variant("w/o light-independence regularization", loss={"lambda_c": 0.0, "lambda_kld": 0.0}),
    "no-neural": Variant("w/o neural appearance modeling", arch={"head": "pbr"}),
    PLUS: Variant("F-RNG+ (the project's additions)", additions=True),
    **{
        leave_out_variant(key): Variant(f"F-RNG+ without {key}", arch=a.arch, loss=a.loss, additions=True)
        for key, a in ADDITIONS.items()
    },
}
LEAVE_OUT_VARIANTS = {leave_out_variant(key): key for key in ADDITIONS}  # variant -> the addition it leaves out
BASE_VARIANTS = tuple(v for v in VARIANTS if v not in LEAVE_OUT_VARIANTS)  # the default frng.variants
ABLATION_VARIANTS = tuple(v for v in VARIANTS if not VARIANTS[v].additions)  # full and the paper's ablations
RIG_VIEWS = 6  # the paper's input rig
SWEEP_VIEWS = (2, 4, 6, 8, 10)  # the #views table
BACKBONE = "backbone"
ORACLE_RUN = "full-oracle"  # the full model fed the G-buffers instead of the IDM's priors (quality ladder row f)
BASE_RUN = "plus-base"  # F-RNG+'s Lambertian base alone (decoder residual, attenuation, specular base dropped)
KNOWN_LIGHT_RUN = "plus-known-light"  # oracle: F-RNG+ told the input views' light (the paper's task does not give it)
# the runs that keep their relightable asset (relight/{run}/{obj}/asset): the paper's full model and F-RNG+, the one
# `frng view --object` shows (it relights photos best under the paper's task: docs/model-and-training.md)
ASSET_RUNS = ("full", PLUS)
VIEW_RUN = PLUS
# What F-RNG's coarse Gaussians sit on (frng.training.frng_trainer.load_objects): the backbone's geometry, or, diagnostics
# (`frng train` / `frng bench heldout --geometry ...`), the input pixels' G-buffer surface distances, their visual
# hull's, or the hull refined by multi-view stereo (frng.priors.stereo)
GEOMETRIES = ("backbone", "gbuffer", "hull", "stereo")
SEED_SEP = "@s"  # {variant}@s{seed}: a variant trained with another training seed
MAIN_GROUP = "main"  # the relighting group of the models' seed runs and the backbone (timing included)
ALL_GROUPS = "all"  # every run of a test object


def seed_variant(name: str, seed: int) -> str:
    """Name of variant ``name`` trained with training seed ``seed`` (``full``, 1 -> ``full@s1``)."""
    return f"{name}{SEED_SEP}{int(seed)}"


def split_seed(name: str) -> tuple[str, int | None]:
    """(variant, seed) of a name: ``full@s1`` -> ("full", 1), ``full`` -> ("full", None) (the models' seed)."""
    base, sep, seed = name.partition(SEED_SEP)
    if not sep:
        return name, None
    if not seed.isdigit():
        raise ValueError(f"variant {name!r}: the training seed after {SEED_SEP!r} must be a non-negative integer")
    return base, int(seed)


def model_seed(config: TypedConfig | Mapping) -> int:
    """The models' seed (``train_seed``, else ``seed``), as :attr:`frng.typedconfig.Config.model_seed`, from the dict."""
    c = as_dict(config)
    return int(c["seed"] if c.get("train_seed") is None else c["train_seed"])


def extra_seeds(config: TypedConfig | Mapping) -> list[int]:
    """The seeds of ``train.seeds`` other than the models' seed (each adds ``{variant}@s{seed}`` models)."""
    own = model_seed(config)
    return [int(s) for s in dict.fromkeys(as_dict(config)["train"].get("seeds", [])) if int(s) != own]


def full_and(variants) -> list[str]:
    """``full`` then the ablations ``variants`` (``frng.variants``), duplicates dropped."""
    return list(dict.fromkeys(["full", *variants]))


def seeded_bases(config: TypedConfig | Mapping) -> list[str]:
    """The variants trained once more per other training seed: ``full`` and every ablation of ``frng.variants``."""
    return full_and(as_dict(config)["frng"]["variants"])


def seeded_variants(config: TypedConfig | Mapping) -> list[str]:
    """``{variant}@s{seed}`` for every :func:`seeded_bases` entry, per :func:`extra_seeds`."""
    return [seed_variant(v, s) for s in extra_seeds(config) for v in seeded_bases(config)]


def k_variant(percent: float) -> str:
    """Name of the K-sweep variant for K = ``percent`` % (1 -> "k1", 0.5 -> "k0.5")."""
    return f"k{percent:g}"


def all_variants(config: TypedConfig | Mapping) -> list[str]:
    """Every variant the config asks for: ``frng.variants``, the K sweep (``frng.k_sweep``, percent), then the other
    training seeds (:func:`seeded_variants`)."""
    f = as_dict(config)["frng"]
    out = list(f["variants"])
    out += [k_variant(p) for p in f["k_sweep"] if k_variant(p) not in out]
    out += [v for v in seeded_variants(config) if v not in out]
    return out


def k_percent(name: str) -> float | None:
    """K in percent of a K-sweep variant name (``k2`` -> 2.0), None for other names; ValueError for a ``k`` name
    whose K is not a number in (0, 100]. A training-seed suffix (``k2@s1``) is ignored."""
    name = split_seed(name)[0]
    if name in VARIANTS or not name.startswith("k"):
        return None
    try:
        pct = float(name[1:])
    except ValueError:
        raise ValueError(f"unknown F-RNG variant {name!r}; known: {', '.join(BASE_VARIANTS)}, k<percent>") from None
    if not (0 < pct <= 100) or not math.isfinite(pct):
        raise ValueError(f"K-sweep variant {name!r}: K must be in (0, 100] percent")
    return pct


def variant(name: str) -> Variant:
    """The table entry of ``name`` (a K-sweep name ``k{P}`` is the full model with K = P %: arch top_k; a
    training-seed suffix ``@s{seed}`` does not change it)."""
    name = split_seed(name)[0]
    if name in VARIANTS:
        return VARIANTS[name]
    pct = k_percent(name)
    if pct is None:
        raise ValueError(f"unknown F-RNG variant {name!r}; known: {', '.join(BASE_VARIANTS)}, k<percent>")
    return Variant(f"K = {pct:g}%", arch={"top_k": pct / 100.0})


def reads_priors(name: str) -> bool:
    """Whether variant ``name``'s reconstruction reads the IDM's priors."""
    return variant(name).reads_priors


def canonical_variant(config: TypedConfig | Mapping, name: str) -> str:
    """The variant whose training produces ``name``'s model under the config's ``frng.top_k_percent``
    (:func:`canonical_for`)."""
    return canonical_for(name, float(as_dict(config)["frng"]["top_k_percent"]))


def canonical_for(name: str, top_k_percent: float) -> str:
    """The variant whose training produces ``name``'s model when the full model's K is ``top_k_percent``: the K-sweep
    entry equal to it is the full model itself (``k2`` -> ``full`` with the paper's K = 2%), so it is not trained
    twice. A training-seed suffix is kept (``k2@s1`` -> ``full@s1``)."""
    base, seed = split_seed(name)
    pct = k_percent(base)
    if pct is not None and pct == float(top_k_percent):
        return "full" if seed is None else seed_variant("full", seed)
    return name


def trained_variants(config: TypedConfig | Mapping) -> list[str]:
    """The variants that get a ``train`` job (aliases resolved, order kept, duplicates dropped)."""
    return list(dict.fromkeys(canonical_variant(config, v) for v in all_variants(config)))


def view_counts(split: str, n_views: int) -> list[int]:
    """Input-view counts cached/relit for an object of ``split`` with ``n_views`` input views: the rig for training
    objects, every :data:`SWEEP_VIEWS` entry the object has for test objects."""
    vs = [RIG_VIEWS] if split == "train" else [v for v in SWEEP_VIEWS if v <= n_views]
    return sorted(set(v for v in vs if v <= n_views))


@dataclass(frozen=True)
class Run:
    """One set of relit images of a test object: ``name`` is its folder under ``{results}/relight/``."""

    name: str
    method: str  # "F-RNG" or "backbone"
    variant: str  # model variant (folder under results/models/), "backbone" for the baseline
    views: int  # input views fed to the reconstruction
    k_percent: float  # K of the model (NaN for the backbone)
    priors: str = "idm"  # "idm" (the configured IDM) or "oracle" (the rendered G-buffers: the quality ladder's (f))
    seed: int | None = None  # training seed of the model (None: the models' seed, train_seed else seed)
    decoder: str = "full"  # "full", or "base": the cosine decoder's Lambertian base alone (residual dropped)
    light: str = "estimated"  # the input views' light: "estimated" (the paper's task), or "known" (oracle: told it)

    @property
    def group(self) -> str:
        """Its relighting group: :data:`MAIN_GROUP` for the models' seed and the backbone, else ``str(seed)``."""
        return MAIN_GROUP if self.seed is None else str(self.seed)


@dataclass(frozen=True)
class RunPlan:
    """What the runs of a test object follow from (:meth:`runs`): the ``frng`` keys ``variants``, ``k_sweep``,
    ``top_k_percent`` and ``prior_dim``, ``idm.kind``, ``shading.decoder_cosine``, the other training seeds
    (:func:`extra_seeds`) and ``render.extra_input_views``. :meth:`of` reads them from a config; a stage hands a
    library this instead of the config."""

    variants: tuple[str, ...]
    k_sweep: tuple[float, ...]
    top_k_percent: float
    prior_dim: int
    idm_kind: str
    decoder_cosine: bool
    extra_seeds: tuple[int, ...]
    extra_input_views: int

    @classmethod
    def of(cls, config: TypedConfig | Mapping) -> RunPlan:
        c = as_dict(config)
        f = c["frng"]
        return cls(
            variants=tuple(f["variants"]),
            k_sweep=tuple(f["k_sweep"]),
            top_k_percent=float(f["top_k_percent"]),
            prior_dim=int(f.get("prior_dim", 1)),
            idm_kind=c["idm"]["kind"],
            decoder_cosine=bool(c.get("shading", {}).get("decoder_cosine", False)),
            extra_seeds=tuple(extra_seeds(c)),
            extra_input_views=int(c.get("render", {}).get("extra_input_views", 0)),
        )

    def runs(self, n_input_views: int | None = None, group: str = ALL_GROUPS) -> list[Run]:
        """All runs of one test object (``n_input_views`` None: the views the config gives every test object), or
        those of relighting group ``group`` (:meth:`groups`; :data:`ALL_GROUPS`: every run).

        ``frng.variants`` at 6 views, the K sweep ``frng.k_sweep`` (the entry equal to ``frng.top_k_percent`` is the
        full run itself), the #views sweep ``full-v{V}``, the oracle-prior run, the other training seeds of ``full``
        and the ablations (:func:`seeded_variants`), F-RNG+'s Lambertian-base and known-light runs (with ``plus``)
        and the backbone."""
        if n_input_views is None:
            n_input_views = RIG_VIEWS + self.extra_input_views
        k_full = self.top_k_percent
        out = [Run(v, "F-RNG", v, RIG_VIEWS, k_full) for v in full_and(self.variants)]
        for p in self.k_sweep:
            name = k_variant(p)
            if canonical_for(name, k_full) != "full":
                out.append(Run(name, "F-RNG", name, RIG_VIEWS, float(p)))
        out += [
            Run(f"full-v{V}", "F-RNG", "full", V, k_full) for V in view_counts("test", n_input_views) if V != RIG_VIEWS
        ]
        if self.idm_kind != "oracle" and self.prior_dim > 0:
            out.append(Run(ORACLE_RUN, "F-RNG", "full", RIG_VIEWS, k_full, priors="oracle"))
        seeded = [seed_variant(v, s) for s in self.extra_seeds for v in full_and(self.variants)]
        for name in seeded:
            out.append(Run(name, "F-RNG", name, RIG_VIEWS, k_full, seed=split_seed(name)[1]))
        if PLUS in self.variants:
            if self.decoder_cosine:
                out.append(Run(BASE_RUN, "F-RNG", PLUS, RIG_VIEWS, k_full, decoder="base"))
            out.append(Run(KNOWN_LIGHT_RUN, "F-RNG", PLUS, RIG_VIEWS, k_full, light="known"))
        out.append(Run(BACKBONE, "backbone", BACKBONE, RIG_VIEWS, float("nan")))
        if group == ALL_GROUPS:
            return out
        if group not in self.groups():
            raise ValueError(f"unknown relighting group {group!r}; this config has {', '.join(self.groups())}")
        return [r for r in out if r.group == group]

    def groups(self) -> list[str]:
        """The relighting groups: :data:`MAIN_GROUP`, then one per other training seed (``"1"``, ...)."""
        return [MAIN_GROUP, *(str(s) for s in self.extra_seeds)]

    def model_variants(self, group: str = ALL_GROUPS) -> list[str]:
        """The trained variants (``{results}/models/{variant}/model.pt``) the runs (of ``group``) read."""
        return list(dict.fromkeys(r.variant for r in self.runs(group=group) if r.method != BACKBONE))


def runs(config: TypedConfig | Mapping, n_input_views: int | None = None) -> list[Run]:
    """All runs of one test object under the config (:meth:`RunPlan.runs`)."""
    return RunPlan.of(config).runs(n_input_views)


def model_variants(config: TypedConfig | Mapping, group: str = ALL_GROUPS) -> list[str]:
    """The trained variants (``{results}/models/{variant}/model.pt``) the runs (of relighting group ``group``) read
    (:meth:`RunPlan.model_variants`)."""
    return RunPlan.of(config).model_variants(group)


def run_groups(config: TypedConfig | Mapping) -> list[str]:
    """The relighting groups of the config (:meth:`RunPlan.groups`)."""
    return RunPlan.of(config).groups()


def torchrun_command(nproc: int, module: str = "frng", python: str | None = None) -> str:
    """Shell prefix a rule uses to start ``nproc`` training processes on one node (plain python for 1).

    ``python -m torch.distributed.run`` is torchrun run by the given interpreter (the rule's ``PY``)."""
    import shlex
    import sys

    py = shlex.quote(python or sys.executable)
    if nproc <= 1:
        return f"{py} -m {module}"
    return f"{py} -m torch.distributed.run --standalone --nnodes=1 --nproc-per-node={int(nproc)} -m {module}"
