"""Clean ground truth: the render.* sampling keys (denoising, clamps) reach Cycles, and `frng bench targets-noise`
measures the curated images' noise floor against a high-spp render (docs/studies/2026-11-28-clean-targets.md)."""

import numpy as np
import pandas as pd
import pytest
from data_helpers import frng, write_config

from frng import io
from frng.plan import config as frng_config
from frng.render import envmap

pytestmark = pytest.mark.blender


def _scene(tmp_path, **render):
    from frng.data.curate import object_scene
    from frng.plan import catalog
    from frng.plan.sections import config_section

    cfg = frng_config.load(write_config(tmp_path / "config.yaml", tmp_path / "results", render=render))
    plan = catalog.plan(cfg)
    spec = next(o for o in plan.objects if o.material == "diffuse")
    return object_scene(plan, config_section(cfg, "objects").objaverse, config_section(cfg, "render"), spec, print)


def _render(tmp_path, name, **render) -> dict[str, np.ndarray]:
    from frng import camera
    from frng.blender import scene as bscene
    from frng.blender import world

    scene, cam, *_ = _scene(tmp_path, **render)
    env = tmp_path / "env.exr"
    sky = np.full((16, 32, 3), 0.2, np.float32)
    sky[2:4, 10:12] = 2000.0  # a small sun: the samples that hit it are what a clamp cuts
    envmap.write(env, sky)
    world.set_envmap(scene, env, 64)
    bscene.set_camera_pose(cam, camera.look_at(camera.spherical_to_cartesian(30.0, 20.0, 2.6)))
    out = tmp_path / f"{name}.exr"
    bscene.render_to(scene, out)
    return scene, io.read_exr_channels(out)


def test_render_settings_reach_cycles(tmp_path):
    scene, ch = _render(
        tmp_path,
        "oidn",
        resolution=16,
        spp=4,
        denoise=True,
        denoise_prefilter="fast",
        clamp_direct=2.5,
        clamp_indirect=3.5,
    )
    c = scene.cycles
    assert (c.samples, c.use_denoising, c.denoiser, c.denoising_input_passes) == (
        4,
        True,
        "OPENIMAGEDENOISE",
        "RGB_ALBEDO_NORMAL",
    )
    assert (c.sample_clamp_direct, c.sample_clamp_indirect, c.denoising_prefilter) == (2.5, 3.5, "FAST")
    # the denoiser ran: Blender keeps the noisy image beside the denoised Combined layer
    noisy = np.stack([ch[f"ViewLayer.Noisy Image.{k}"] for k in "RGB"], -1)
    combined = np.stack([ch[f"ViewLayer.Combined.{k}"] for k in "RGB"], -1)
    assert np.abs(noisy - combined).max() > 1e-3

    scene, raw = _render(tmp_path, "raw", resolution=16, spp=4, denoise=False, clamp_direct=0, clamp_indirect=0)
    assert not scene.cycles.use_denoising and not any("Noisy" in k for k in raw)
    _, clamped = _render(tmp_path, "clamped", resolution=16, spp=4, denoise=False, clamp_direct=0.05, clamp_indirect=0)
    # a direct clamp far below the sun's radiance darkens the render: the value reached the sampler
    assert clamped["ViewLayer.Combined.R"].mean() < 0.7 * raw["ViewLayer.Combined.R"].mean()


def test_noise_floor_bench_on_a_toy_case(tmp_path):
    """The bench's `tier` row is the curated target bit for bit, more samples score closer to the reference, and a
    rerun of the denoised setting gives the same bytes."""
    cfg = write_config(tmp_path / "config.yaml", tmp_path / "results", render={"resolution": 32, "spp": 2})
    frng("envmaps", "--config", str(cfg))
    frng("curate", "--config", str(cfg), "--object", "obj_0000")
    common = ["--config", str(cfg), "--objects", "obj_0000", "--views", "1", "--reference-spp", "32", "--save-images"]
    proc = frng("bench", "targets-noise", *common, "--settings", "tier", "16", "2+oidn", "--out", str(tmp_path / "a"))
    assert "| tier" in proc.stdout
    df = pd.read_csv(tmp_path / "a" / "renders.csv")
    assert set(df["setting"]) == {"reference", "reference-half", "tier", "16", "2+oidn"}
    assert df.loc[df["setting"] != "reference", "psnr"].notna().all()
    by = df.groupby("setting")["psnr"].mean()
    assert by["16"] > by["tier"] + 3.0, by  # 8x the samples: ~9 dB less noise
    assert (tmp_path / "a" / "summary.md").read_text().count("PSNR") >= 3

    light = df["light"].iloc[0]
    curated = io.read_rgba(tmp_path / "results" / "objects" / "obj_0000" / "targets" / light / "tgt_000.exr")
    images = tmp_path / "a" / "images" / "obj_0000" / light / "tgt_000"
    assert np.array_equal(io.read_rgba(images / "tier.exr"), curated)

    frng("bench", "targets-noise", *common, "--settings", "2+oidn", "--out", str(tmp_path / "b"))
    again = tmp_path / "b" / "images" / "obj_0000" / light / "tgt_000" / "2+oidn.exr"
    assert np.array_equal(io.read_rgba(again), io.read_rgba(images / "2+oidn.exr"))


def test_bad_setting_is_one_line(tmp_path):
    cfg = write_config(tmp_path / "config.yaml", tmp_path / "results")
    proc = frng(
        "bench", "targets-noise", "--config", str(cfg), "--settings", "32+fast", "--out", str(tmp_path), check=False
    )
    assert proc.returncode == 2 and "32+fast" in proc.stderr and "unknown part 'fast'" in proc.stderr
