"""The learned IDM on top of the visual-hull cues (frng/priors/idm.py, idm_train.py): a zero-initialised geometry
output decodes exactly the hull's depth and normals, the trainer's cue cache is exact, the object-context
normalisation behaves, and training on one small synthetic object lowers the loss.

No curated data: the object is an analytic sphere seen by a small ring of cameras, with exact G-buffers."""

import csv

import numpy as np
import torch

from frng import camera
from frng.priors.dataset import PriorObject, Views
from frng.priors.idm import IDMConfig, LearnedIDM, idm_loss
from frng.priors.intrinsics import IntrinsicPriors
from frng.priors.multiview import geometry_cues
from frng.training import idm as idm_train
from frng.typedconfig import typed

NEAR, FAR, RADIUS = 1.0, 4.5, 0.6
TINY = dict(width=32, heads=2, depth=1, patch=8, pixel_features=8, near=NEAR, far=FAR, head_hidden=16, cue_bins=24)


def trainer_config(train: dict) -> dict:
    """A validated pipeline config for the IDM trainer on the sphere: TINY's architecture, ``idm.train`` = ``train``,
    the schema's defaults for the rest (objects, envmaps and render are required but unused here)."""
    from frng.plan import config as frng_config

    return frng_config.validate(
        {
            "tier": "custom",
            "seed": 0,
            "device": "cpu",
            "objects": {"count": 2, "test_count": 1},
            "envmaps": {},
            "render": {"resolution": 32},
            "model": {"patch_size": 8},
            "backbone": {"near": NEAR, "far": FAR},
            "idm": {k: v for k, v in TINY.items() if k not in ("patch", "near", "far")} | {"train": train},
        }
    )


def sphere_object(V: int = 4, H: int = 32, light: str = "l0") -> PriorObject:
    """A sphere of radius RADIUS at the origin, V views on a ring (elevation 15 deg, distance 2.6), exact
    G-buffers (albedo (0.8, 0.4, 0.2), roughness 0.3, metallic 0) and a Lambert-shaded image."""
    c2w = torch.stack(
        [
            torch.tensor(camera.look_at(camera.spherical_to_cartesian(a, 15, 2.6)), dtype=torch.float32)
            for a in np.linspace(0, 360, V, endpoint=False)
        ]
    )
    intr = torch.tensor(camera.intrinsics_from_fov(50, H, H), dtype=torch.float32).expand(V, 4).clone()
    o, d = camera.pixel_rays(c2w, intr, H, H)
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - RADIUS**2)
    hit = disc > 0
    t = -b - disc.clamp_min(0).sqrt()
    pts = o + d * t[..., None]
    normal = torch.nn.functional.normalize(pts, dim=-1)
    m = hit.float()[..., None]
    z = t[..., None] * (d * c2w[:, None, None, :3, 2]).sum(-1, keepdim=True)
    albedo = torch.tensor([0.8, 0.4, 0.2]).expand(V, H, H, 3)
    shade = 0.3 + 0.7 * (normal @ torch.nn.functional.normalize(torch.tensor([0.3, 0.5, 0.8]), dim=0)).clamp_min(0)
    rgb = albedo * shade[..., None] * m
    gb = IntrinsicPriors(
        normal=normal * m, depth=z * m, albedo=albedo * m, roughness=0.3 * m, metallic=torch.zeros_like(m), mask=m
    )
    views = Views([f"in_{i:02d}" for i in range(V)], rgb.contiguous(), m.contiguous(), c2w, intr)
    return PriorObject("sphere", "train", {light: views}, {}, gb, rig_views=V)


def test_zero_head_decodes_hull_depth_and_normals():
    torch.manual_seed(0)
    obj = sphere_object()
    v = obj.inputs["l0"]
    model = LearnedIDM(IDMConfig.from_dict(TINY))
    raw = model(v.rgb[None], v.alpha[None], v.c2w[None], v.intr[None])
    out = model.decode(raw, v.alpha[None], v.c2w[None])
    # the hull, computed independently of the model
    g = geometry_cues(v.rgb, v.alpha, v.c2w, v.intr, NEAR, FAR, bins=TINY["cue_bins"])
    _, d = camera.pixel_rays(v.c2w, v.intr, 32, 32)
    z_hull = (g["distance"] * (d * v.c2w[:, None, None, :3, 2]).sum(-1, keepdim=True)).clamp(NEAR, FAR)
    assert torch.allclose(out["depth"][0], z_hull, atol=1e-5)
    n_world = (v.c2w[:, None, None, :3, :3] @ g["normal"].unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(out["normal"][0], n_world, atol=1e-5)
    fg = obj.gbuffer.mask[..., 0] > 0.5
    assert float((out["depth"][0].detach() - obj.gbuffer.depth).abs()[fg].mean()) < 0.1  # the hull is near the sphere


def test_cue_cache_reuses_the_hull_under_another_light():
    obj = sphere_object()
    v0 = obj.inputs["l0"]
    v1 = Views(v0.names, v0.rgb * torch.tensor([0.5, 1.0, 2.0]), v0.alpha, v0.c2w, v0.intr)
    obj.inputs["l1"] = v1
    model = LearnedIDM(IDMConfig.from_dict(TINY))
    cache = idm_train.CueCache()
    idx = list(range(len(v0)))
    cache.get(model, obj, "l0", idx, v0)
    got = cache.get(model, obj, "l1", idx, v1)
    ref = model.cues(v1.rgb[None], v1.alpha[None], v1.c2w[None], v1.intr[None])
    for k in ref:
        assert torch.allclose(got[k], ref[k], atol=1e-6), k


def train_idm(config, objects, out, **kw):
    """frng.training.idm.train handed the typed config's sections (as frng/stages/idm_train.py does)."""
    b = config.backbone
    return idm_train.train(
        config.idm, config.model.patch_size, b.near, b.far, config.device, config.model_seed, objects, out, **kw
    )


def test_overfits_one_object(tmp_path):
    config = trainer_config({"steps": 60, "lr": 3e-3, "warmup": 2, "bf16": False, "checkpoint_every": 60})
    torch.manual_seed(0)
    path = train_idm(typed(config), [sphere_object()], tmp_path / "idm")
    with open(tmp_path / "idm" / "loss.csv") as f:
        loss = [float(r["total"]) for r in csv.DictReader(f)]
    assert len(loss) == 60
    first, last = np.mean(loss[:5]), np.mean(loss[-5:])
    assert last < 0.5 * first, (first, last)
    # the saved model beats the untrained one (= the hull + initial materials) on the object, geometry included
    state = torch.load(path, weights_only=False)
    obj = sphere_object()
    v = obj.inputs["l0"]
    target = {k: t[None] for k, t in obj.gbuffer.as_dict().items()}

    def losses(model):
        with torch.no_grad():
            raw = model(v.rgb[None], v.alpha[None], v.c2w[None], v.intr[None])
            return {k: float(x) for k, x in idm_loss(model, raw, v.alpha[None], v.c2w[None], target).items()}

    untrained = losses(LearnedIDM(IDMConfig.from_dict(state["config"])))
    model = LearnedIDM(IDMConfig.from_dict(state["config"]))
    model.load_state_dict(state["state_dict"])
    trained = losses(model)
    assert trained["total"] < 0.5 * untrained["total"], (trained, untrained)
    assert trained["depth"] + trained["normal"] < untrained["depth"] + untrained["normal"], (trained, untrained)


def test_running_norm_standardises_objects_and_freezes_in_eval():
    from frng.priors.idm import RunningNorm

    torch.manual_seed(0)
    n = RunningNorm(2, momentum=0.001)
    x = torch.randn(400, 2) * torch.tensor([3.0, 0.5]) + torch.tensor([1.0, -2.0])
    for row in x:  # one object per training step
        n(row[None])
    y = n(x)
    assert torch.allclose(y.mean(0), torch.zeros(2), atol=0.05) and torch.allclose(y.std(0), torch.ones(2), atol=0.05)
    n.eval()
    before = n.mean.clone()
    n(torch.full((1, 2), 100.0))
    assert torch.equal(n.mean, before)
    assert torch.equal(RunningNorm(2).eval()(x), x)  # untrained: identity
