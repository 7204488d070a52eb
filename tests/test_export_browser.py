"""``frng export-asset``'s files in a real browser, each read by a maintained third-party three.js Gaussian-splat
renderer installed from npm into a cache folder, served from 127.0.0.1 and rendered in Debian's headless Chromium
(selenium; software WebGL, SwiftShader) at a camera of the asset's rig; each canvas is compared with
``frng render-asset``'s image at the same camera and light, over the object (its pixels where render-asset's
alpha > 0.5):

- the PLY and the GLB in three.js's own renderer (three@0.187.0: the ``GaussianSplat`` addon with
  ``GaussianSplatPLYLoader`` and the glTF loader's ``KHR_gaussian_splatting`` plugin; the WebGPU renderer's WebGL
  backend): within :data:`PSNR_OBJECT_DB`, and the two formats within :data:`PSNR_FORMATS_DB` of each other;
- the SPZ in Spark (@sparkjsdev/spark@2.2.0, World Labs' renderer, on three's ``WebGLRenderer``; its own SPZ
  decoder, which takes the file's RUB axes as three.js's world axes with no conversion): within
  :data:`PSNR_SPZ_DB` of render-asset and :data:`PSNR_SPZ_PLY_DB` of three.js's PLY canvas. The axes are checked
  by rendering, at the same camera, the same bake written in wrong axes (a front/back mirror, SPZ's y and z
  negated as an RDF-for-RUB mix-up, the asset's Z-up axes unconverted): each must fall below the threshold.

What differs, and why the thresholds are not higher: render-asset blends the Gaussians' features and decodes per
pixel (deferred), 3DGS blends the Gaussians' baked colours (forward), in display (sRGB) space, with degree-3 SH.
Measured on the test's ball at -2 EV: three.js 19.2 dB for each of PLY and GLB, 53.3 dB between them; Spark's SPZ
22.8 dB, 27.5 dB against three.js's PLY canvas; the wrongly-oriented SPZ files 10.7-15.9 dB.
Without /usr/bin/chromium or npm this module skips, except on CI (``CI`` or ``FRNG_REQUIRE_BROWSER`` set), where it
fails (tests/browser.py).
"""

from __future__ import annotations

import dataclasses
import functools
import gzip
import http.server
import json
import os
import threading
import time
from pathlib import Path

import browser
import numpy as np
import pytest
from test_export import _frng, ball_asset, npm_packages, sky_map

THREE = "three@0.187.0"
SPARK = "@sparkjsdev/spark@2.2.0"
SIZE = 160  # canvas side, px
EV = -2.0  # exposure: the test map's sun would saturate most of the ball at 0 EV
ROTATION = 30.0  # the map's rotation about the asset's Z, degrees
PSNR_OBJECT_DB = 17.0  # three.js's PLY / GLB canvas against render-asset, over the object (measured 19.2 dB)
PSNR_FORMATS_DB = 35.0  # three.js's PLY canvas against its GLB canvas (measured 53.3 dB)
PSNR_SPZ_DB = 21.0  # Spark's SPZ canvas against render-asset (measured 22.8 dB; wrong axes 10.7-15.9 dB)
PSNR_SPZ_PLY_DB = 25.0  # Spark's SPZ canvas against three.js's PLY canvas (measured 27.5 dB)

PAGE = """<!doctype html><html><head><meta charset="utf-8">
<style>html,body{margin:0;background:#000;overflow:hidden}canvas{display:block}</style>
<script type="importmap">{"imports":{"three":"./node_modules/three/build/three.webgpu.js",
"three/webgpu":"./node_modules/three/build/three.webgpu.js","three/tsl":"./node_modules/three/build/three.tsl.js",
"three/addons/":"./node_modules/three/examples/jsm/"}}</script></head><body><script type="module">
import * as THREE from 'three/webgpu';
import { GaussianSplat } from 'three/addons/objects/GaussianSplat.js';
import { GaussianSplatPLYLoader } from 'three/addons/loaders/GaussianSplatPLYLoader.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { GLTFGaussianSplatLoaderExtension } from 'three/addons/loaders/GLTFGaussianSplatLoaderExtension.js';
const q = JSON.parse(decodeURIComponent(location.hash.slice(1)));
try {
  const renderer = new THREE.WebGPURenderer({ antialias: false, forceWebGL: true, alpha: false });
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;  // the splats' colours are display-referred already
  renderer.toneMapping = THREE.NoToneMapping;
  renderer.setPixelRatio(1);
  renderer.setSize(q.size, q.size);
  document.body.appendChild(renderer.domElement);
  await renderer.init();
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0, 0, 0);
  const camera = new THREE.PerspectiveCamera(q.fov, 1, 0.05, 100);
  camera.matrixAutoUpdate = false;
  camera.matrix.fromArray(q.matrix);
  camera.matrixWorld.copy(camera.matrix);
  camera.matrixWorldInverse.copy(camera.matrix).invert();
  if (q.file.endsWith('.ply')) {
    scene.add(new GaussianSplat(await new GaussianSplatPLYLoader().loadAsync(q.file)));
  } else {
    const loader = new GLTFLoader();
    loader.register((parser) => new GLTFGaussianSplatLoaderExtension(parser));
    scene.add((await loader.loadAsync(q.file)).scene);
  }
  for (let i = 0; i < 4; i++) { renderer.render(scene, camera); await new Promise(r => setTimeout(r, 50)); }
  document.title = 'rendered';
} catch (e) { document.title = 'error: ' + e; }
</script></body></html>
"""

# Spark: the output colour space stays sRGB so that Spark writes the splats' (display-referred) colours as they are
# (it converts them to linear only for a linear output); preBlurAmount 0.3 is the 0.3 px^2 that 3DGS and frng's
# rasterizer (raster.eps2d) add to each 2D covariance, without Spark's default opacity-compensated blurAmount (the
# convention of files trained with anti-aliasing, which SPZ flags; frng's are not).
SPARK_PAGE = """<!doctype html><html><head><meta charset="utf-8">
<style>html,body{margin:0;background:#000;overflow:hidden}canvas{display:block}</style>
<script type="importmap">{"imports":{"three":"./node_modules/three/build/three.module.js",
"three/addons/":"./node_modules/three/examples/jsm/",
"@sparkjsdev/spark":"./node_modules/@sparkjsdev/spark/dist/spark.module.js"}}</script></head><body>
<script type="module">
import * as THREE from 'three';
import { SparkRenderer, SplatMesh } from '@sparkjsdev/spark';
const q = JSON.parse(decodeURIComponent(location.hash.slice(1)));
try {
  const renderer = new THREE.WebGLRenderer({ antialias: false, alpha: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(q.size, q.size);
  document.body.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0, 0, 0);
  scene.add(new SparkRenderer({ renderer, preBlurAmount: 0.3, blurAmount: 0.0 }));
  const camera = new THREE.PerspectiveCamera(q.fov, 1, 0.05, 100);
  camera.matrixAutoUpdate = false;
  camera.matrix.fromArray(q.matrix);
  camera.matrixWorld.copy(camera.matrix);
  camera.matrixWorldInverse.copy(camera.matrix).invert();
  const mesh = new SplatMesh({ url: q.file });
  scene.add(mesh);
  await mesh.initialized;
  // Spark sorts the splats in a worker: render frames until the sorted order has arrived
  for (let i = 0; i < 20; i++) { renderer.render(scene, camera); await new Promise(r => setTimeout(r, 50)); }
  document.title = 'rendered';
} catch (e) { document.title = 'error: ' + e; }
</script></body></html>
"""


@pytest.fixture(scope="module")
def browser_paths():
    return browser.paths()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


def serve(folder: Path) -> tuple[http.server.ThreadingHTTPServer, int]:
    """A static file server on 127.0.0.1 (a free port) for ``folder``, in a daemon thread."""
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(folder)))
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    return httpd, httpd.server_address[1]


def three_camera(c2w: np.ndarray, frame: np.ndarray) -> list[float]:
    """An OpenCV camera-to-world (4, 4) in the asset's axes -> three.js's camera matrix (column-major 16) in a
    file's axes (``frame`` (3, 3): asset -> file): three.js cameras look down -Z with +Y up (OpenCV: +Z, -Y)."""
    m = np.eye(4)
    m[:3, :3] = frame @ c2w[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    m[:3, 3] = frame @ c2w[:3, 3]
    return m.T.reshape(-1).tolist()


def shoot(url: str, profile: Path) -> np.ndarray:
    """The page's canvas as float RGB in [0, 1] once it reports 'rendered'."""
    import io as _io

    import imageio.v3 as iio
    from selenium.webdriver.common.by import By

    driver = browser.chrome(
        profile, (SIZE + 200, SIZE + 200), ("--use-angle=swiftshader", "--enable-unsafe-swiftshader")
    )
    try:
        driver.get(url)
        t0 = time.monotonic()
        while driver.title != "rendered" and not driver.title.startswith("error") and time.monotonic() - t0 < 120:
            time.sleep(0.25)
        assert driver.title == "rendered", (driver.title, driver.get_log("browser")[-5:])
        time.sleep(0.5)
        png = driver.find_element(By.TAG_NAME, "canvas").screenshot_as_png
    finally:
        driver.quit()
    return iio.imread(_io.BytesIO(png))[..., :3].astype(np.float64) / 255.0


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / max(float(np.mean((a - b) ** 2)), 1e-12)))


@dataclasses.dataclass
class Scene:
    """The test asset exported by the command line, and ``frng render-asset``'s image of it at the test camera:
    ``files`` (format -> path), ``c2w`` (4, 4) OpenCV camera-to-world in asset axes, ``fov`` (degrees, vertical),
    ``ref_rgb`` (SIZE, SIZE, 3) display sRGB over black, ``alpha`` (SIZE, SIZE)."""

    asset: Path
    sky: Path
    files: dict[str, Path]
    c2w: np.ndarray
    fov: float
    ref_rgb: np.ndarray
    alpha: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """The object's pixels: render-asset's alpha > 0.5."""
        return self.alpha > 0.5

    @property
    def background(self) -> np.ndarray:
        """Pixels well off the object: render-asset's alpha < 0.01."""
        return self.alpha < 0.01

    def env(self) -> np.ndarray:
        """The map as exported: rotated by :data:`ROTATION` about Z."""
        from frng.render import envmap

        return envmap.rotate_z(envmap.read(self.sky), ROTATION)


@pytest.fixture(scope="module")
def scene(browser_paths, tmp_path_factory) -> Scene:
    """The ball exported as PLY, SPZ and GLB by ``frng export-asset`` (rotation 30 degrees, -2 EV), and its
    render-asset image at a turntable camera."""
    import torch

    from frng import io
    from frng.apps.asset import AssetRenderer
    from frng.apps.render_asset import turntable

    root = tmp_path_factory.mktemp("browser")
    asset, sky = ball_asset(root / "asset"), sky_map(root / "sky.exr")
    files = {}
    t0 = time.monotonic()
    for fmt in ("ply", "spz", "glb"):
        files[fmt] = root / "files" / f"ball.{fmt}"
        r = _frng("export-asset", asset, "--env", sky, "--rotation", ROTATION, "--exposure", EV,
                  "--out", files[fmt])  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
    print(f"\nexport (three formats): {time.monotonic() - t0:.1f} s")
    cam = turntable(1, 25.0, 3.0, 40.0, SIZE)[0]
    c2w, intr = np.asarray(cam["c2w"]), np.asarray(cam["intrinsics"])
    s = Scene(asset, sky, files, c2w, float(np.degrees(2 * np.arctan(SIZE / 2 / intr[1]))), np.empty(0), np.empty(0))
    ref = AssetRenderer(asset).render(
        torch.from_numpy(s.env()), torch.tensor(c2w[None]).float(), torch.tensor(intr[None]).float(), SIZE, SIZE,
        generator=torch.Generator().manual_seed(0),
    )[0].numpy()  # fmt: skip
    s.ref_rgb = io.srgb_encode(np.clip(ref[..., :3] * 2.0**EV, 0, None)).astype(np.float64)  # over black
    s.alpha = ref[..., 3]
    assert s.mask.mean() > 0.1, s.mask.mean()
    return s


def site(folder: Path, modules: Path, page: str, files: dict[str, Path]) -> Path:
    """A folder to serve: ``node_modules`` (a link to ``modules``), ``index.html`` = ``page``, and ``files``
    (name -> path, linked)."""
    folder.mkdir()
    (folder / "node_modules").symlink_to(modules, target_is_directory=True)
    (folder / "index.html").write_text(page)
    for name, path in files.items():
        (folder / name).symlink_to(path)
    return folder


def shoot_all(folder: Path, views: dict[str, tuple[str, np.ndarray]], c2w: np.ndarray, fov: float, profiles: Path):
    """Serve ``folder`` on 127.0.0.1 and shoot its index.html once per view (name -> (file, frame: asset -> the
    file's axes (3, 3))) at the camera ``c2w`` (asset axes); returns name -> canvas (SIZE, SIZE, 3)."""
    httpd, port = serve(folder)
    shots = {}
    try:
        for name, (file, frame) in views.items():
            q = {"file": file, "size": SIZE, "fov": fov, "matrix": three_camera(c2w, frame)}
            url = f"http://127.0.0.1:{port}/index.html#" + json.dumps(q).replace(" ", "")
            shots[name] = shoot(url, profiles / f"profile-{name}")
            assert shots[name].shape == (SIZE, SIZE, 3), shots[name].shape
    finally:
        httpd.shutdown()
    return shots


@pytest.fixture(scope="module")
def threejs_shots(scene, tmp_path_factory) -> dict[str, np.ndarray]:
    """three.js's canvases of the PLY (asset axes) and the GLB (glTF axes)."""
    from frng.apps.splat_axes import Y_UP

    root = tmp_path_factory.mktemp("threejs")
    files = {name: scene.files[name.rsplit(".", 1)[1]] for name in ("ball.ply", "ball.glb")}
    folder = site(root / "site", npm_packages(root, THREE), PAGE, files)
    views = {"ply": ("ball.ply", np.eye(3)), "glb": ("ball.glb", Y_UP)}
    return shoot_all(folder, views, scene.c2w, scene.fov, root)


def test_exported_ply_and_glb_in_threejs(scene, threejs_shots):

    shots, mask = threejs_shots, scene.mask
    scores = {fmt: _psnr(s[mask], scene.ref_rgb[mask]) for fmt, s in shots.items()}
    between = _psnr(shots["ply"][mask], shots["glb"][mask])
    background = {fmt: float(s[scene.background].mean()) for fmt, s in shots.items()}
    print(f"three.js vs render-asset over the object: PLY {scores['ply']:.1f} dB, GLB {scores['glb']:.1f} dB; "
          f"PLY vs GLB {between:.1f} dB; background mean {background}")  # fmt: skip
    assert all(v > PSNR_OBJECT_DB for v in scores.values()), scores
    assert between > PSNR_FORMATS_DB, between
    assert all(v < 0.05 for v in background.values()), background


def in_axes(baked, m: np.ndarray):
    """A :class:`~frng.apps.export.Baked` with everything taken through the orthogonal ``m`` (3, 3) (a rotation or
    a mirror) in the asset's axes: means and the fitted view directions by m; the Gaussians' frames by m det(m) (a
    rotation: -I leaves a Gaussian's covariance as it is)."""
    import torch

    from frng.apps.splat_axes import quat_multiply
    from frng.render.project import rotmat_to_quat

    q = rotmat_to_quat(torch.from_numpy(m * np.linalg.det(m))).numpy().reshape(1, 4)
    dirs = baked.fit_dirs @ torch.from_numpy(m).T.to(baked.fit_dirs)
    return dataclasses.replace(baked, means=baked.means @ m.T, quats=quat_multiply(q, baked.quats), fit_dirs=dirs)


# the same bake written in wrong axes: each map (3, 3) taken in SPZ's axes after the right conversion
WRONG_SPZ_AXES = {
    "mirrored front/back (z negated)": np.diag([1.0, 1.0, -1.0]),
    "upside down (y, z negated: RDF read as RUB)": np.diag([1.0, -1.0, -1.0]),
    "the asset's Z-up axes unconverted": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),  # splat_axes.Y_UP^-1
}


def test_exported_spz_in_spark(scene, threejs_shots, tmp_path):
    """Spark renders ``frng export-asset --format spz`` at the camera mapped into SPZ's RUB axes like render-asset
    and like three.js's PLY; the same bake in wrong axes (a mirror, an upside-down and an unconverted file) does
    not pass: the threshold tells the axes apart."""
    from frng.apps import export
    from frng.apps.asset import AssetRenderer
    from frng.apps.splat_axes import Y_UP

    modules = npm_packages(tmp_path, SPARK, THREE)
    t0 = time.monotonic()
    baked = export.bake(AssetRenderer(scene.asset), scene.env(), EV)
    ours, cli = export.spz_bytes(baked), gzip.decompress(scene.files["spz"].read_bytes())
    # the bake here is the command line's (up to float rounding), so the wrong files differ from it by the axes only
    assert len(ours) == len(cli) and ours[:16] == cli[:16], (len(ours), len(cli))
    assert np.mean(np.frombuffer(ours, np.uint8) != np.frombuffer(cli, np.uint8)) < 0.01
    assert export.spz_bytes(in_axes(baked, np.eye(3))) == ours  # and in_axes is exact where it changes nothing
    files = {"ball.spz": scene.files["spz"]}
    for i, m in enumerate(WRONG_SPZ_AXES.values()):  # m in SPZ's axes is Y_UP^-1 m Y_UP in the asset's
        files[f"wrong{i}.spz"] = tmp_path / f"wrong{i}.spz"
        files[f"wrong{i}.spz"].write_bytes(gzip.compress(export.spz_bytes(in_axes(baked, Y_UP.T @ m @ Y_UP))))
    folder = site(tmp_path / "site", modules, SPARK_PAGE, files)
    views = {name: (name, Y_UP) for name in files}
    shots = shoot_all(folder, views, scene.c2w, scene.fov, tmp_path)
    mask = scene.mask
    spz, ply = shots.pop("ball.spz"), threejs_shots["ply"]
    score, against_ply = _psnr(spz[mask], scene.ref_rgb[mask]), _psnr(spz[mask], ply[mask])
    wrong = {what: _psnr(shots[f"wrong{i}.spz"][mask], scene.ref_rgb[mask]) for i, what in enumerate(WRONG_SPZ_AXES)}
    background = float(spz[scene.background].mean())
    print(f"Spark SPZ vs render-asset over the object: {score:.1f} dB; vs three.js's PLY {against_ply:.1f} dB; "
          f"wrong axes: {', '.join(f'{k} {v:.1f} dB' for k, v in wrong.items())}; background mean {background:.4f}; "
          f"{time.monotonic() - t0:.1f} s")  # fmt: skip
    assert score > PSNR_SPZ_DB, score
    assert against_ply > PSNR_SPZ_PLY_DB, against_ply
    assert all(v < PSNR_SPZ_DB for v in wrong.values()), wrong
    assert background < 0.05, background


def test_readme_figure_of_a_trained_asset(browser_paths, tmp_path):
    """The README's "Take it elsewhere" picture, made only when asked: ``FRNG_EXPORT_FIGURE=OUT.png
    FRNG_EXPORT_FIGURE_ASSET=ASSET FRNG_EXPORT_FIGURE_ENV=MAP.exr [FRNG_EXPORT_FIGURE_EV=EV]``: the asset exported
    as GLB by ``frng export-asset`` (rotation :data:`ROTATION`), rendered by three.js in headless Chromium at three
    turntable cameras, each beside ``frng render-asset`` at the same camera and light (three.js top row,
    render-asset bottom row); the PSNR over the object printed. The made figure is checked like the ball (three.js
    within :data:`PSNR_OBJECT_DB` of render-asset)."""
    import torch

    from frng import io
    from frng.apps.asset import AssetRenderer
    from frng.apps.render_asset import turntable
    from frng.apps.splat_axes import Y_UP
    from frng.render import envmap

    out, asset = os.environ.get("FRNG_EXPORT_FIGURE"), os.environ.get("FRNG_EXPORT_FIGURE_ASSET")
    if not (out and asset):
        pytest.skip("makes the README figure: set FRNG_EXPORT_FIGURE and FRNG_EXPORT_FIGURE_ASSET (and _ENV, _EV)")
    sky, ev = Path(os.environ["FRNG_EXPORT_FIGURE_ENV"]), float(os.environ.get("FRNG_EXPORT_FIGURE_EV", "0"))
    glb = tmp_path / "asset.glb"
    t0 = time.monotonic()
    r = _frng("export-asset", asset, "--env", sky, "--rotation", ROTATION, "--exposure", ev, "--out", glb)
    assert r.returncode == 0, r.stdout + r.stderr
    print(f"\nexport: {time.monotonic() - t0:.1f} s; {r.stdout.strip()}")
    folder = site(tmp_path / "site", npm_packages(tmp_path, THREE), PAGE, {"asset.glb": glb})
    env = torch.from_numpy(envmap.rotate_z(envmap.read(sky), ROTATION))
    renderer, top, bottom, scores = AssetRenderer(Path(asset)), [], [], []
    for cam in turntable(3, 25.0, 3.0, 40.0, SIZE):
        c2w, intr = np.asarray(cam["c2w"]), np.asarray(cam["intrinsics"])
        fov = float(np.degrees(2 * np.arctan(SIZE / 2 / intr[1])))
        shot = shoot_all(folder, {"glb": ("asset.glb", Y_UP)}, c2w, fov, tmp_path)["glb"]
        ref = renderer.render(
            env, torch.tensor(c2w[None]).float(), torch.tensor(intr[None]).float(), SIZE, SIZE,
            generator=torch.Generator().manual_seed(0),
        )[0].numpy()  # fmt: skip
        ref_rgb = io.srgb_encode(np.clip(ref[..., :3] * 2.0**ev, 0, None)).astype(np.float64)
        mask = ref[..., 3] > 0.5
        scores.append(_psnr(shot[mask], ref_rgb[mask]))
        top.append(shot)
        bottom.append(ref_rgb)
    gap = lambda: np.ones((SIZE, 4, 3))  # noqa: E731
    row = lambda ims: np.concatenate(sum(([im, gap()] for im in ims), [])[:-1], 1)  # noqa: E731
    figure = np.concatenate([row(top), np.ones((4, row(top).shape[1], 3)), row(bottom)], 0)
    io.write_png(Path(out), figure.astype(np.float32))
    print(f"three.js GLB vs render-asset over the object: {', '.join(f'{s:.1f}' for s in scores)} dB -> {out}")
    assert all(s > PSNR_OBJECT_DB for s in scores), scores
