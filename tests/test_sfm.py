"""Cameras from the photos alone (frng.apps.sfm, `frng reconstruct --sfm`): structure from motion with pycolmap on
synthetic photos (tests/capture_scene.py: a textured sphere on a textured table, 12 views at 256 px with known
cameras) recovers the camera centres up to a similarity, its records are those of the COLMAP reader, the capture
comes out upright with its views chosen and masks segmented, and photos that cannot register are one line naming
what failed. CPU only, about 30 s."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import capture_scene as cs
import numpy as np
import pytest

from frng import camera, io
from frng.apps import camera_formats, masks, sfm
from frng.apps.capture import prepare
from frng.apps.capture_errors import CaptureError

N_VIEWS, RES, DIST = 12, 256, 4.0
# camera centres, after the best similarity onto the true ones, within this fraction of the camera distance
# (measured: 0.05-0.25 % over four scene seeds; 1 % = 4 cm at 4 m)
CENTRE_TOL = 0.01


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The 12 synthetic photos (PNG) and their true shots."""
    d = tmp_path_factory.mktemp("sfm") / "images"
    d.mkdir()
    shots = cs.shots(N_VIEWS, res=RES, distance=DIST)
    for i, s in enumerate(shots):
        io.write_png(d / f"v{i:02d}.png", s.rgb)
    return d, shots


def _one_line(e: pytest.ExceptionInfo, *parts: str) -> None:
    msg = str(e.value)
    assert "\n" not in msg, msg
    for p in parts:
        assert p in msg, msg


def test_sfm_recovers_the_camera_centres_up_to_a_similarity(scene, tmp_path):
    images, shots = scene
    work = tmp_path / "work"
    work.mkdir()
    lines = []
    cset = sfm.cameras_from_photos(sorted(images.glob("*.png")), images, work=work, progress=lines.append)
    assert cset.format == sfm.FORMAT and cset.path == images
    assert [n for n, _ in cset.cams] == [f"v{i:02d}" for i in range(N_VIEWS)]  # every photo registered, by stem
    assert len(lines) == 4 and lines[-1].startswith(f"sfm: {N_VIEWS} of {N_VIEWS} photos registered")
    assert list(work.iterdir()) == []  # the scratch folder is gone
    stats = cset.notes["sfm"]
    assert stats["registered"] == N_VIEWS and stats["reprojection_error_px"] < 1.0
    est = np.stack([c.c2w[:3, 3] for _, c in cset.cams])
    true = np.stack([s.c2w[:3, 3] for s in shots])
    s_, R, t = cs.similarity_fit(est, true)
    err = np.linalg.norm(s_ * est @ R.T + t - true, axis=1) / DIST
    assert err.max() < CENTRE_TOL, err
    # the orientations agree through the same rotation, the focal length is found (one shared camera)
    for (_, c), shot in zip(cset.cams, shots):
        assert cs.angle_deg(R @ c.c2w[:3, 2], shot.c2w[:3, 2]) < 1.0
        assert abs(c.intr[0] / shot.intr[0] - 1) < 0.02 and c.size == (RES, RES)
    # each photo's keypoints of sparse points are where the points project (the seeds of its mask)
    for name, cam in cset.cams:
        xy, rows = cset.observations[name]
        assert len(rows) > 30
        proj = np.array([masks._project(p, cam) for p in cset.points[rows]])
        assert np.median(np.linalg.norm(proj - xy, axis=1)) < 1.0


def test_sfm_capture_is_upright_centred_chosen_and_segmented(scene, tmp_path):
    """`frng reconstruct --sfm`'s capture: 12 photos -> 6 chosen views, GrabCut masks seeded by the sparse
    points, the world turned upright (the true up is the asset's +Z)."""
    images, shots = scene
    cap = prepare(images, resolution=64, distance=DIST, fov_deg=30.0, sfm=True, work=tmp_path, progress=lambda _: 0)
    info = cap.info
    assert info["cameras"] == "sfm" and info["camera_format"] == sfm.FORMAT and info["sfm"]["registered"] == N_VIEWS
    assert len(cap.names) == 6 and len(info["selection"]["held_out"]) == N_VIEWS - 6
    assert info["masks"] == ["grabcut:sfm-points"] * 6 and set(info["segmentation"]) == set(cap.names)
    assert "sparse points, inside the masks" in info["centre_source"]
    assert list(tmp_path.iterdir()) == []
    # asset-frame camera centres against the true ones: a similarity whose rotation only turns about Z
    true = np.stack([shots[int(n[1:])].c2w[:3, 3] for n in cap.names])
    s_, R, _ = cs.similarity_fit(true, cap.c2w[:, :3, 3])
    assert cs.angle_deg(R @ np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])) < 1.0
    assert np.allclose(np.median(np.linalg.norm(cap.c2w[:, :3, 3], axis=1)), DIST, rtol=0.1)
    assert (cap.alpha.reshape(6, -1) > 0.5).mean(1).min() > 0.05  # every view kept its object


def test_sfm_records_are_the_colmap_readers(tmp_path):
    """The in-memory conversion and the COLMAP text reader give the same cameras and points (one path)."""
    import pycolmap

    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_rigs, opts.num_frames_per_rig, opts.num_points3D = 1, 4, 40
    rec = pycolmap.synthesize_dataset(opts)
    rec.write_text(str(tmp_path))
    a = camera_formats.read_colmap(tmp_path, ".txt")
    b = sfm._to_camera_set(rec, tmp_path, {})
    assert [n for n, _ in a.cams] == [n for n, _ in b.cams]
    for (_, x), (_, y) in zip(a.cams, b.cams):
        assert np.allclose(x.c2w, y.c2w, atol=1e-9) and np.allclose(x.intr, y.intr) and x.size == y.size
        assert x.distortion == y.distortion and x.distortion.model == "opencv"  # SIMPLE_RADIAL's k1
    assert np.allclose(np.sort(a.points, 0), np.sort(b.points, 0))


def test_photos_that_share_no_features_are_too_few_matches(tmp_path):
    d = tmp_path / "unrelated"
    d.mkdir()
    K = camera.intrinsics_from_fov(42.0, RES, RES)
    for i in range(3):  # the same view of three differently textured scenes
        io.write_png(
            d / f"u{i}.png", cs.render(camera.look_at(camera.spherical_to_cartesian(0, 30, DIST)), K, seed=100 + i).rgb
        )
    with pytest.raises(CaptureError) as e:
        sfm.cameras_from_photos(sorted(d.glob("*.png")), d, progress=None)
    _one_line(e, str(d), "too few matches", "no pair of the 3 photos")


def test_photos_from_one_place_make_no_reconstruction(tmp_path):
    d = tmp_path / "turned"
    d.mkdir()
    K = camera.intrinsics_from_fov(42.0, RES, RES)
    eye = camera.spherical_to_cartesian(30, 30, DIST)
    for i, off in enumerate([(0, 0, 0), (0.6, 0, 0), (0, 0.6, 0), (0.4, -0.4, 0.2)]):  # only the camera turns
        io.write_png(d / f"r{i}.png", cs.render(camera.look_at(eye, np.array(off)), K).rgb)
    with pytest.raises(CaptureError) as e:
        sfm.cameras_from_photos(sorted(d.glob("*.png")), d, progress=None)
    _one_line(e, str(d), "made no reconstruction", "best pair")


@pytest.fixture(scope="module")
def strays(scene, tmp_path_factory):
    """The 12 photos plus two that cannot register: the same view of another scene (``stray.png``) and noise
    (``noise.png``)."""
    images, _ = scene
    d = tmp_path_factory.mktemp("strays") / "images"
    shutil.copytree(images, d)
    K = camera.intrinsics_from_fov(42.0, RES, RES)
    io.write_png(d / "stray.png", cs.render(camera.look_at(camera.spherical_to_cartesian(0, 30, DIST)), K, seed=7).rgb)
    io.write_png(d / "noise.png", np.random.default_rng(3).uniform(size=(RES, RES, 3)).astype(np.float32))
    return d


def test_photos_that_do_not_register_are_left_out_when_enough_do(strays, tmp_path):
    lines = []
    cset = sfm.cameras_from_photos(sorted(strays.glob("*.png")), strays, need=6, progress=lines.append)
    assert [n for n, _ in cset.cams] == [f"v{i:02d}" for i in range(N_VIEWS)]
    assert cset.notes["sfm"]["not_registered"] == ["noise.png", "stray.png"]
    left = [ln for ln in lines if "left out" in ln]
    assert len(left) == 1 and left[0].startswith("sfm: not registered, left out: noise.png, stray.png (")
    assert f"{N_VIEWS} of {N_VIEWS + 2} photos registered" in left[0]
    # through the capture: the two are neither views nor held out, and the record names them
    cap = prepare(strays, resolution=64, distance=DIST, fov_deg=30.0, sfm=True, work=tmp_path, progress=lines.append)
    assert cap.info["sfm"]["not_registered"] == ["noise.png", "stray.png"]
    sel = cap.info["selection"]
    assert len(sel["chosen"]) == 6 and len(sel["held_out"]) == N_VIEWS - 6
    assert not {"noise", "stray"} & set(sel["chosen"] + sel["held_out"])
    assert [c["name"] for c in cap.info["held_out_cameras"]] == sel["held_out"]


def test_too_few_registered_photos_are_one_line_naming_them(strays):
    files = sorted(strays.glob("*.png"))
    with pytest.raises(CaptureError) as e:  # every photo must register
        sfm.cameras_from_photos(files, strays, progress=None)
    _one_line(e, str(strays), f"registered {N_VIEWS} of {N_VIEWS + 2} photos", "noise.png (", "stray.png (")
    with pytest.raises(CaptureError) as e:  # more views wanted than registered
        sfm.cameras_from_photos(files, strays, need=N_VIEWS + 1, progress=None)
    _one_line(e, str(strays), f"fewer than the {N_VIEWS + 1} views the model takes", "did not register: noise.png (")


def test_too_few_photos_and_bad_combinations(scene, tmp_path):
    images, _ = scene
    two = tmp_path / "two"
    two.mkdir()
    for f in sorted(images.glob("*.png"))[:2]:
        shutil.copy(f, two / f.name)
    with pytest.raises(CaptureError) as e:
        sfm.cameras_from_photos(sorted(two.glob("*.png")), two, progress=None)
    _one_line(e, str(two), "2 photo(s)", "at least 3 photos")
    with pytest.raises(CaptureError, match="without --cameras or --rig"):
        prepare(images, resolution=32, distance=DIST, fov_deg=30.0, sfm=True, rig="paper")
    import argparse

    from frng.commands import reconstruct

    parser = argparse.ArgumentParser()
    reconstruct.configure(parser)
    assert parser.parse_args(["--sfm", "--images", "x", "--out", "y"]).sfm
    with pytest.raises(SystemExit):
        parser.parse_args(["--sfm", "--cameras", "c.json", "--out", "y"])
    assert "--sfm" in parser.format_help()


def test_photos_colmap_cannot_read_are_copied_into_the_scratch_folder(scene, tmp_path):
    """JPEG/PNG photos are read where they are; a folder with EXR photos is copied as 8-bit sRGB PNGs into the
    scratch folder (and nothing is written beside the photos)."""
    from frng.apps.capture import read_image

    images, shots = scene
    pngs = sorted(images.glob("*.png"))[:3]
    assert sfm._image_folder(pngs, tmp_path, read_image) == (images, [f.name for f in pngs])
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    io.write_exr(mixed / "a.exr", io.srgb_decode(shots[0].rgb))
    shutil.copy(pngs[1], mixed / "b.png")
    before = sorted(mixed.iterdir())
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    folder, names = sfm._image_folder(before, scratch, read_image)
    assert folder == scratch / "images" and names == ["a.png", "b.png"] and sorted(mixed.iterdir()) == before
    assert np.abs(io.read_png(folder / "a.png")[..., :3] - shots[0].rgb).max() <= 1.5 / 255


def test_sfm_and_masks_modules_do_not_import_torch():
    code = "import sys\nimport frng.apps.sfm, frng.apps.masks\nprint('torch' in sys.modules)"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    assert out.strip() == "False"
