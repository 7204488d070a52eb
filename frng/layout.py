"""Where every artefact of a results folder lives: one place for the layout, read by the rules and the stages.

Torch-free (the Snakemake rule files import it while planning). Every method returns a ``str`` path under the
results folder; arguments default to Snakemake wildcard patterns (``"{obj}"``, ``"{variant}"``, ...), so a rule
writes ``L.object_meta()`` for ``{results}/objects/{obj}/meta.json`` and a stage ``L.object_meta("obj_0007")``.

::

    {results}/config.yaml                         the effective config (frng.config.record)
    envmaps/index.json, envmaps/{env}.exr         prepared environment maps (rule envmaps)
    objects/{obj}/meta.json, inputs/, targets/, gbuffer/   curated objects (rule curate)
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
"""

from __future__ import annotations

from pathlib import Path


class Layout:
    """The results folder ``root``'s artefact paths (see the module docstring)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def _p(self, *parts: str) -> str:
        return str(self.root.joinpath(*parts))

    # -- configuration and logs ---------------------------------------------------------------------------------
    def config(self) -> str:
        return self._p("config.yaml")

    def log(self, rule: str, obj: str | None = None) -> str:
        """``logs/{rule}.log``, or ``logs/{rule}/{obj}.log`` for per-object jobs."""
        return self._p("logs", rule, f"{obj}.log") if obj is not None else self._p("logs", f"{rule}.log")

    # -- data -----------------------------------------------------------------------------------------------------
    def envmaps_dir(self) -> str:
        return self._p("envmaps")

    def envmap_index(self) -> str:
        return self._p("envmaps", "index.json")

    def envmap(self, env: str = "{env}") -> str:
        return self._p("envmaps", f"{env}.exr")

    def objects_dir(self) -> str:
        return self._p("objects")

    def object_dir(self, obj: str = "{obj}") -> str:
        return self._p("objects", obj)

    def object_meta(self, obj: str = "{obj}") -> str:
        return self._p("objects", obj, "meta.json")

    def object_image(self, obj: str, kind: str, light: str, view: str) -> str:
        """A curated view: kind ``inputs`` or ``targets``."""
        return self._p("objects", obj, kind, light, f"{view}.exr")

    def previews_dir(self) -> str:
        return self._p("previews")

    def preview(self, obj: str = "{obj}") -> str:
        return self._p("previews", f"{obj}.png")

    # -- priors ---------------------------------------------------------------------------------------------------
    def backbone_dir(self) -> str:
        return self._p("backbone")

    def backbone_model(self) -> str:
        return self._p("backbone", "model.pt")

    def backbone_curve(self, ext: str = "csv") -> str:
        """The backbone's loss log (``csv``) or plot (``png``)."""
        return self._p("backbone", f"loss.{ext}")

    def backbone_cache(self, obj: str = "{obj}") -> str:
        return self._p("backbone", "cache", f"{obj}.safetensors")

    def backbone_cache_index(self) -> str:
        return self._p("backbone", "cache", "train_set.json")

    def idm_dir(self) -> str:
        return self._p("idm")

    def idm_model(self) -> str:
        return self._p("idm", "model.pt")

    def idm_curve(self, ext: str = "csv") -> str:
        return self._p("idm", f"loss.{ext}")

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
        return self._p("models", variant, "model.pt")

    def model_curve(self, variant: str = "{variant}", ext: str = "csv") -> str:
        return self._p("models", variant, f"loss.{ext}")

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
        return self._p("relight", run, obj, "run.json")

    def relight_image(self, run: str, obj: str, light: str, view: str) -> str:
        return self._p("relight", run, obj, light, f"{view}.exr")

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
