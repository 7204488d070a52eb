"""`frng view` in a real browser: the viewer started on the smoke tier's asset (the full run's ``asset/`` of its test
object), the page loaded in Debian's headless Chromium (selenium + chromedriver), a rendered frame waited for and
screenshotted; the object is where the asset projects; the map switched in the page's picker, and the new frame is
what ``frng render-asset`` renders for the same camera and map. Plus the one-line errors of bad input.

The trained smoke tier comes from ``FRNG_SMOKE_RESULTS`` when set, else the test session's smoke run
(``conftest.smoke_pipeline``, shared with tests/test_smoke_workflow.py and tests/test_reconstruct.py).
Without /usr/bin/chromium this module skips, except on CI (``CI`` or ``FRNG_REQUIRE_BROWSER`` set, as .ci/run does
after installing it), where it fails.
"""

from __future__ import annotations

import io as _io
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import browser
import numpy as np
import pytest
from conftest import ROOT

WINDOW = (1200, 800)  # browser window; the viewport canvas is the page's inner size
RESOLUTION = 96  # frame height the viewer renders at (the default tier's)
# The saved frame is rendered by render-asset's own code from the saved camera and map: bit-identical to the command
# line (measured: inf dB); the screenshot is that frame PNG-encoded and bilinearly upscaled by the browser, compared
# with the same frame upscaled by Pillow over the canvas away from the panel (measured 39-40 dB; under the other map
# the same comparison gives ~21 dB).
PSNR_SAVED_DB = 60.0
PSNR_SCREEN_DB = 30.0


@pytest.fixture(scope="module")
def browser_paths():
    return browser.paths()


@pytest.fixture(scope="module")
def smoke_asset(request) -> tuple[Path, Path]:
    """(results folder, the full run's asset of its first test object)."""
    from frng.plan.layout import Layout, RelightFolder

    given = os.environ.get("FRNG_SMOKE_RESULTS")
    results = Path(given) if given else request.getfixturevalue("smoke_pipeline")
    assets = sorted(Path(RelightFolder(Layout(results).relight_run("full", "*")).asset()).parent.parent.glob("*/asset"))
    assert assets, f"{results}: no relit test object with an asset"
    return Path(results), assets[0]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _frng(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "frng", *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=300, **kw
    )


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


class Page:
    """The viewer's page in headless Chromium."""

    def __init__(self, url: str, profile: Path):
        self.driver = browser.chrome(profile, WINDOW, ("--disable-quic",))
        self.driver.get(url)

    def text(self) -> str:
        from selenium.webdriver.common.by import By

        return self.driver.find_element(By.TAG_NAME, "body").text

    def wait_text(self, *needles: str, after: int = 0, timeout: float = 120.0, settle: float = 1.0) -> str:
        """Wait until the status line reads a full frame numbered above ``after`` with every needle, unchanged for
        ``settle`` seconds (the camera at rest: no newer frame on its way); returns it."""
        t0, seen, since = time.monotonic(), None, 0.0
        while time.monotonic() - t0 < timeout:
            line = next((s for s in self.text().splitlines() if s.startswith("full frame ")), "")
            if line and int(line.split()[2].rstrip(":")) > after and all(n in line for n in needles):
                if line != seen:
                    seen, since = line, time.monotonic()
                elif time.monotonic() - since >= settle:
                    return line
            else:
                seen = None
            time.sleep(0.2)
        raise AssertionError(f"no full frame with {needles} after {timeout} s; page text: {self.text()[-600:]}")

    def screenshot(self) -> np.ndarray:
        """The page as uint8 RGB, once two consecutive screenshots agree (the frame's texture is drawn)."""
        import imageio.v3 as iio

        prev = None
        for _ in range(40):
            img = iio.imread(_io.BytesIO(self.driver.get_screenshot_as_png()))[..., :3]
            if prev is not None and np.array_equal(img, prev):
                return img
            prev = img
            time.sleep(0.25)
        return prev

    def pick(self, label: str, option: str) -> None:
        """Choose ``option`` in the dropdown whose current value starts with ``label``."""
        from selenium.webdriver.common.by import By

        box = next(
            e
            for e in self.driver.find_elements(By.CSS_SELECTOR, "input.mantine-Select-input")
            if (e.get_attribute("value") or "").startswith(label) and e.is_displayed()
        )
        box.click()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 10:
            opts = [o for o in self.driver.find_elements(By.CSS_SELECTOR, "[role=option]") if o.text == option]
            if opts:
                opts[0].click()
                return
            time.sleep(0.1)
        shown = [o.text for o in self.driver.find_elements(By.CSS_SELECTOR, "[role=option]")]
        raise AssertionError(f"no option {option!r} in the picker; it shows {shown}")

    def click(self, text: str) -> None:
        from selenium.webdriver.common.by import By

        # textContent, not .text: a button scrolled out of the panel's view has an empty .text
        buttons = self.driver.find_elements(By.TAG_NAME, "button")
        found = [b for b in buttons if (b.get_attribute("textContent") or "").strip() == text]
        assert found, f"no button {text!r}; the page has {[b.get_attribute('textContent') for b in buttons]}"
        self.driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", found[0])
        found[0].click()

    def type_number(self, index: int, value: str) -> None:
        """Type ``value`` into the panel's ``index``-th number box (a slider's) and press Enter."""
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys

        boxes = [
            e for e in self.driver.find_elements(By.CSS_SELECTOR, "input.mantine-NumberInput-input") if e.is_displayed()
        ]
        boxes[index].click()
        boxes[index].send_keys(Keys.CONTROL, "a")
        boxes[index].send_keys(value, Keys.ENTER)

    def images(self) -> list:
        """The panel's images (the map thumbnail, a test object's side by side)."""
        from selenium.webdriver.common.by import By

        return [
            i
            for i in self.driver.find_elements(By.TAG_NAME, "img")
            if (i.get_attribute("src") or "").startswith("blob:")
        ]

    def close(self) -> None:
        self.driver.quit()


def _start(args: list, log: Path) -> subprocess.Popen:
    with open(log, "w") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "frng", "view", *map(str, args)], cwd=ROOT, stdout=f, stderr=subprocess.STDOUT
        )


def _wait_listening(proc: subprocess.Popen, port: int, log: Path, timeout: float = 120.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        assert proc.poll() is None, log.read_text()[-2000:]
        if "frng view: http://" in log.read_text():
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    return
        time.sleep(0.2)
    raise AssertionError(f"viewer not listening after {timeout} s: {log.read_text()[-2000:]}")


def _wait_file(path: Path, timeout: float = 60.0) -> None:
    t0 = time.monotonic()
    while not path.exists():
        assert time.monotonic() - t0 < timeout, f"{path} not written after {timeout} s"
        time.sleep(0.2)


def _canvas_compare(shot: np.ndarray, frame_rgb: np.ndarray, keep: np.ndarray) -> float:
    """PSNR of the screenshot against a frame (uint8 (h, w, 3)) upscaled bilinearly to the page, over ``keep``."""
    from PIL import Image

    H, W = shot.shape[:2]
    up = np.asarray(Image.fromarray(frame_rgb).resize((W, H), Image.BILINEAR))
    return _psnr(shot[keep] / 255.0, up[keep] / 255.0)


def test_viewer_in_a_browser(smoke_asset, browser_paths, tmp_path):
    import torch

    from frng import camera, io
    from frng.apps.asset import load_asset
    from frng.apps.view_scene import display
    from frng.plan.layout import Layout
    from frng.render import envmap

    results, asset = smoke_asset
    index = io.read_json(Layout(results).envmap_index())
    # the picker's test maps: one per test base map (the first of its maps: one per object and light draw), less
    # the asset's object's input light (listed as the input light)
    inputs = set(io.read_json(Layout(results).object_meta(asset.parent.name))["input_lights"])
    firsts: dict[str, str] = {}
    for m in index["maps"]:
        if m["split"] == "test":
            firsts.setdefault(m["base"], m["name"])
    test_maps = [n for n in firsts.values() if n not in inputs]
    other = next(m["name"] for m in index["maps"] if m["split"] == "train")  # a map given with --env
    other_file = Path(Layout(results).envmap(other))
    port = _free_port()
    log, out = tmp_path / "view.log", tmp_path / "saved"
    proc = _start(
        [asset, "--env", other_file, "--port", port, "--out", out, "--device", "cpu", "--resolution", RESOLUTION], log
    )
    page = cli_proc = None
    try:
        _wait_listening(proc, port, log)
        page = Page(f"http://127.0.0.1:{port}", tmp_path / "profile")
        first = page.wait_text(f"{other} · file")  # the first map of the picker: the --env file
        assert f"{RESOLUTION} px" in first or f"×{RESOLUTION} px" in first, first
        shot0 = page.screenshot()
        H, W = shot0.shape[:2]
        keep = np.ones((H, W), bool)
        keep[:, W - 360 :] = False  # the panel
        keep[:180, :340] = False  # the software-WebGL notice
        page.click("Save frame")
        _wait_file(out / "frame_000" / "view.json")
        saved0 = io.read_json(out / "frame_000" / "cameras.json")["cameras"][0]
        assert (saved0["height"], saved0["width"]) == (RESOLUTION, round(RESOLUTION * W / H)), (saved0, W, H)

        # the object is where the asset projects: its opaque Gaussians' centres land on non-background pixels
        g, *_ = load_asset(asset)
        pts = g.means[g.opacities.reshape(-1) > 0.5]
        scale = H / saved0["height"]
        uv, depth = camera.project(
            pts, torch.tensor([saved0["c2w"]]).float(), torch.tensor([saved0["intrinsics"]]).float() * scale
        )
        uv, depth = uv[0], depth[0]
        uv = uv.round().long().numpy()
        inside = (depth.numpy() > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        uv = uv[inside]
        uv = uv[keep[uv[:, 1], uv[:, 0]]]
        assert len(uv) > 100, len(uv)
        bg = display(np.zeros((1, 1, 4), np.float32))[0, 0].astype(int)
        differs = np.abs(shot0.astype(int) - bg).max(-1) > 12
        on_object = differs[uv[:, 1], uv[:, 0]].mean()
        (x0, y0), (x1, y1), m = uv.min(0), uv.max(0), int(0.1 * H)
        away = keep.copy()  # well outside where the asset projects: background
        away[max(y0 - m, 0) : y1 + m, max(x0 - m, 0) : x1 + m] = False
        corner = differs[away]
        print(f"\nobject pixels where the asset projects: {on_object:.3f}; away from it: {corner.mean():.4f}")
        assert on_object > 0.9 and corner.size > 0 and corner.mean() < 0.02, (on_object, corner.mean())

        # switch the map in the page: the new frame is render-asset's for the saved camera and the new map
        n = int(first.split()[2].rstrip(":"))
        page.pick(f"{other} · file", f"{test_maps[0]} · test map")
        page.wait_text(f"{test_maps[0]} · test map", after=n)
        shot1 = page.screenshot()
        page.click("Save frame")
        _wait_file(out / "frame_001" / "view.json")
        saved1 = io.read_json(out / "frame_001" / "cameras.json")["cameras"][0]
        assert {**saved1, "name": ""} == {**saved0, "name": ""}  # the camera did not move
        ref = tmp_path / "ref"  # render-asset on the command line, while the page goes on
        cli_proc = subprocess.Popen(
            [sys.executable, "-m", "frng", "render-asset", str(asset), "--env", Layout(results).envmap(test_maps[0]),
             "--cameras", str(out / "frame_001" / "cameras.json"), "--out", str(ref), "--device", "cpu"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip

        # the rotation slider (its number box): the saved light is the map rotated about Z, the frame re-shaded
        n = int(page.wait_text(after=0).split()[2].rstrip(":"))
        page.type_number(0, "90")
        page.wait_text(f"{test_maps[0]} · test map", after=n)
        page.click("Save frame")
        _wait_file(out / "frame_002" / "view.json")
        assert io.read_json(out / "frame_002" / "view.json")["rotation_deg"] == 90.0
        test_map = envmap.read(Layout(results).envmap(test_maps[0]))
        np.testing.assert_allclose(envmap.read(out / "frame_002" / "light.exr"), envmap.rotate_z(test_map, 90.0))
        turned = io.read_rgba(out / "frame_002" / "frame_002.exr")
        assert np.abs(turned - io.read_rgba(out / "frame_001" / "frame_001.exr")).max() > 1e-3

        # a relit test object's asset: picking a target view and light moves the camera there, picks the light and
        # shows the ground truth, F-RNG and the backbone side by side
        oid = asset.parent.name
        rec = io.read_json(Layout(results).relight_record("full", oid))
        target, light = rec["target_views"][0], rec["lights"][-1]
        cam = next(c for c in io.read_json(Layout(results).object_meta(oid))["views"]["targets"] if c["name"] == target)
        n = int(page.wait_text(after=0).split()[2].rstrip(":"))
        page.pick("(free camera)", f"{target} · {light}")
        page.wait_text(light, after=n)
        page.click("Save frame")
        _wait_file(out / "frame_003" / "view.json")
        saved2 = io.read_json(out / "frame_003" / "cameras.json")["cameras"][0]
        np.testing.assert_allclose(saved2["c2w"], cam["c2w"], atol=2e-3)
        fov = lambda c: c["intrinsics"][1] / c["height"]  # noqa: E731
        assert abs(fov(saved2) / fov(cam) - 1) < 1e-3, (saved2, cam)
        picked = io.read_json(out / "frame_003" / "view.json")
        assert picked["map"].startswith(f"{light} · ") and picked["rotation_deg"] == 0.0
        shown = [i for i in page.images() if i.is_displayed() and i.rect["width"] > 3 * i.rect["height"] > 0]
        assert len(shown) == 1, [i.rect for i in page.images()]  # the side-by-side strip (the thumbnail is 2:1)

        cli_out = cli_proc.communicate(timeout=300)[0]
        assert cli_proc.returncode == 0, cli_out
        cli = io.read_rgba(ref / "frame_001.exr")
        saved = io.read_rgba(out / "frame_001" / "frame_001.exr")
        psnr_saved = _psnr(np.clip(saved, 0, 1), np.clip(cli, 0, 1))
        old = io.read_rgba(out / "frame_000" / "frame_000.exr")  # render-asset's frame of the first map
        psnr_new = _canvas_compare(shot1, display(cli), keep)
        psnr_old = _canvas_compare(shot1, display(old), keep)
        psnr_first = _canvas_compare(shot0, display(old), keep)
        print(
            f"saved vs render-asset: {psnr_saved:.1f} dB; screen after the switch vs render-asset (new map): "
            f"{psnr_new:.1f} dB, (old map): {psnr_old:.1f} dB; first screen vs render-asset (first map): "
            f"{psnr_first:.1f} dB"
        )
        assert psnr_saved > PSNR_SAVED_DB
        assert psnr_new > PSNR_SCREEN_DB and psnr_first > PSNR_SCREEN_DB, (psnr_new, psnr_first)
        assert psnr_old < psnr_new - 3.0, (psnr_old, psnr_new)  # the frame changed with the map
        assert np.abs(shot1.astype(int) - shot0.astype(int))[keep].mean() > 0.5
        view = io.read_json(out / "frame_001" / "view.json")
        assert view["map"] == f"{test_maps[0]} · test map" and view["rotation_deg"] == 0.0

    finally:
        if cli_proc is not None and cli_proc.poll() is None:
            cli_proc.kill()
            cli_proc.wait()
        if page is not None:
            page.close()
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode == 0, log.read_text()[-2000:]


def test_bad_input_one_line_nothing_left_running(smoke_asset, tmp_path, capsys):
    """A missing or malformed asset, a map that is not 2:1, a port in use: one line on stderr naming the file or
    option, exit status 2, no thread of the viewer left running (in-process: the stage's run), and for the port a
    ``frng view`` process that exits by itself."""
    import signal
    import threading

    from frng import cli, io

    results, asset = smoke_asset
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "asset.json").write_text("{not json")
    (bad / "gaussians.ply").write_text("ply\n")
    (bad / "decoder.safetensors").write_bytes(b"")
    wide = tmp_path / "wide.exr"
    io.write_exr(wide, np.ones((8, 24, 3), np.float32))
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cases = {
            "missing": ([tmp_path / "nope"], "nope"),
            "malformed": ([bad], "asset.json"),
            "not 2:1": ([asset, "--env", wide], "wide.exr"),
            "port in use": ([asset, "--port", port], f"--port {port}"),
        }
        threads, sigterm = set(threading.enumerate()), signal.getsignal(signal.SIGTERM)
        for what, (args, names) in cases.items():
            parsed = cli.stage_parser("view").parse_args([*map(str, args), "--device", "cpu"])
            rc = parsed._run(parsed)
            lines = capsys.readouterr().err.strip().splitlines()
            assert rc == 2 and len(lines) == 1 and names in lines[0], (what, lines)
            assert lines[0].startswith("frng view: error: "), (what, lines)
            assert not [t for t in set(threading.enumerate()) - threads if t.is_alive()], what
            assert signal.getsignal(signal.SIGTERM) == sigterm, what
        r = _frng("view", asset, "--port", port, "--device", "cpu")
        assert r.returncode == 2 and r.stderr.strip() == lines[0] and not r.stdout.strip(), (r.stdout, r.stderr)


def test_viewport_camera_is_visers_and_frngs():
    """A viewport pose as viser reports it (wxyz of the camera-to-world rotation, position, vertical fov) is the
    OpenCV camera frng renders with, and :func:`camera_pose` (how the viewer moves a viewport to a target view) is
    its inverse."""
    import viser.transforms as vtf

    from frng import camera
    from frng.apps.view_scene import camera_pose, frame_size, quat_to_matrix, viewport_camera

    rng = np.random.default_rng(0)
    for _ in range(5):
        eye = camera.spherical_to_cartesian(rng.uniform(0, 360), rng.uniform(-60, 60), rng.uniform(2, 5))
        c2w = camera.look_at(eye)
        W, H = frame_size(96, rng.uniform(0.5, 2.0))
        intr = camera.intrinsics_from_fov(rng.uniform(20, 60) * H / W, W, H)  # any focal length, square pixels
        wxyz = vtf.SO3.from_matrix(c2w[:3, :3]).wxyz
        np.testing.assert_allclose(quat_to_matrix(wxyz), c2w[:3, :3], atol=1e-9)
        pose = camera_pose(c2w, intr, H)
        c2w2, intr2 = viewport_camera(pose["position"], wxyz, pose["fov"], W, H)
        np.testing.assert_allclose(c2w2, c2w, atol=1e-9)
        np.testing.assert_allclose(intr2, intr, rtol=1e-9)
        np.testing.assert_allclose(pose["up_direction"], -c2w[:3, 1], atol=1e-12)
        forward = (pose["look_at"] - pose["position"]) / np.linalg.norm(pose["look_at"] - pose["position"])
        np.testing.assert_allclose(forward, c2w[:3, 2], atol=1e-9)


def test_object_opens_f_rng_plus_and_either_asset_is_a_test_object(smoke_asset):
    """``--object`` shows F-RNG+ (the run that relights photos best) where the results folder relit the object with
    it; the full run's asset, opened as an ASSET, is still recognised as that test object's (with full's images)."""
    from frng.apps.view_scene import TestObject, shown_run
    from frng.plan.layout import Layout, RelightFolder
    from frng.plan.variants import VIEW_RUN

    results, asset = smoke_asset
    oid = asset.parent.name
    has_plus = Path(Layout(results).relight_record(VIEW_RUN, oid)).exists()
    assert shown_run(results, oid) == (VIEW_RUN if has_plus else "full")
    shown = TestObject(results, oid)
    assert set(shown.runs.values()) == {None, shown.run, "backbone"}
    assert TestObject(results, oid, "full").runs["F-RNG"] == "full"
    if has_plus:
        assert shown.runs["F-RNG+"] == VIEW_RUN
        assert (Path(RelightFolder(Layout(results).relight_run(VIEW_RUN, oid)).asset()) / "asset.json").exists()
