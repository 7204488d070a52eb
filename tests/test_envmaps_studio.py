"""Procedural studio environments (envmaps.studio): seeded area lights over a dim background, baked to equirect EXR
(issue 23 item 2). No Blender needed: the maps are generated in numpy."""

import math

import numpy as np
import torch
from data_helpers import frng, write_config

from frng import io
from frng.data import envmaps
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config
from frng.plan.sections import schema_defaults
from frng.render import envmap


def _cfg(count=3, seed=0):
    return frng_config.validate(
        {
            "tier": "custom",
            "seed": seed,
            "objects": {"count": 2, "test_count": 1},
            "envmaps": {
                "bundled": ["city", "forest", "sunset"],
                "skies": {"models": []},
                "rotations": 1,
                "studio": {"count": count},
            },
            "render": {"resolution": 32, "input_lights": 1, "target_lights": 1},
        }
    )


def test_studio_plan_is_seeded_and_off_by_default():
    assert all(e.source != "studio" for e in catalog.envmap_plan(_cfg(count=0)))
    a, b = catalog.envmap_plan(_cfg()), catalog.envmap_plan(_cfg())
    studios = [e for e in a if e.source == "studio"]
    bases = catalog.plan(_cfg()).bases
    assert [b.base for b in bases if b.source == "studio"] == ["procstudio_0", "procstudio_1", "procstudio_2"]
    assert {e.base for e in studios} <= {"procstudio_0", "procstudio_1", "procstudio_2"}
    assert [e.to_dict() for e in a] == [e.to_dict() for e in b]
    assert [e.studio for e in studios] != [e.studio for e in catalog.envmap_plan(_cfg(seed=1)) if e.source == "studio"]
    d = dataset_config.StudioConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in schema_defaults("envmaps.studio").items()}
    )
    for e in studios:
        lights = e.studio["lights"]
        hard = e.studio["hard"]
        assert hard == e.hard and e.family == "studio"
        assert (1 <= len(lights) <= 2) if hard else (d.lights[0] <= len(lights) <= d.lights[1])
        size = d.hard_size_deg if hard else d.size_deg
        for light in lights:
            assert d.kelvin[0] <= light["kelvin"] <= d.kelvin[1]
            assert size[0] <= light["width_deg"] <= size[1]
    assert "studio" not in next(e for e in a if e.source == "bundled").to_dict()  # other records unchanged


def test_blackbody_colours():
    warm, white, cold = (envmaps.blackbody_rgb(k) for k in (2700, 6500, 10000))
    assert warm[0] > warm[1] > warm[2] and cold[2] > cold[0]
    assert np.abs(white - 1).max() < 0.08
    assert all(abs(float(envmap.luminance(c)) - 1) < 1e-5 for c in (warm, white, cold))


def test_studio_map_puts_each_light_where_the_plan_says():
    params = {
        "background": 0.02,
        "lights": [
            {
                "azimuth_deg": 60.0,
                "elevation_deg": 30.0,
                "width_deg": 20.0,
                "height_deg": 10.0,
                "roll_deg": 0.0,
                "kelvin": 3000.0,
                "strength": 1.0,
            },
            {
                "azimuth_deg": 250.0,
                "elevation_deg": 5.0,
                "width_deg": 30.0,
                "height_deg": 30.0,
                "roll_deg": 20.0,
                "kelvin": 9000.0,
                "strength": 2.0,
            },
        ],
    }
    img = envmaps.studio_map(params, 256)
    assert img.shape == (128, 256, 3) and np.isfinite(img).all()
    d = envmap.pixel_directions(128, 256, dtype=torch.float64).numpy()
    for light in params["lights"]:
        az, el = math.radians(light["azimuth_deg"]), math.radians(light["elevation_deg"])
        f = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        j, i = np.unravel_index(np.argmax(d @ f), d.shape[:2])
        centre = img[j, i]
        want = light["strength"] * envmaps.blackbody_rgb(light["kelvin"]) + 0.02
        assert np.allclose(centre, want, rtol=1e-4), (centre, want)
        lit = (img.sum(-1) > 0.5) & (d @ f > math.cos(math.radians(25)))
        omega = envmap.pixel_solid_angles(128, 256).numpy()
        area = math.radians(light["width_deg"]) * math.radians(light["height_deg"])  # small-angle rectangle
        assert 0.7 < (omega * lit).sum() / area < 1.3
    dark = d @ np.array([0.0, 0.0, -1.0]) > 0.99  # straight down: the floor, no light there
    assert np.allclose(img[dark], 0.01)


def test_studio_maps_are_written_by_the_envmaps_stage(tmp_path):
    cfg = write_config(
        tmp_path / "config.yaml",
        tmp_path / "results",
        envmaps={
            "bundled": [],
            "skies": {"models": []},
            "width": 32,
            "rotations": 2,
            "test_fraction": 0.5,
            "studio": {"count": 2},
        },
    )
    frng("envmaps", "--config", str(cfg))
    index = io.read_json(tmp_path / "results" / "envmaps" / "index.json")
    plan = catalog.plan(frng_config.load(cfg))
    assert sorted(m["name"] for m in index["maps"]) == sorted(e.name for e in plan.envmaps)
    assert {m["base"] for m in index["maps"]} == {"procstudio_0", "procstudio_1"}  # one hard (test), one soft
    assert {m["split"] for m in index["maps"]} == {"train", "test"}
    for m in index["maps"]:
        assert m["source"] == "studio" and m["studio"]["lights"] and m["licence"] == catalog.GENERATED_LICENCE
        img = envmap.read(tmp_path / "results" / "envmaps" / f"{m['name']}.exr")
        assert img.shape == (16, 32, 3) and abs(m["mean_luminance"] - 0.5) < 1e-3
