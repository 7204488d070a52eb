"""Where every artefact of a results folder lives: one place for the layout, read by the rules and the stages.

Torch-free (the Snakemake rule files import it while planning). Every method returns a ``str`` path under the
results folder; arguments default to Snakemake wildcard patterns (``"{obj}"``, ``"{variant}"``, ...), so a rule
writes ``L.object_meta()`` for ``{results}/objects/{obj}/meta.json`` and a stage ``L.object_meta("obj_0007")``.

::

    {results}/config.yaml                         the effective config (frng.plan.config.record)
    .digests/{rule}-{digest}.txt                  each rule's config digest, an input of its jobs (rule config_digest)
    .lock                                         held by the snakemake running on the folder (rules/common.smk)
    envmaps/index.json, envmaps/{env}.exr         prepared environment maps (rule envmaps)
    objects/{obj}/meta.json, inputs/, targets/, gbuffer/   curated objects (rule curate)
    baselines/views/{obj}/meta.json, dense/, targets/     the baselines' extra views (rule curate_baselines)
    previews/{obj}.png                            contact sheets (rule dataset_preview)
    backbone/model.pt, loss.csv, loss.png         the frozen backbone (rule backbone_train)
    backbone/cache/{obj}.safetensors, train_set.json    its token caches (rules backbone_cache, training_set_caches)
    idm/model.pt, loss.csv, loss.png             the IDM (rule idm_train)
    priors/idm/{obj}.safetensors, train_set.json  its priors (rules idm_priors, training_set_priors)
    models/{variant}/model.pt, loss.csv, loss.png, train.log   F-RNG variants (rules train, model_alias)
    relight/{run}/{obj}/run.json, {light}/{view}.exr, saliency.npz   relit test objects (rule relight)
    relight/timing/{obj}.json                     relighting timings
    metrics/{name}.csv                            backbone, idm, relight_per_image, relight_summary
    tables/{name}.{csv,md,tex}, figures/...       the paper's tables and figures (rules tables, figures)
    logs/{rule}.log, logs/{rule}/{obj}.log        one log per job

The files inside a folder that a stage may be pointed at elsewhere (``--out``, ``--envmaps``: a staging folder, a
user's folder) are named by the folder classes :class:`EnvmapFolder`, :class:`ObjectFolder`, :class:`TrainingFolder`
and :class:`RelightFolder`; :class:`Layout` places those folders in the results folder and asks them for the names,
so every name is spelled once.
"""

from __future__ import annotations

from pathlib import Path


class _Folder:
    """A folder's files as ``str`` paths (``root`` joined with their names)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def _p(self, *parts: str) -> str:
        return str(self.root.joinpath(*parts))


class EnvmapFolder(_Folder):
    """A prepared env-map folder (``{results}/envmaps``, ``frng curate --envmaps``, the staging folder of
    :func:`frng.data.envmaps.prepare`)."""

    def index(self) -> str:
        return self._p("index.json")

    def envmap(self, env: str = "{env}") -> str:
        return self._p(f"{env}.exr")

    def record(self, env: str = "{env}") -> str:
        """The map's record ``{env}.json`` (as in the index)."""
        return self._p(f"{env}.json")


class ObjectFolder(_Folder):
    """One curated object's folder (``{results}/objects/{obj}``, or the staging folder curation writes)."""

    def meta(self) -> str:
        return self._p("meta.json")

    def image(self, kind: str, light: str, view: str) -> str:
        """A curated view: kind ``inputs`` or ``targets``."""
        return self._p(kind, light, f"{view}.exr")

    def gbuffer(self, view: str) -> str:
        return self._p("gbuffer", f"{view}.exr")


class TrainingFolder(_Folder):
    """What a training run writes into its ``--out`` folder (:func:`frng.training.loop.fit`): the backbone's, the IDM's,
    an F-RNG variant's."""

    def model(self) -> str:
        return self._p("model.pt")

    def checkpoint(self) -> str:
        return self._p("checkpoint.pt")

    def curve(self, ext: str = "csv") -> str:
        """The loss log (``csv``) or plot (``png``)."""
        return self._p(f"loss.{ext}")

    def summary(self) -> str:
        return self._p("train.json")


class RelightFolder(_Folder):
    """One relighting run's folder for one object (``{results}/relight/{run}/{obj}``, or its staging folder)."""

    def record(self) -> str:
        return self._p("run.json")

    def image(self, light: str, view: str) -> str:
        return self._p(light, f"{view}.exr")

    def saliency(self) -> str:
        return self._p("saliency.npz")

    def asset(self) -> str:
        return self._p("asset")


class ImageInputsFolder(_Folder):
    """What ``frng export-image-inputs --out DIR`` writes for image-based methods run elsewhere
    (:mod:`frng.baselines.export_inputs`): ``index.json`` lists the objects, views and lights."""

    def index(self) -> str:
        return self._p("index.json")


class Layout(_Folder):
    """The results folder ``root``'s artefact paths (see the module docstring)."""

    # -- configuration and logs ---------------------------------------------------------------------------------
    def config(self) -> str:
        return self._p("config.yaml")

    def digests_dir(self) -> str:
        return self._p(".digests")

    def rule_digest(self, rule: str = "{rule}", digest: str = "{digest}") -> str:
        """``.digests/{rule}-{digest}.txt``: the record that ``rule``'s jobs run with config digest ``digest``
        (:func:`frng.plan.digests.rule_digest`); every job of the rule reads it, so the digest travels with the folder."""
        return self._p(".digests", f"{rule}-{digest}.txt")

    def curate_record(self, obj: str = "{obj}", digest: str = "{digest}") -> str:
        """``.digests/objects/{obj}-{digest}.json``: what object ``obj``'s curation renders -- its plan entry and
        its maps' plan records (:func:`frng.plan.curate_jobs.curate_record`), ``digest`` their digest; its curation job
        reads it, so a change of them (and only of them) reruns the job, wherever the folder goes."""
        return self._p(".digests", "objects", f"{obj}-{digest}.json")

    def lock(self) -> str:
        """``.lock``: locked (fcntl) by the snakemake process running jobs on this folder."""
        return self._p(".lock")

    def log(self, rule: str, obj: str | None = None) -> str:
        """``logs/{rule}.log``, or ``logs/{rule}/{obj}.log`` for per-object jobs."""
        return self._p("logs", rule, f"{obj}.log") if obj is not None else self._p("logs", f"{rule}.log")

    # -- data -----------------------------------------------------------------------------------------------------
    def envmaps_dir(self) -> str:
        return self._p("envmaps")

    def envmap_index(self) -> str:
        return EnvmapFolder(self.envmaps_dir()).index()

    def envmap(self, env: str = "{env}") -> str:
        return EnvmapFolder(self.envmaps_dir()).envmap(env)

    def objects_dir(self) -> str:
        return self._p("objects")

    def object_dir(self, obj: str = "{obj}") -> str:
        return self._p("objects", obj)

    def object_meta(self, obj: str = "{obj}") -> str:
        return ObjectFolder(self.object_dir(obj)).meta()

    def object_image(self, obj: str, kind: str, light: str, view: str) -> str:
        """A curated view: kind ``inputs`` or ``targets``."""
        return ObjectFolder(self.object_dir(obj)).image(kind, light, view)

    def object_gbuffer(self, obj: str, view: str) -> str:
        return ObjectFolder(self.object_dir(obj)).gbuffer(view)

    def baseline_views_dir(self, obj: str = "{obj}") -> str:
        """The baselines' extra curated views of one object (an :class:`ObjectFolder`: ``meta.json``, the dense views
        ``dense/{light}/{view}.exr`` and the target views under the input light ``targets/{light}/{view}.exr``;
        rule curate_baselines)."""
        return self._p("baselines", "views", obj)

    def baseline_views_meta(self, obj: str = "{obj}") -> str:
        return ObjectFolder(self.baseline_views_dir(obj)).meta()

    def previews_dir(self) -> str:
        return self._p("previews")

    def preview(self, obj: str = "{obj}") -> str:
        return self._p("previews", f"{obj}.png")

    # -- priors ---------------------------------------------------------------------------------------------------
    def backbone_dir(self) -> str:
        return self._p("backbone")

    def backbone_model(self) -> str:
        return TrainingFolder(self.backbone_dir()).model()

    def backbone_curve(self, ext: str = "csv") -> str:
        """The backbone's loss log (``csv``) or plot (``png``)."""
        return TrainingFolder(self.backbone_dir()).curve(ext)

    def backbone_cache(self, obj: str = "{obj}") -> str:
        return self._p("backbone", "cache", f"{obj}.safetensors")

    def backbone_cache_index(self) -> str:
        return self._p("backbone", "cache", "train_set.json")

    def idm_dir(self) -> str:
        return self._p("idm")

    def idm_model(self) -> str:
        return TrainingFolder(self.idm_dir()).model()

    def idm_curve(self, ext: str = "csv") -> str:
        return TrainingFolder(self.idm_dir()).curve(ext)

    def idm_priors(self, obj: str = "{obj}") -> str:
        return self._p("priors", "idm", f"{obj}.safetensors")

    def idm_priors_index(self) -> str:
        return self._p("priors", "idm", "train_set.json")

    # -- F-RNG models ---------------------------------------------------------------------------------------------
    def models_dir(self) -> str:
        return self._p("models")

    def model_dir(self, variant: str = "{variant}") -> str:
        return self._p("models", variant)

    def model(self, variant: str = "{variant}") -> str:
        return TrainingFolder(self.model_dir(variant)).model()

    def model_curve(self, variant: str = "{variant}", ext: str = "csv") -> str:
        return TrainingFolder(self.model_dir(variant)).curve(ext)

    def model_file(self, variant: str, name: str) -> str:
        """Another file of a variant's folder (``train.log``, ``alias.log``, ...)."""
        return self._p("models", variant, name)

    # -- relighting -----------------------------------------------------------------------------------------------
    def relight_dir(self) -> str:
        return self._p("relight")

    def relight_run(self, run: str = "{run}", obj: str = "{obj}") -> str:
        """A run's folder for one object (``run.json``, ``{light}/{view}.exr``, ``saliency.npz``)."""
        return self._p("relight", run, obj)

    def relight_record(self, run: str = "{run}", obj: str = "{obj}") -> str:
        return RelightFolder(self.relight_run(run, obj)).record()

    def relight_image(self, run: str, obj: str, light: str, view: str) -> str:
        return RelightFolder(self.relight_run(run, obj)).image(light, view)

    def relight_saliency(self, run: str = "{run}", obj: str = "{obj}") -> str:
        return RelightFolder(self.relight_run(run, obj)).saliency()

    def relight_timing(self, obj: str = "{obj}") -> str:
        return self._p("relight", "timing", f"{obj}.json")

    # -- reports --------------------------------------------------------------------------------------------------
    def metrics_dir(self) -> str:
        return self._p("metrics")

    def metrics(self, name: str) -> str:
        """``metrics/{name}.csv``: backbone, idm, relight_per_image, relight_summary."""
        return self._p("metrics", f"{name}.csv")

    def tables_dir(self) -> str:
        return self._p("tables")

    def table(self, name: str, ext: str = "csv") -> str:
        return self._p("tables", f"{name}.{ext}")

    def figures_dir(self) -> str:
        return self._p("figures")

    def figure(self, name: str) -> str:
        """``figures/{name}`` (a file such as ``ablation.png`` or a folder such as ``comparison``)."""
        return self._p("figures", name)
