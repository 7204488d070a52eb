"""The per-scene baselines (frng/baselines/perscene.py, splat3d.py, gsir.py; stage ``frng baseline-fit``) do their job
before they are compared (issue 54, Must show): on a small object rendered with the project's own renderer (a shell
of a few hundred flat Gaussians of known albedo / roughness / normal, shaded by gsir's split-sum under a procedural
studio light, at 32 px from ``frng.baselines.plan.dense_views`` cameras) their loss falls, their re-renders of their
own training views reach a measured PSNR, gsir relit under a second light approaches that light's ground truth, and
both lose novel-view quality with 6 views against 24. gsir learns its input light (it never reads that map) and the
light it learns moves towards the truth."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from frng.baselines import gsir, splat3d
from frng.baselines.fit_settings import FitSettings
from frng.baselines.perscene import GaussianSet, TrainViews, photometric_loss, psnr, ssim
from frng.baselines.plan import dense_subset, dense_views
from frng.data.envmaps import studio_map
from frng.plan.sections import section
from frng.render.project import rotmat_to_quat
from frng.render.raster import RasterConfig

RES = 32
RASTER = RasterConfig.from_dict({})

STUDIO_A = {
    "background": 0.15,
    "lights": [
        {
            "azimuth_deg": 30,
            "elevation_deg": 40,
            "roll_deg": 0,
            "width_deg": 50,
            "height_deg": 40,
            "strength": 4.0,
            "kelvin": 6500,
        },
        {
            "azimuth_deg": 200,
            "elevation_deg": 10,
            "roll_deg": 0,
            "width_deg": 40,
            "height_deg": 60,
            "strength": 1.5,
            "kelvin": 4000,
        },
    ],
}
STUDIO_B = {
    "background": 0.1,
    "lights": [
        {
            "azimuth_deg": 120,
            "elevation_deg": -10,
            "roll_deg": 0,
            "width_deg": 60,
            "height_deg": 50,
            "strength": 3.0,
            "kelvin": 9000,
        },
        {
            "azimuth_deg": 300,
            "elevation_deg": 60,
            "roll_deg": 0,
            "width_deg": 30,
            "height_deg": 30,
            "strength": 5.0,
            "kelvin": 3000,
        },
    ],
}


def env(params: dict) -> torch.Tensor:
    return torch.from_numpy(studio_map(params, 64))


def toy_model(n: int = 300, seed: int = 0) -> gsir.GSIR:
    """A known relightable object: ``n`` flat Gaussians on an ellipsoid shell (normal radial), two-tone albedo,
    roughness 0.3-0.9, a few metallic ones."""
    g = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    axes = torch.tensor([0.7, 0.55, 0.45])
    means = d * axes
    normal = torch.nn.functional.normalize(d / axes, dim=-1)
    ref = torch.where(normal[:, 2:3].abs() < 0.9, torch.tensor([0.0, 0.0, 1.0]), torch.tensor([1.0, 0.0, 0.0]))
    t1 = torch.nn.functional.normalize(torch.cross(ref, normal, dim=-1), dim=-1)
    t2 = torch.cross(normal, t1, dim=-1)
    quats = rotmat_to_quat(torch.stack([t1, t2, normal], -1))
    albedo = torch.where(means[:, :1] > 0, torch.tensor([0.8, 0.3, 0.2]), torch.tensor([0.2, 0.5, 0.8]))
    albedo = albedo + 0.1 * torch.rand(n, 3, generator=g)
    params = {
        "means": means,
        "log_scales": torch.log(torch.tensor([0.12, 0.12, 0.015])).repeat(n, 1),
        "quats": quats,
        "opacity": torch.full((n, 1), 3.0),
        "normal": normal,
        "albedo": torch.logit(albedo.clamp(0.05, 0.95)),
        "roughness": torch.logit(0.3 + 0.6 * torch.rand(n, 1, generator=g)),
        "metallic": torch.where(torch.rand(n, 1, generator=g) < 0.1, 2.0, -6.0),
    }
    gs = GaussianSet(params, {k: 0.0 for k in params})
    return gsir.GSIR(gs, gsir.occlusion_grid(gs), None, 0.0, 0)


def toy_views(model: gsir.GSIR, cams, light: gsir.Light) -> TrainViews:
    c2w = torch.tensor(np.array([v.c2w for v in cams]), dtype=torch.float32)
    intr = torch.tensor(np.array([v.intrinsics for v in cams]), dtype=torch.float32)
    rgba = model.shade(model.gbuffer(c2w, intr, RES, RES, RASTER), light)
    return TrainViews([v.name for v in cams], c2w, intr, rgba[..., :3], rgba[..., 3:4])


def settings(**kw) -> FitSettings:
    return dataclasses.replace(section(FitSettings, {}, "baselines.fit"), **kw)


@pytest.fixture(autouse=True)
def one_thread():
    """The fits at one thread (as the pipeline's jobs run them; measured thresholds), the count restored after."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def toy():
    torch.manual_seed(0)
    model = toy_model()
    cams = dense_views(24, 2.6, 50.0, RES)
    held = [v for v in dense_views(31, 2.6, 50.0, RES)][1::4]  # other cameras on the sphere: novel views
    la, lb = gsir.Light.of(env(STUDIO_A)), gsir.Light.of(env(STUDIO_B))
    return {
        "cams": cams,
        "train": toy_views(model, cams, la),
        "held_a": toy_views(model, held, la),
        "held_b": toy_views(model, held, lb),
        "light_b": lb,
    }


def test_ssim_and_loss():
    x = torch.rand(2, 16, 16, 3, generator=torch.Generator().manual_seed(0))
    assert abs(float(ssim(x, x)) - 1.0) < 1e-5
    assert float(photometric_loss(x, x)) < 1e-5
    assert float(ssim(x, x.flip(1))) < 0.5
    assert psnr(x, x) > 100


def test_densify_keeps_adam_state():
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(50, 3, generator=g)
    gs = GaussianSet(
        splat3d.gaussian_params(pts, torch.rand(50, 3, generator=g), 1),
        {"means": 0.1} | {k: 0.1 for k in ("log_scales", "quats", "opacity", "sh_dc", "sh_rest")},
    )
    gs["means"].sum().backward()
    gs.opt.step()
    before = gs.opt.state[gs["means"]]["exp_avg"].clone()
    gs.extend({k: v[:5] for k, v in gs.state().items()})
    assert len(gs) == 55 and torch.equal(gs.opt.state[gs["means"]]["exp_avg"][:50], before)
    assert float(gs.opt.state[gs["means"]]["exp_avg"][50:].abs().sum()) == 0.0
    keep = torch.arange(55) % 2 == 0
    gs.keep(keep)
    assert len(gs) == 28 and torch.equal(gs.opt.state[gs["means"]]["exp_avg"][:25], before[keep[:50]])


def _novel_psnr(render, held: TrainViews) -> float:
    return splat3d.train_psnr(render, held)


def test_3dgs_recovers_its_views_and_collapses_with_fewer(toy):
    s = settings(steps=150, init_points=500, max_gaussians=1000, lr_scale=6.0)
    m24 = splat3d.fit(toy["train"], s, RASTER, seed=0)
    r24 = lambda c, i, h, w: m24.render(c, i, h, w, RASTER)  # noqa: E731
    assert m24.curve.mean_loss(False) < 0.5 * m24.curve.mean_loss(True)
    train24 = splat3d.train_psnr(r24, toy["train"])
    assert train24 > 28.0, train24
    v6 = TrainViews(*_subset(toy["train"], toy["cams"], 6))
    m6 = splat3d.fit(v6, s, RASTER, seed=0)
    r6 = lambda c, i, h, w: m6.render(c, i, h, w, RASTER)  # noqa: E731
    assert splat3d.train_psnr(r6, v6) > 32.0
    nv24, nv6 = _novel_psnr(r24, toy["held_a"]), _novel_psnr(r6, toy["held_a"])
    # 6 views fall at least 1 dB below 24 on novel views: measured gaps 1.2 / 3.5 / 3.8 dB at seeds 0 / 1 / 2 with
    # both CPU rasterizers (`torch`, `native`; within 0.04 dB of each other); 1.5 sat on seed 0's gap
    assert nv24 > 28.0 and nv6 < nv24 - 1.0, (nv24, nv6)


def _subset(views: TrainViews, cams, n: int):
    names = [v.name for v in dense_subset(cams, n)]
    idx = torch.tensor([views.names.index(x) for x in names])
    return names, views.c2w[idx], views.intr[idx], views.rgb[idx], views.alpha[idx]


def test_3dgs_is_deterministic(toy):
    s = settings(steps=20, init_points=300, max_gaussians=600)
    v = TrainViews(*_subset(toy["train"], toy["cams"], 6))
    a, b = splat3d.fit(v, s, RASTER, seed=3), splat3d.fit(v, s, RASTER, seed=3)
    assert all(torch.equal(a.gs[k], b.gs[k]) for k in a.gs.params)


def test_gsir_relights(toy):
    s = settings(steps=150, pbr_steps=100, init_points=500, max_gaussians=1000, lr_scale=6.0)
    m = gsir.fit(toy["train"], s, RASTER, seed=0)  # its light unknown: it learns one
    assert len(m.curve.rows) == 250 and m.curve.mean_loss(False) < 0.5 * m.curve.mean_loss(True)
    assert m.env.shape == (gsir.LIGHT_HEIGHT, 2 * gsir.LIGHT_HEIGHT, 3) and bool((m.env > 0).all())
    v = toy["train"]
    H, W = v.size
    rgba = m.shade(m.gbuffer(v.c2w, v.intr, H, W, RASTER), m.light)  # under the light it learned
    assert psnr(rgba[..., :3], v.rgb) > 28.0
    held = toy["held_b"]
    relit = m.shade(m.gbuffer(held.c2w, held.intr, H, W, RASTER), toy["light_b"])
    p_relit = psnr(relit[..., :3], held.rgb)
    # against the trivial answer: the object as seen under the training light. Measured (seeds 0 / 1 / 2): relit
    # 24.0 / 23.5 / 23.5 dB with the learned light (25.8 / 25.0 / 25.1 given the true one), unrelit 22.2
    p_unrelit = psnr(toy["held_a"].rgb, held.rgb)
    assert p_relit > 23.5 and p_relit > p_unrelit + 1.0, (p_relit, p_unrelit)
    assert math.isfinite(m.geometry_psnr)


def test_learned_light_is_differentiable_and_prefilters_as_a_given_map():
    """The learned light's SH and prefiltered levels are the given-map path's (same projection, same vMF lobes at
    its resolution) and carry gradient back to the map."""
    from frng.render.prefilter import prefilter

    e = torch.rand(gsir.LIGHT_HEIGHT, 2 * gsir.LIGHT_HEIGHT, 3, generator=torch.Generator().manual_seed(0)) + 0.1
    ll = gsir.LearnedLight(1.0)
    with torch.no_grad():
        ll.log_env.copy_(torch.log(e))
    lit = ll.light()
    assert torch.allclose(lit.pref, prefilter(e.clone(), height=gsir.LIGHT_HEIGHT), rtol=1e-5, atol=1e-6)
    assert torch.allclose(lit.sh, gsir.Light.of(e).sh, rtol=1e-5, atol=1e-6)
    (lit.sh.sum() + lit.pref.sum() + ll.tv()).backward()
    assert ll.log_env.grad is not None and bool((ll.log_env.grad.abs() > 0).all())


def _lambert_sphere(n: int = 400) -> gsir.GSIR:
    """A grey (0.6) rough dielectric sphere of radius 0.6: flat Gaussians on its surface, normal radial."""
    g = torch.Generator().manual_seed(1)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    ref = torch.where(d[:, 2:3].abs() < 0.9, torch.tensor([0.0, 0.0, 1.0]), torch.tensor([1.0, 0.0, 0.0]))
    t1 = torch.nn.functional.normalize(torch.cross(ref, d, dim=-1), dim=-1)
    params = {
        "means": 0.6 * d,
        "log_scales": torch.log(torch.tensor([0.1, 0.1, 0.012])).repeat(n, 1),
        "quats": rotmat_to_quat(torch.stack([t1, torch.cross(d, t1, dim=-1), d], -1)),
        "opacity": torch.full((n, 1), 3.0),
        "normal": d,
        "albedo": torch.full((n, 3), math.log(0.6 / 0.4)),
        "roughness": torch.full((n, 1), 6.0),
        "metallic": torch.full((n, 1), -8.0),
    }
    gs = GaussianSet(params, {k: 0.0 for k in params})
    return gsir.GSIR(gs, gsir.occlusion_grid(gs), None, 0.0, 0)


def test_learned_light_moves_towards_the_truth():
    """A diffuse sphere lit from +x (radiance 1 + 0.9 x, a degree-1 SH light: irradiance 4x brighter at +x than at
    -x): the light fitted from its images, started uniform, is brighter on the +x side (measured over fit seeds 0-3:
    2.2-2.4x at +x than at -x, +y / -y within 11 %)."""
    from frng.render import envmap

    d = envmap.pixel_directions(32, 64)
    truth = gsir.Light.of((1.0 + 0.9 * d[..., :1]).expand(32, 64, 3).contiguous())
    sphere = _lambert_sphere()
    cams = dense_views(12, 2.6, 50.0, RES)
    views = toy_views(sphere, cams, truth)
    s = settings(steps=60, pbr_steps=80, init_points=300, max_gaussians=600, lr_scale=6.0)
    m = gsir.fit(views, s, RASTER, seed=0)
    axes = torch.tensor([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]], dtype=torch.float64)
    e = envmap.sh_irradiance(m.light.sh.double(), axes).mean(-1)
    e_true = envmap.sh_irradiance(truth.sh.double(), axes).mean(-1)
    assert float(e_true[0] / e_true[1]) > 3.5
    assert float(e[0] / e[1]) > 1.8, e.tolist()
    assert abs(float(e[2] / e[3]) - 1.0) < 0.3, e.tolist()


def _write_object(results, toy, oid: str = "toy") -> None:
    """A results folder holding what ``frng baseline-fit`` reads: the baselines' views of one object (the toy's 24
    dense views under light A, 2 target views), its meta.json with one target light (B), both env maps."""
    from frng import io
    from frng.plan.layout import Layout, ObjectFolder
    from frng.render import envmap

    L = Layout(results)
    train: TrainViews = toy["train"]
    targets = [
        dataclasses.replace(v, kind="target", name=f"t{k}") for k, v in enumerate(dense_views(31, 2.6, 50.0, RES)[1:3])
    ]
    folder = ObjectFolder(L.baseline_views_dir(oid))
    for k, v in enumerate(toy["cams"]):
        rgba = torch.cat([train.rgb[k], train.alpha[k]], -1).numpy()
        io.write_exr(folder.image("dense", "lightA", v.name), rgba, channels=["R", "G", "B", "A"])
    io.write_json(
        L.baseline_views_meta(oid),
        {
            "id": oid,
            "light": "lightA",
            "views": {"dense": [v.to_dict() for v in toy["cams"]], "targets": [v.to_dict() for v in targets]},
        },
    )
    io.write_json(L.object_meta(oid), {"id": oid, "input_lights": ["lightA"], "target_lights": ["lightB"]})
    Path(L.envmap("x")).parent.mkdir(parents=True, exist_ok=True)
    envmap.write(L.envmap("lightA"), env(STUDIO_A).numpy())
    envmap.write(L.envmap("lightB"), env(STUDIO_B).numpy())


@pytest.mark.parametrize("method", ["3dgs", "gsir"])
def test_stage_writes_the_contract(toy, tmp_path, method):
    from frng import io
    from frng.baselines.fit_job import BaselineFitError, FitJob, fit_object
    from frng.plan import config as frng_config
    from frng.plan.layout import RelightFolder
    from frng.typedconfig import typed

    results = tmp_path / "results"
    _write_object(results, toy)
    config = typed(frng_config.load(str(Path(__file__).resolve().parent.parent / "config" / "smoke.yaml")))
    fit = settings(steps=12, pbr_steps=6, init_points=200, max_gaussians=400)
    job = dataclasses.replace(FitJob.of(config), results=str(results), device="cpu", fit=fit)
    out = results / "relight" / f"{method}-v6" / "toy"
    rec = fit_object(job, "toy", method, 6, out)
    folder = RelightFolder(out)
    lights = ["lightA", "lightB"] if method == "gsir" else ["lightA"]
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == lights
    for light in lights:
        for view in ("t0", "t1"):
            img = io.read_rgba(folder.image(light, view), require_alpha=True)
            assert img.shape == (RES, RES, 4) and np.isfinite(img).all() and img[..., 3].max() > 0.05
    saved = io.read_json(folder.record())
    assert saved["run"] == f"{method}-v6" and saved["views"] == 6 and saved["source"] == "trained here"
    assert saved["steps"] == (18 if method == "gsir" else 12) == rec["steps"]
    assert len(saved["train_views"]) == 6 and math.isfinite(saved["train_psnr"]) and saved["fit_seconds"] > 0
    assert (out / "loss.csv").read_text().startswith("step,loss,psnr\n")
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".staging")]
    with pytest.raises(BaselineFitError, match="25 views asked"):
        fit_object(job, "toy", method, 25, out)
    (results / "baselines" / "views" / "toy" / "dense" / "lightA" / "d000.exr").unlink()
    with pytest.raises(BaselineFitError, match="d000.exr"):
        fit_object(job, "toy", method, 6, out)
    assert io.read_json(folder.record()) == saved  # the failed jobs left the folder as it was


def test_gsir_fit_never_reads_the_input_light(toy, tmp_path):
    """The task gives no method the input views' light: gsir's outputs (novel views under its learned light, relit
    images, run record) are bit-identical whether the object's input map is the true one, another map, or missing;
    a changed TARGET map (which the task gives) does change the relit images."""
    from frng import io
    from frng.baselines.fit_job import FitJob, fit_object
    from frng.plan import config as frng_config
    from frng.plan.layout import Layout, RelightFolder
    from frng.render import envmap
    from frng.typedconfig import typed

    results = tmp_path / "results"
    _write_object(results, toy)
    L = Layout(results)
    config = typed(frng_config.load(str(Path(__file__).resolve().parent.parent / "config" / "smoke.yaml")))
    fit = settings(steps=12, pbr_steps=6, init_points=200, max_gaussians=400)
    job = dataclasses.replace(FitJob.of(config), results=str(results), device="cpu", fit=fit)

    def outputs(name: str) -> dict:
        out = results / "relight" / name / "toy"
        fit_object(job, "toy", "gsir", 6, out)
        rec = io.read_json(RelightFolder(out).record())
        images = {p.relative_to(out).as_posix(): io.read_rgba(p) for p in sorted(out.glob("*/*.exr"))}
        return {"images": images, "record": {k: v for k, v in rec.items() if "seconds" not in k}}

    first = outputs("a")
    envmap.write(L.envmap("lightA"), env(STUDIO_B).numpy() * 3.0)  # another input map
    second = outputs("b")
    Path(L.envmap("lightA")).unlink()  # no input map at all
    third = outputs("c")
    assert sorted(first["images"]) == ["lightA/t0.exr", "lightA/t1.exr", "lightB/t0.exr", "lightB/t1.exr"]
    for other in (second, third):
        assert other["record"] == first["record"]
        assert sorted(other["images"]) == sorted(first["images"])
        assert all(np.array_equal(other["images"][k], first["images"][k]) for k in first["images"]), "differs"
    envmap.write(L.envmap("lightB"), env(STUDIO_A).numpy())  # the target map: read, it changes the relit images
    fourth = outputs("d")
    assert np.array_equal(fourth["images"]["lightA/t0.exr"], first["images"]["lightA/t0.exr"])
    assert not np.array_equal(fourth["images"]["lightB/t0.exr"], first["images"]["lightB/t0.exr"])


@dataclasses.dataclass
class _TintFitted:
    """A toy per-scene model: 3dgs's fit, relit as its input-light render tinted by each target map's mean."""

    inner: splat3d.FittedSplat3D
    extra = {"toy": True}

    @property
    def curve(self):
        return self.inner.curve

    @property
    def gaussians(self) -> int:
        return self.inner.gaussians

    def render(self, c2w, intr, height, width, envs):
        lit, _ = self.inner.render(c2w, intr, height, width, {})
        tint = {light: torch.cat([lit[..., :3] * env.mean(), lit[..., 3:]], -1) for light, env in envs.items()}
        return lit, tint


def _tint_fit(views, fit_settings, raster, seed, label="tint"):
    return _TintFitted(splat3d.fit_baseline(views, fit_settings, raster, seed, label))


def test_a_registered_method_is_planned_fitted_scored_and_tabled(toy, tmp_path, monkeypatch):
    """Adding a per-scene baseline is one registry entry (frng/baselines/registry.py): a toy method that relights,
    registered here alone, is planned on the smoke tier (its runs at each view count, scored on relighting and novel
    views), accepted by the stage, fitted by the fit job (given the target maps), scored and labelled in the tables."""
    import argparse

    import pandas as pd

    from frng import io
    from frng.baselines import plan as P
    from frng.baselines import registry, scoring
    from frng.baselines.fit_job import FitJob, fit_object
    from frng.plan import config as frng_config
    from frng.plan.layout import Layout, ObjectFolder
    from frng.report import baseline_tables as B
    from frng.stages import baseline_fit
    from frng.typedconfig import typed

    spec = registry.PerSceneMethod("tint", "Tint (per-scene)", "3dgs, tinted per light", relights=True, fit=_tint_fit)
    monkeypatch.setitem(registry.PER_SCENE, spec.name, spec)
    smoke = Path(__file__).resolve().parent.parent / "config" / "smoke.yaml"
    raw = frng_config.load(str(smoke), {"baselines": {"methods": ["tint"]}})
    assert P.per_scene_runs(raw) == ["tint-v8", "tint-v4"]  # smoke: view_counts [8, 4]
    runs = [r for r in scoring.planned_runs(raw, ["toy"], ["toy"], ["toy"]) if r.method == "tint"]
    assert [(r.run, r.tasks, r.family) for r in runs] == [(f"tint-v{n}", ("relight", "nvs"), "dense") for n in (8, 4)]
    parser = argparse.ArgumentParser()
    baseline_fit.configure(parser)
    assert (
        parser.parse_args(["--config", "c", "--object", "toy", "--method", "tint", "--views", "4", "--out", "x"]).method
        == "tint"
    )

    results = tmp_path / "results"
    _write_object(results, toy)
    job = dataclasses.replace(
        FitJob.of(typed(raw)), results=str(results), device="cpu", fit=settings(steps=12, init_points=200)
    )
    for n in (8, 4):
        rec = fit_object(job, "toy", "tint", n, results / "relight" / f"tint-v{n}" / "toy")
        assert rec["lights"] == ["lightB"] and rec["toy"] is True and rec["steps"] == 12

    # the ground truth scoring reads: the toy object under light B (relighting), under light A (novel views)
    L = Layout(results)
    meta = io.read_json(L.baseline_views_meta("toy"))
    from frng.data.rig import View

    targets = [View.from_record(d) for d in meta["views"]["targets"]]
    truth = toy_model()
    for light, params in (("lightA", STUDIO_A), ("lightB", STUDIO_B)):
        gt = toy_views(truth, targets, gsir.Light.of(env(params)))
        for k, v in enumerate(targets):
            rgba = torch.cat([gt.rgb[k], gt.alpha[k]], -1).numpy()
            path = L.object_image("toy", "targets", light, v.name) if light == "lightB" else None
            path = path or ObjectFolder(L.baseline_views_dir("toy")).image("targets", light, v.name)
            io.write_exr(path, rgba, channels=["R", "G", "B", "A"])
    obj = io.read_json(L.object_meta("toy"))
    obj |= {"material_class": "diffuse", "views": {"targets": meta["views"]["targets"]}}
    io.write_json(L.object_meta("toy"), obj)
    rows = [row for r in runs for row in scoring.score_run(results, r, "aligned", (1.0, 1.0, 1.0))]
    df = pd.DataFrame(rows)
    assert df.groupby(["task", "run"]).size().to_dict() == {
        (task, f"tint-v{n}"): 2 for task in ("relight", "nvs") for n in (8, 4)
    }
    assert np.isfinite(df["psnr"]).all()
    assert B.dense_runs(df) == ["tint-v8"] and B.nvs_runs(df) == ["tint-v4", "tint-v8"]
    assert B.label("tint", "dense") == "Tint (per-scene)"


def test_no_module_names_a_per_scene_method():
    """The plan, the fit job, the scoring, the tables, the stage and the rules read the registry: none of them holds
    a method's name as a string of its own (the registry is where ``3dgs`` and ``gsir`` are named)."""
    import ast
    import re

    from frng.baselines import registry

    root = Path(__file__).resolve().parent.parent
    names = set(registry.names())
    for rel in (
        "frng/baselines/plan.py",
        "frng/baselines/fit_job.py",
        "frng/baselines/scoring.py",
        "frng/report/baseline_tables.py",
        "frng/stages/baseline_fit.py",
    ):
        consts = {n.value for n in ast.walk(ast.parse((root / rel).read_text())) if isinstance(n, ast.Constant)}
        assert not names & consts, (rel, names & consts)
    code = "\n".join(line.split("#", 1)[0] for line in (root / "rules" / "baselines.smk").read_text().splitlines())
    assert not [n for n in names if re.search(rf"[\"']{re.escape(n)}[\"']", code)]


def test_an_unknown_method_is_one_line_naming_the_key():
    from frng.baselines import plan as P
    from frng.plan import config as frng_config

    smoke = Path(__file__).resolve().parent.parent / "config" / "smoke.yaml"
    raw = frng_config.load(str(smoke), {"baselines": {"methods": ["3dgs", "nerf"]}})
    with pytest.raises(ValueError, match=r"^config key 'baselines.methods': unknown per-scene baseline 'nerf' "):
        P.per_scene_runs(raw)
