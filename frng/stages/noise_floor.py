"""Stage ``frng noise-floor`` (rule ``noise_floor``): the curated targets' Monte-Carlo noise floor, the quality
ladder's step 0.

Renders the first ``render.noise_floor.views`` target views of the first test object of each material class, under
its first ``render.noise_floor.lights`` target lights, exactly as curation renders them (the config's ``render.*``:
the dataset's images) and as the mean of two raw, unclamped renders of ``render.noise_floor.reference_spp`` samples
with other seeds, and scores the first against the second with the pipeline's metrics (``eval``): how far the
ground truth the models are scored against is from a noise-free render (:mod:`frng.data.noise_floor`; by hand, with
any settings: ``frng bench targets-noise``). Writes one CSV in the layout of the priors' evaluation
(``metrics/backbone.csv``), which ``frng tables`` adds to the ladder. Torch-free but for LPIPS; runs in Blender's
Python, as ``frng curate``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from frng import io
from frng.data import noise_floor as N
from frng.metrics import EvalConfig  # registers the eval section's class (config_section builds it)
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.plan.sections import config_section

# render.* is what curation renders with (the settings the targets are made with and the rig's views); the plan
# names the test objects, their classes and lights; envmaps.width the maps' light sampling; eval the metrics
CONFIG_READS = ("@plan", "render", "!render.dense_views", "envmaps.width", "eval")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--envmaps", help="prepared env-map folder (default: {results}/envmaps)")
    parser.add_argument("--out", help="the CSV to write (default: {results}/metrics/noise_floor.csv)")


def run(args: argparse.Namespace) -> int:
    config = frng_config.load(args.config)
    render = config_section(config, "render")
    evaluation: EvalConfig = config_section(config, "eval")
    nf = render.noise_floor
    if nf.views < 1:
        print("frng noise-floor: error: render.noise_floor.views is 0 (no noise floor asked for)", file=sys.stderr)
        return 2
    L = Layout(config["results"])
    out = Path(args.out or L.metrics("noise_floor"))
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    import bpy  # noqa: F401

    plan = catalog.plan(config)
    objects = N.default_objects(plan)
    scratch = Path(tempfile.mkdtemp(prefix=".tmp-noise-floor-", dir=out.parent))
    try:
        records = N.render_images(
            plan,
            config_section(config, "objects").objaverse,
            render,
            config_section(config, "envmaps").width,
            Path(args.envmaps or L.envmaps_dir()),
            objects,
            None,
            nf.views,
            nf.lights,
            nf.reference_spp,
            [N.parse_setting(N.TIER, render)],
            scratch,
            False,
            log=lambda m: print(m, flush=True),
        )
    except (FileNotFoundError, dataset_config.CatalogError) as e:
        print(f"frng noise-floor: error: {e}", file=sys.stderr)
        return 1
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    import pandas as pd

    scored = N.score(records, evaluation.protocol, evaluation.background)
    with io.atomic_path(out) as tmp:
        pd.DataFrame(N.ladder_rows(scored)).to_csv(tmp, index=False)
    print(N.summary(scored, render, N.renders_per_object(render)), flush=True)
    print(
        f"frng noise-floor: {len(records)} renders of {len(objects)} objects in {time.perf_counter() - t0:.1f} s -> {out}"
    )
    return 0
