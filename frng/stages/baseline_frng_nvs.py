"""Stage ``frng baseline-frng-nvs --object OBJ [--out DIR]`` (rule ``baseline_frng_nvs``): F-RNG's novel-view synthesis
for the views table -- the ``full`` model reconstructed from the object's 6 rig views (live backbone tokens and IDM
priors, as ``frng relight`` does: :func:`frng.apps.relight.backbone_views`, :func:`frng.priors.build_idm`) and rendered
under the object's INPUT light at its target views. Writes the run folder ``{results}/relight/full-nvs/{obj}`` (or
``--out``): ``{input_light}/{view}.exr`` (linear premultiplied RGBA) and ``run.json`` (reconstruction and rendering
times); the relight stage's own outputs are not touched. Staged and renamed into place at the end.

Config keys read: those of ``frng relight`` (:class:`frng.apps.relight.RelightJob`: ``results``, ``seed``, ``device``,
``render.resolution``, ``shading.*``, ``idm.*``, ``backbone.*``, the runs of ``frng.variants`` (the ``full`` run's
variant, views and K) and the dataset plan); reads ``{results}/models/full/model.pt``, ``{results}/backbone/model.pt``,
the IDM's model and ``{results}/baselines/views/{obj}/meta.json`` (the input light and the target cameras)."""

from __future__ import annotations

import argparse

from frng.baselines.plan import FRNG_NVS_RUN
from frng.plan import config as frng_config
from frng.typedconfig import typed

RUN = FRNG_NVS_RUN


# The config keys this stage reads (frng.plan.digests: its rule's digest): what `frng relight` of the main group reads
# (frng/stages/relight.py)
CONFIG_READS = ("@plan", "@relight", "!train.seeds")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True, help="test object id")
    parser.add_argument("--out", help=f"run folder (default {{results}}/relight/{RUN}/{{obj}})")
    parser.add_argument("--device", help="override the config's device")


def render_nvs(job, oid: str, out, device) -> dict:
    """Reconstruct ``oid`` with the full model and render its target views under the input light into ``out``
    (a fresh folder). Returns run.json's record."""
    import os

    import numpy as np
    import torch

    from frng import io
    from frng.apps.relight import RelightError, Timer, backbone_views, validate_inputs
    from frng.model.composed import FRNG
    from frng.plan import catalog
    from frng.plan.layout import Layout, RelightFolder
    from frng.plan.variants import ALL_GROUPS
    from frng.priors import build_idm, load_backbone, view_priors
    from frng.priors.dataset import load_object

    L = Layout(job.results)
    meta = validate_inputs(job, oid)
    vmeta_path = L.baseline_views_meta(oid)
    try:
        vmeta = io.read_json(vmeta_path)
        light, cams = vmeta["light"], vmeta["views"]["targets"]
    except (FileNotFoundError, ValueError, KeyError) as e:
        raise RelightError(f"{vmeta_path}: cannot read the baseline views' light and target cameras ({e})") from e
    full = [r for r in job.runs.runs(len(meta["views"]["inputs"]), ALL_GROUPS) if r.name == "full"]
    if not full:
        raise RelightError("the config plans no 'full' run (frng.variants)")
    run = full[0]
    model_path = L.model(run.variant)
    for p, what in ((model_path, "F-RNG full model"), (L.backbone_model(), "backbone model")):
        if not os.path.exists(p):
            raise RelightError(f"{p}: {what} missing")
    idm = build_idm(job.idm, job.backbone, job.results, device)
    obj = load_object(job.results, oid, with_targets=False, with_gbuffer=idm.kind == "oracle" or run.priors == "oracle")
    if light not in obj.envs:
        raise RelightError(f"{vmeta_path}: light {light!r} is not one of the object's lights")
    views = obj.inputs[obj.input_lights[0]].select(range(run.views))
    env = obj.envs[light].to(device)
    names = [c["name"] for c in cams]
    c2w = torch.tensor(np.array([c["c2w"] for c in cams]), dtype=torch.float32, device=device)
    intr = torch.tensor(np.array([c["intrinsics"] for c in cams]), dtype=torch.float32, device=device)
    H, W = views.rgb.shape[1:3]
    backbone = load_backbone(L.backbone_model(), device)
    model = FRNG.load(model_path, device).set_inference_shading(job.shading)
    with torch.no_grad():
        with Timer(device) as t_rec:
            if run.priors == "oracle":
                pri = obj.gbuffer.select(slice(0, run.views)).to(device)
            else:  # from exactly the run's input views
                pri = view_priors(idm, obj, obj.input_lights[0], range(run.views)).to(device)
            bv = backbone_views(job.seed, backbone, oid, views, device)
            images = torch.cat([views.rgb, views.alpha], -1).to(device)
            rec = model.reconstruct(bv, 0, pri if model.cfg.uses_priors else None, images)
        g = torch.Generator(device=device).manual_seed(catalog.derive_seed(job.seed, "relight-frng", oid, light))
        with Timer(device) as t_ren:
            rgba = model.render(rec, env, c2w, intr, H, W, job.shading.spp_infer, generator=g)
    arr = rgba.float().cpu().numpy()
    for k, name in enumerate(names):
        io.write_exr(RelightFolder(out).image(light, name), arr[k], channels=["R", "G", "B", "A"])
    info = {
        "run": RUN,
        "name": RUN,
        "method": "F-RNG",
        "object": oid,
        "variant": run.variant,
        "views": int(run.views),
        "source": "trained here",
        "input_light": light,
        "lights": [light],
        "target_views": names,
        "input_views": views.names,
        "fit_seconds": t_rec.s,
        "relight_seconds_per_image": t_ren.s / len(names),
        "spp": int(job.shading.spp_infer),
        "threads": torch.get_num_threads(),
        "device": str(device),
    }
    io.write_json(RelightFolder(out).record(), info)
    return info


def run(args: argparse.Namespace) -> int:
    import os
    import shutil
    import tempfile
    from pathlib import Path

    from frng.apps.relight import RelightError, RelightJob
    from frng.device import resolve_device
    from frng.plan.layout import Layout

    config = typed(frng_config.load(args.config))
    job = RelightJob.of(config)
    out = Path(args.out or Layout(config.results).relight_run(RUN, args.object))
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".staging-{out.name}-", dir=out.parent))
    try:
        info = render_nvs(job, args.object, staging, resolve_device(args.device or job.device))
        if out.exists():
            shutil.rmtree(out)
        os.replace(staging, out)
    except RelightError as e:
        print(f"frng baseline-frng-nvs: error: {e}")
        return 2
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    print(
        f"baseline-frng-nvs {args.object}: {len(info['target_views'])} view(s) under {info['input_light']} -> {out} "
        f"(reconstruction {info['fit_seconds']:.2f} s, {1000 * info['relight_seconds_per_image']:.1f} ms/image)"
    )
    return 0
