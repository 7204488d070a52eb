"""The training light pool (issue 55 part 4): families (sky / hdri / studio) held out per family or whole, hard
procedural studios, one map per (object, light) draw with its own rotation, hard first input lights for a
configured fraction of the objects. Plan-only (no Blender) but for the studio maps' measured hardness (numpy)."""

from pathlib import Path

import numpy as np
import pytest

from frng.data import envmaps
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config

ROOT = Path(__file__).resolve().parents[1]


def _cfg(seed=0, **envmaps_keys):
    env = {
        "width": 32,
        "bundled": ["city", "forest", "studio", "sunset"],
        "skies": {"models": ["preetham"], "sun_elevations_deg": [10, 40], "turbidity": [2.5, 6]},
        "rotations": 2,
        "studio": {"count": 8},
        "hard_input_fraction": 0.5,
    }
    env |= envmaps_keys
    return frng_config.validate(
        {
            "tier": "custom",
            "seed": seed,
            "objects": {"count": 24, "test_count": 8, "sources": ["primitives", "procedural"]},
            "envmaps": env,
            "render": {"resolution": 32, "input_lights": 2, "target_lights": 3},
        }
    )


def test_plan_is_deterministic_and_seeded():
    a, b = catalog.plan(_cfg()), catalog.plan(frng_config.validate(dict(_cfg())))
    assert a == b and [e.to_dict() for e in a.envmaps] == [e.to_dict() for e in b.envmaps]
    other = catalog.plan(_cfg(seed=1))
    assert [e.rotation_deg for e in other.envmaps] != [e.rotation_deg for e in a.envmaps]
    assert [o.input_lights for o in other.objects] != [o.input_lights for o in a.objects]


def test_pool_counts_and_turbidity_grid():
    bases = catalog.plan(_cfg()).bases
    by = {f: [b for b in bases if b.family == f] for f in ("hdri", "sky", "studio")}
    assert len(by["hdri"]) == 4 and len(by["sky"]) == 4 and len(by["studio"]) == 8
    assert {b.sky["turbidity"] for b in by["sky"]} == {2.5, 6.0}
    assert sum(b.hard for b in by["studio"]) == 4 and not any(b.hard for b in by["hdri"] + by["sky"])
    assert len({b.base for b in bases}) == len(bases)


@pytest.mark.parametrize("test_families", [[], ["studio"], ["sky", "hdri"]])
def test_families_are_held_out(test_families):
    # a held-out studio family leaves training no hard light to photograph objects under
    cat = catalog.plan(_cfg(test_families=test_families, hard_input_fraction=0.0 if "studio" in test_families else 0.5))
    split = {b.base: b.split for b in cat.bases}
    for fam in ("hdri", "sky", "studio"):
        splits = {b.split for b in cat.bases if b.family == fam}
        # held out whole, or per base within the family: both splits, never a base in both
        assert splits == ({"test"} if fam in test_families else {"train", "test"}), fam
    if "studio" not in test_families:  # the test pool gains hard lights, training keeps some
        assert {b.split for b in cat.bases if b.hard} == {"train", "test"}
    train_bases = {
        cat.envmap(l).base for o in cat.objects if o.split == "train" for l in o.input_lights + o.target_lights
    }
    test_bases = {
        cat.envmap(l).base for o in cat.objects if o.split == "test" for l in o.input_lights + o.target_lights
    }
    assert not train_bases & test_bases
    assert all(split[b] == "test" for b in test_bases) and all(split[b] == "train" for b in train_bases)
    for fam in test_families:
        assert not any(cat.envmap(l).family == fam for o in cat.objects if o.split == "train" for l in o.input_lights)
    for e in cat.envmaps:
        assert e.split == split[e.base] and e.family == catalog.FAMILY_OF_SOURCE[e.source]


def test_unknown_test_family_is_a_config_error():
    with pytest.raises(Exception, match="test_families"):
        catalog.plan(_cfg(test_families=["moon"]))


def test_every_draw_is_its_own_rotated_map():
    cat = catalog.plan(_cfg())
    names = [e.name for e in cat.envmaps]
    assert len(names) == len(set(names))
    drawn = [l for o in cat.objects for l in dict.fromkeys(o.input_lights + o.target_lights)]
    assert sorted(drawn) == sorted(names)
    for o in cat.objects:
        assert all(cat.envmap(l).object == o.id for l in o.input_lights + o.target_lights)
    by_base: dict[str, list[float]] = {}
    for e in cat.envmaps:
        by_base.setdefault(e.base, []).append(e.rotation_deg)
    shared = [r for r in by_base.values() if len(r) > 1]
    assert shared, "no base map drawn twice: the test says nothing"
    for rots in shared:  # the same base drawn by different objects (or twice by one) is rotated otherwise
        assert len(set(rots)) == len(rots)
    assert all(0.0 <= e.rotation_deg < 360.0 for e in cat.envmaps)


@pytest.mark.parametrize("fraction", [0.25, 0.5, 1.0])
def test_hard_input_fraction_is_as_configured(fraction):
    cat = catalog.plan(_cfg(hard_input_fraction=fraction))
    for split in ("train", "test"):
        objs = [o for o in cat.objects if o.split == split]
        hard = [o for o in objs if cat.envmap(o.input_lights[0]).hard]
        assert len(hard) == int(round(fraction * len(objs))), split
        for o in hard:  # photographed under a hard light, supervised under other base maps
            inputs = {cat.envmap(l).base for l in o.input_lights}
            assert not inputs & {cat.envmap(l).base for l in o.target_lights}


def test_targets_spread_over_the_families():
    """One target light of each family where the split's pool has one left besides the inputs' base maps."""
    cat = catalog.plan(_cfg(test_fraction=0.5))
    full = 0
    for o in cat.objects:
        inputs = {cat.envmap(l).base for l in o.input_lights}
        left = {b.family for b in cat.bases if b.split == o.split and b.base not in inputs}
        got = [cat.envmap(l).family for l in o.target_lights]
        assert set(got) == left, o.id  # 3 targets, at most 3 families: one of each family left
        full += sorted(got) == ["hdri", "sky", "studio"]
    assert full >= len(cat.objects) // 2


def test_a_split_without_hard_lights_is_a_plan_error():
    with pytest.raises(dataset_config.CatalogError, match="envmaps.hard_input_fraction"):
        catalog.plan(_cfg(studio={"count": 0}))
    assert catalog.plan(_cfg(studio={"count": 0}, hard_input_fraction=0.0)).objects  # 0: no constraint


@pytest.mark.parametrize("path", ["config/config.yaml", "config/paper.yaml"])
def test_tier_pools(path):
    """Counts the docs state: the default tier's pool (76 bases: 8 HDRIs, 20 skies, 48 studios), a quarter of each
    family held out, every test object supervised under one light of each family."""
    cfg = frng_config.load(ROOT / path)
    cat = catalog.plan(cfg)
    fams = {f: [b for b in cat.bases if b.family == f] for f in ("hdri", "sky", "studio")}
    if path == "config/config.yaml":
        assert [len(fams[f]) for f in ("hdri", "sky", "studio")] == [8, 20, 48]
        assert len(cat.envmaps) == sum(len(dict.fromkeys(o.input_lights + o.target_lights)) for o in cat.objects)
    for f, bs in fams.items():
        assert sum(b.split == "test" for b in bs) == round(0.25 * len(bs)), f
    assert sum(b.hard and b.split == "test" for b in cat.bases) >= 2
    for o in cat.objects[:50]:
        if o.split == "test" and cfg["render"]["target_lights"] == 3:
            assert sorted(cat.envmap(l).family for l in o.target_lights) == ["hdri", "sky", "studio"]


def test_hard_studios_measure_hard():
    """The plan's hard studios are hard by the measured hardness (the share of the light from the brightest 1 % of
    the sphere), the soft ones are not, and a uniform map gives 1 %."""
    cat = catalog.plan(_cfg())
    studios = [b for b in cat.bases if b.family == "studio"]
    measured = {b.base: envmaps.hardness(envmaps.studio_map(b.studio, 128)) for b in studios}
    hard = [measured[b.base] for b in studios if b.hard]
    soft = [measured[b.base] for b in studios if not b.hard]
    assert min(hard) > 0.6 and max(soft) < min(hard), (hard, soft)
    assert abs(envmaps.hardness(np.ones((64, 128, 3), np.float32)) - 0.01) < 0.002


def test_sunny_skies_are_hard_lights():
    """envmaps.skies.sun_share: a sun disc towards the sky's sun carrying that share of the light (measured), in
    the sky's colour there; at >= 0.5 the skies join the hard lights the hard inputs are drawn from."""
    import math

    import torch

    from frng.render import envmap

    h, w = 128, 256
    d = envmap.pixel_directions(h, w, dtype=torch.float64).numpy()
    sky = np.where(d[..., 2:3] > 0, [[0.3, 0.4, 0.6]], [[0.05, 0.05, 0.05]]).astype(np.float32) * np.ones((h, w, 3))
    el = 30.0
    sunny = envmaps.add_sun(sky, el, 0.8)
    e_all, e_sky = envmaps.mean_luminance(sunny), envmaps.mean_luminance(sky)
    assert np.isclose((e_all - e_sky) / e_all, 0.8, atol=1e-4)
    j, i = np.unravel_index(np.argmax(envmap.luminance(sunny)), (h, w))
    sun = np.array([math.cos(math.radians(el)), 0.0, math.sin(math.radians(el))])
    assert d[j, i] @ sun > math.cos(math.radians(2.0))
    rgb = sunny[j, i] - sky[j, i]
    assert np.allclose(rgb / rgb.sum(), np.array([0.3, 0.4, 0.6]) / 1.3, atol=1e-3)  # the sky's colour there
    assert envmaps.hardness(sunny) > 0.75 > 0.1 > envmaps.hardness(sky)

    cat = catalog.plan(_cfg(skies={"models": ["preetham"], "sun_elevations_deg": [10, 40], "sun_share": 0.8}))
    skies = [b for b in cat.bases if b.family == "sky"]
    assert skies and all(b.hard and b.sky["sun_share"] == 0.8 for b in skies)
    hard_inputs = {cat.envmap(o.input_lights[0]).family for o in cat.objects if cat.envmap(o.input_lights[0]).hard}
    assert hard_inputs == {"sky", "studio"}
    assert not any(b.hard for b in catalog.plan(_cfg()).bases if b.family == "sky")  # sun_share 0: soft skies
