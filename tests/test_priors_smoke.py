"""Smoke-tier integration of the priors on real curated data (Blender smoke dataset, tiny models):
kill + resume of training, caches with stale-hash refusal, and models beating trivial baselines."""

import csv
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from data_helpers import kill_at_first_checkpoint

from frng.plan.catalog import plan
from frng.typedconfig import typed

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def smoke(smoke_dataset, tmp_path_factory):
    """Own results folder on the session's shared smoke dataset (tests/conftest.py)."""
    from conftest import smoke_results

    # the learned IDM's training at a fifth of the tier's steps, a checkpoint every 10: the kill-and-resume test needs
    # a checkpoint before the end, not the tier's 150 steps (the smoke run trains those)
    idm_train = {"steps": 30, "checkpoint_every": 10, "bf16": False}
    return smoke_results(smoke_dataset, tmp_path_factory.mktemp("priors_smoke"), idm={"train": idm_train})


def _rows(p):
    with open(p) as f:
        return list(csv.DictReader(f))


def test_idm_train_killed_then_resumed(smoke):
    path, config = smoke
    out = Path(config["results"]) / "idm"
    cmd = [sys.executable, "-m", "frng", "idm-train", "--config", str(path), "--out", str(out)]
    saved = kill_at_first_checkpoint(cmd, out)
    steps_total = config["idm"]["train"]["steps"]
    assert 0 < saved < steps_total
    subprocess.run(cmd, check=True, capture_output=True)
    assert (out / "model.pt").exists() and (out / "loss.png").exists()
    rows = _rows(out / "loss.csv")
    assert [int(r["step"]) for r in rows] == list(range(1, steps_total + 1))  # resumed, not restarted


def _bb(config):
    """What frng.training.backbone.train reads of the config (as frng/stages/backbone_train.py hands it)."""
    tc = typed(config)
    return tc.backbone, tc.model.patch_size, tc.device, tc.model_seed


def test_backbone_resume_cache_and_stale(smoke):
    from frng.priors import cache
    from frng.priors.dataset import load_split
    from frng.training import backbone as backbone_train

    _, config = smoke
    res = Path(config["results"])
    objs = load_split(config["results"], plan(config).split("train"))
    out = res / "backbone"
    backbone_train.train(*_bb(config), objs, out, stop_after=5)
    assert torch.load(out / "checkpoint.pt", weights_only=False)["step"] == 5
    model = backbone_train.train(*_bb(config), objs, out)  # resumes at 5
    rows = _rows(out / "loss.csv")
    assert [int(r["step"]) for r in rows] == list(range(1, config["backbone"]["train"]["steps"] + 1))
    test_id = cache.catalog.plan(config).split("test")[0]
    tc = typed(config)
    p = cache.make_backbone_cache(
        tc.results,
        tc.seed,
        cache.catalog.plan(tc).envmaps,
        tc.backbone.cache_extra_lights,
        test_id,
        model,
        res / "backbone" / "cache" / f"{test_id}.safetensors",
    )
    c = cache.load_backbone_cache(p, model)
    # light 0: the reference light E_0 (the input views' light is never an input), then the extra training lights
    assert len(c.lights) == 1 + tc.backbone.cache_extra_lights and c.lights[0] == cache.REFERENCE_LIGHT
    train_lights = {e.name for e in cache.catalog.plan(config).envmaps if e.split == "train"}
    assert c.lights[1] in train_lights
    v6 = c.views(6)
    assert v6["t_geo"].shape[0] == 6 and v6["light1.sh"].shape[0] == v6["means"].shape[0]
    assert 2 in c.meta["view_counts"]
    # a changed backbone file makes the cache stale
    other = res / "other.pt"
    state = torch.load(model, weights_only=False)
    state["steps"] = -1
    torch.save(state, other)
    with pytest.raises(cache.StaleCacheError):
        cache.load_backbone_cache(p, other)


def test_priors_beat_trivial_baselines(smoke_dataset):
    """eval-backbone on the smoke test object, with the smoke run's backbone and learned IDM (trained at the tier's
    steps; this module's own trainings are short resume checks)."""
    from frng.priors import build_idm, evaluate, load_backbone
    from frng.priors.dataset import load_split

    _, config = smoke_dataset
    res = Path(config["results"])
    assert (res / "backbone" / "model.pt").exists() and (res / "idm" / "model.pt").exists()
    train_objs, test = (
        load_split(config["results"], plan(config).split("train")),
        load_split(config["results"], plan(config).split("test")),
    )
    rows = evaluate.eval_backbone(
        typed(config).seed, load_backbone(res / "backbone" / "model.pt"), test, evaluate.mean_image(train_objs)
    )

    def mean(method, key):
        v = [r[key] for r in rows if r["method"] == method]
        return sum(v) / len(v)

    assert mean("backbone", "psnr") > mean("mean-image", "psnr") + 1.0
    assert 0 <= mean("backbone", "lpips") < mean("mean-image", "lpips")  # recorded for the ladder's rows a-c
    idm_rows = evaluate.eval_idm(
        build_idm(typed(config).idm, typed(config).backbone, config["results"]), test, train_objs
    )
    learned = [r for r in idm_rows if r["method"] == "idm-learned"]
    const = [r for r in idm_rows if r["method"] == "constant"]
    assert sum(r["albedo_psnr"] for r in learned) > sum(r["albedo_psnr"] for r in const) + 0.2 * len(learned)
    assert sum(r["normal_deg"] for r in learned) < sum(r["normal_deg"] for r in const)


def test_backbone_cue_cache_changes_nothing(smoke, tmp_path, monkeypatch):
    """Keeping the rig views' multi-view cues between steps (CueCache) gives the same weights, bit for bit, as
    computing them every step, and the cache is used."""
    from conftest import assert_same_weights, record_instances

    from frng.priors.dataset import load_split
    from frng.training import backbone as bt

    _, config = smoke
    objs = load_split(config["results"], plan(config).split("train"))
    made = record_instances(monkeypatch, bt, "CueCache")
    kept = bt.train(*_bb(config), objs, tmp_path / "kept", steps=10)
    fresh = bt.train(*_bb(config), objs, tmp_path / "fresh", steps=10, cue_cache=False)
    assert len(made) == 1 and made[0].hits > 0 and made[0].bytes > 0
    assert_same_weights(kept, fresh)


def test_backbone_overfits_one_object(smoke):
    """The backbone's learned part can fit one object: the same training sample (fixed light, views, timestep and
    noise) every step, its L2 falls well below where the multi-view prior alone starts."""
    import random

    from frng.priors import backbone as bb
    from frng.priors.backbone_config import backbone_config
    from frng.priors.dataset import load_split
    from frng.training import backbone as bt

    _, config = smoke
    obj = load_split(config["results"], plan(config).split("train"))[0]
    torch.manual_seed(0)
    model = bb.RelitLRMBackbone(backbone_config(typed(config).backbone, config["model"]["patch_size"]))
    tcfg = bt.BackboneTrainConfig.from_dict({**config["backbone"]["train"], "bf16": False})
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    l2 = []
    for _step in range(60):
        torch.manual_seed(1)  # same timestep and noise
        losses = bt.step_loss(model, obj, tcfg, 0, random.Random(1), torch.device("cpu"))
        opt.zero_grad()
        losses["total"].backward()
        opt.step()
        l2.append(float(losses["l2"].detach()))
    assert l2[-1] < 0.5 * l2[0], l2[::10]


def test_backbone_opacity_term_keeps_pixels_gaussians_as_opaque_as_their_pixels(smoke):
    """``backbone.train.lambda_opacity``: the loss is the mean |opacity - input alpha| of the foreground pixels'
    Gaussians, ~0 where the backbone starts (the prior's opacity is the alpha), added to the total with its weight,
    and its gradient reaches the GeoDetokenizer (without it the wide light pool's backbone fell to opacity ~0.3)."""
    import random

    from frng.priors import backbone as bb
    from frng.priors.backbone_config import backbone_config
    from frng.priors.dataset import load_split
    from frng.training import backbone as bt

    _, config = smoke
    obj = load_split(config["results"], plan(config).split("train"))[0]
    torch.manual_seed(0)
    model = bb.RelitLRMBackbone(backbone_config(typed(config).backbone, config["model"]["patch_size"]))
    base = {**config["backbone"]["train"], "bf16": False, "lambda_per": 0.0}

    def losses(lam):
        torch.manual_seed(1)
        tcfg = bt.BackboneTrainConfig.from_dict({**base, "lambda_opacity": lam})
        return bt.step_loss(model, obj, tcfg, 0, random.Random(1), torch.device("cpu"))

    on, off = losses(2.0), losses(0.0)
    assert "opacity" not in off and 0.0 <= float(on["opacity"]) < 0.05, float(on["opacity"])
    assert torch.isclose(on["total"] - off["total"], 2.0 * on["opacity"], atol=1e-5)
    model.zero_grad()
    on["opacity"].backward()
    assert float(model.geo_detokenizer.proj.bias.grad.abs().sum()) > 0


def test_backbone_cue_noise_perturbs_what_the_geometry_transformer_reads(smoke, monkeypatch):
    """``backbone.train.cue_noise``: the cue features the geometry transformer reads in a training step carry
    N(0, (scale x CUE_NOISE_SIGMA)^2) per channel (none on the hit flag), the prior's raw Gaussians and the hull
    normals are untouched, the rig views' cue cache keeps the clean cues, and at 0 nothing is added."""
    import random

    from frng.priors import backbone as bb
    from frng.priors.backbone_config import backbone_config
    from frng.priors.dataset import load_split
    from frng.training import backbone as bt

    _, config = smoke
    obj = load_split(config["results"], plan(config).split("train"))[0]
    torch.manual_seed(0)
    model = bb.RelitLRMBackbone(backbone_config(typed(config).backbone, config["model"]["patch_size"]))
    seen = []
    encode = model.encode_geometry
    monkeypatch.setattr(model, "encode_geometry", lambda *a: seen.append(a[4]) or encode(*a))
    base = {**config["backbone"]["train"], "bf16": False, "lambda_per": 0.0}
    rng_seed = next(s for s in range(50) if len(bt.sample_views(obj, random.Random(s))[1]) == obj.rig_views)

    def cues_of_a_step(scale, cache=None):
        tcfg = bt.BackboneTrainConfig.from_dict({**base, "cue_noise": scale})
        bt.step_loss(model, obj, tcfg, 0, random.Random(rng_seed), torch.device("cpu"), cues=cache)
        return seen[-1]

    cache = bt.CueCache()
    clean = cues_of_a_step(0.0, cache)
    assert clean is not None and cache.bytes > 0
    kept = [t.clone() for t in clean]
    noisy = cues_of_a_step(3.0, cache)
    assert cache.hits == 1 and all(torch.equal(a, b) for a, b in zip(clean, kept))  # the cache's cues stay clean
    assert torch.equal(noisy[1], clean[1]) and torch.equal(noisy[2], clean[2])
    std = (noisy[0] - clean[0]).flatten(0, -2).std(dim=0)
    want = 3.0 * torch.tensor(bt.CUE_NOISE_SIGMA)
    assert std[-1] == 0 and torch.allclose(std[:-1], want[:-1], rtol=0.15), (std, want)
    again = cues_of_a_step(0.0, cache)
    assert all(torch.equal(a, b) for a, b in zip(again, kept))
