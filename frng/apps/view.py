"""``frng view``: an interactive relighting viewer in the browser for a relightable asset (:mod:`frng.apps.asset`).

A local web server on ``127.0.0.1`` built on viser (pinned in requirements.txt): the browser shows viser's viewport
with its orbit / zoom / pan camera; every camera or light change is rendered on the server by the asset's own
decoder (:class:`frng.apps.asset.AssetRenderer`, the path ``frng render-asset`` renders with; no training code) and sent
back as the viewport's background image. On a headless machine: ``ssh -L 8080:127.0.0.1:8080 HOST`` and open
``http://127.0.0.1:8080`` locally.

What a client sees (each browser tab has its own camera and settings):

- the frame, rendered at the browser's aspect ratio with the viewport's vertical field of view (OpenCV camera:
  viser's ``wxyz``/``position`` are the camera-to-world rotation and centre, world Z up), composited over a dark grey
  (:data:`frng.apps.view_scene.BACKGROUND`);
- progressive quality: while the camera or a slider moves, frames at ``1 / LOW_DIVISOR`` of the resolution,
  ``1 / LOW_SPP_DIVISOR`` of the light samples and a coarser rasterizer (:data:`~frng.apps.view_scene.LOW_RASTER`); once nothing changed
  for :data:`REST_S` seconds, the full frame (the resolution's height, the asset's ``shading.spp_infer`` or
  ``--spp``, the asset's rasterizer settings; the light samples seeded as ``frng render-asset --seed 0``, so a full
  frame is the image render-asset writes for the same camera and map);
- a map picker (the tier's test maps, the asset's input light, files given with ``--env``), a rotation slider
  about world Z (:func:`frng.render.envmap.rotate_z`) and an exposure slider (EV; scales the object's radiance on screen),
  the rotated map's thumbnail, and the last frame's quality, size, light samples and time;
- "Save frame": the current camera and map rendered by ``frng render-asset`` itself (its parser and
  :func:`frng.apps.render_asset.render`) into ``{out}/frame_NNN/``: ``frame_NNN.exr`` (linear premultiplied RGBA),
  ``frame_NNN.png`` (sRGB, straight alpha) and ``cameras.json`` (the ``--cameras`` format) as render-asset writes
  them, ``light.exr`` (the map as rotated), ``display.png`` (the frame as shown: exposure, background) and
  ``view.json`` (map, rotation, exposure, samples and the render-asset command that renders it again);
- "Export splat": the asset baked under the map, rotation and exposure on screen by ``frng export-asset`` itself
  (:mod:`frng.apps.export`) into ``{out}/export_NNN.{ply|spz|glb}`` (the format picked beside the button), with
  ``export_NNN.json`` (the light and the command);
- for a relit test object (``--object``, or an ASSET that is a results folder's ``relight/full/{obj}/asset``): its
  target views and lights; picking one moves the camera to that view, picks its light and shows the ground truth,
  F-RNG+'s relit image (the paper's F-RNG where F-RNG+ was not trained) and the backbone's side by side (the results folder's images, :mod:`frng.plan.layout`).

Everything that can fail on the user's input (the asset, the maps, the config, the port) is checked before the
server starts, as :class:`ViewError` (or the readers' :class:`~frng.apps.asset.AssetError` /
:class:`~frng.apps.capture.CaptureError`): one line, nothing left running.

This module is the server (viser, the panel, one session per browser tab) and its opening from the command line's
arguments; what it shows -- the maps, the cameras, the frames, a test object's images -- is
:mod:`frng.apps.view_scene`, which imports no viser. The light ``frng`` modules are imported at the top; torch,
viser and the exporter (:mod:`frng.apps.export`, which imports torch) only where a frame is rendered, the server
starts or a splat is exported, so that ``frng view --help`` imports no torch.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from io import StringIO
from pathlib import Path

import numpy as np

from frng import confine, io
from frng.apps import render_asset
from frng.apps.render_asset import MAX_RESOLUTION, MAX_SPP, turntable
from frng.apps.view_scene import (
    TILE_MIN,
    FrameRenderer,
    Light,
    TestObject,
    ViewError,
    camera_pose,
    camera_record,
    client_camera,
    client_light,
    collect_lights,
    display,
    frame_size,
    quat_to_matrix,
    results_of_asset,
    rotated,
    thumbnail,
    viewport_camera,
)
from frng.plan.layout import Layout, RelightFolder
from frng.plan.variants import ASSET_RUNS
from frng.render import envmap

HOST = "127.0.0.1"
DEFAULT_PORT = 8080
REST_S = 0.3  # nothing changed for this long: render the full-quality frame
LOW_DIVISOR = 2  # while moving: the resolution divided by this
LOW_SPP_DIVISOR = 4  # while moving: the light samples divided by this (at least 1)
MIN_LOW_HEIGHT = 16  # ...but frames at least this tall
MAX_ASPECT = 4  # frames are at most 4:1 (or 1:4), whatever the browser window's shape
FALLBACK_RESOLUTION = 64  # frame height when neither the asset's rig nor an object's views give one
FULL, LOW = "full", "low"  # frame qualities, as the status line names them


LOCAL_NAMES = ("127.0.0.1", "localhost")  # the Host / Origin names the viewer answers (frng.confine.local_request)


# -- the server ---------------------------------------------------------------------------------------------------


_SERVE_LOCK = threading.Lock()


@contextlib.contextmanager
def own_page_only(port: int, log=print):
    """While viser starts its server inside this block, every HTTP request and websocket handshake it gets first
    passes :func:`frng.confine.local_request` (Host 127.0.0.1 / localhost on ``port``; an Origin, where sent, the
    same): anything else is answered 403 and logged in one line. What Jupyter and TensorBoard do: a web page on
    another origin cannot drive the viewer, and a DNS-rebound name (Host: evil.example) is not served.

    viser (``viser.infra._infra``) passes its ``process_request`` hook to ``websockets.asyncio.server.serve`` and
    exposes no option for it: ``serve`` is wrapped for the duration of the start (viser waits until it listens)."""
    import websockets.asyncio.server as ws_server

    with _SERVE_LOCK:
        real = ws_server.serve

        def serve(*args, **kwargs):
            inner = kwargs.get("process_request")

            def process_request(connection, request):
                refusal = confine.local_request(request.headers, port, LOCAL_NAMES)
                if refusal is not None:
                    log(f"frng view: refused {request.path[:80]!r}: {refusal}")
                    return connection.respond(403, f"frng view: {refusal}\n")
                return inner(connection, request) if inner is not None else None

            kwargs["process_request"] = process_request
            return real(*args, **kwargs)

        ws_server.serve = serve
        try:
            yield
        finally:
            ws_server.serve = real


def check_port(port: int, host: str = HOST) -> None:
    """A :class:`ViewError` when ``host:port`` cannot be listened on (in use, or not a port)."""
    if not 1 <= int(port) <= 65535:
        raise ViewError(f"--port {port}: not a TCP port (1-65535)")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, int(port)))
        except OSError as e:
            raise ViewError(
                f"--port {port}: cannot listen on {host}:{port} ({e.strerror or e}); pick another port"
            ) from None


@dataclass
class Settings:
    """What a viewer was opened with: frame height and light samples at full quality, the save folder, the
    initial camera (c2w, intrinsics, height), the render-asset options a saved frame is rendered with."""

    resolution: int
    spp: int | None
    out: Path
    initial: tuple[np.ndarray, np.ndarray, int]
    seed: int = 0


class Viewer:
    """The viser server and one :class:`_Session` per browser tab. :meth:`start` listens (checked first),
    :meth:`stop` ends every thread it started."""

    def __init__(
        self, frames: FrameRenderer, lights: list[Light], settings: Settings, test_object: TestObject | None = None
    ):
        self.frames, self.lights, self.settings, self.test_object = frames, lights, settings, test_object
        self.by_label = {x.label: x for x in lights}
        self.server = None
        self.sessions: dict[int, _Session] = {}
        self._saves = 0
        self._save_lock = threading.Lock()
        self._rotated: dict[tuple[str, float], np.ndarray] = {}
        self._env_lock = threading.Lock()
        self.log = lambda line: print(line, flush=True)  # one line per refused request or ignored client value

    def start(self, port: int) -> str:
        """Listen on 127.0.0.1:port; returns the URL. A :class:`ViewError` (nothing left running) when the port is
        taken."""
        import viser

        check_port(port)
        with contextlib.redirect_stdout(StringIO()), own_page_only(int(port), self.log):  # banner: serve() prints
            server = viser.ViserServer(host=HOST, port=int(port), label="frng view", verbose=False)
        if server.get_port() != int(port):  # taken between the check and the bind: viser moved on to another
            with contextlib.redirect_stdout(StringIO()):
                server.stop()
            raise ViewError(f"--port {port}: cannot listen on {HOST}:{port} (in use); pick another port")
        self.server = server
        c2w, intr, height = self.settings.initial
        pose = camera_pose(c2w, intr, height)
        server.initial_camera.position = tuple(pose["position"])
        server.initial_camera.look_at = tuple(pose["look_at"])
        server.initial_camera.up = tuple(pose["up_direction"])
        server.initial_camera.fov = pose["fov"]
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)
        return f"http://{HOST}:{port}"

    def warm_up(self) -> float:
        """Render the first camera's frame once (torch's first calls are several times slower than the next ones),
        so the first frame a browser gets is timed as every later one; returns the seconds it took."""
        c2w, intr, height = self.settings.initial
        w, h = frame_size(self.settings.resolution, 1.0)
        f = intr[1] * h / height
        spp = self.settings.spp or self.frames.spp
        _, s = self.frames.frame(c2w, np.array([f, f, w / 2, h / 2]), w, h, self.lights[0].image, spp)
        return s

    def stop(self) -> None:
        """Stop every tab's render thread (waiting for a frame in flight) and the server."""
        sessions = list(self.sessions.values())
        for s in sessions:
            s.close()
        for s in sessions:
            s.thread.join(timeout=30)
        if self.server is not None:
            with contextlib.redirect_stdout(StringIO()):  # viser's "Server stopped"
                self.server.stop()
            self.server = None

    def _connect(self, client) -> None:
        self.sessions[client.client_id] = _Session(self, client)

    def _disconnect(self, client) -> None:
        s = self.sessions.pop(client.client_id, None)
        if s is not None:
            s.close()

    def env(self, label: str, rotation: float) -> np.ndarray:
        """The map ``label`` rotated by ``rotation`` degrees (cached)."""
        key = (label, float(rotation))
        with self._env_lock:
            if key not in self._rotated:
                if len(self._rotated) > 64:
                    self._rotated.clear()
                self._rotated[key] = rotated(self.by_label[label], rotation)
            return self._rotated[key]

    def save(self, c2w: np.ndarray, intr: np.ndarray, width: int, height: int, label: str, rotation: float,
             exposure: float) -> Path:  # fmt: skip
        """Render the view with ``frng render-asset`` (its own parser and :func:`~frng.apps.render_asset.render`)
        into ``{out}/frame_NNN/`` (module docstring); returns that folder."""

        st = self.settings
        with self._save_lock:
            st.out.mkdir(parents=True, exist_ok=True)
            while (st.out / f"frame_{self._saves:03d}").exists():
                self._saves += 1
            name = f"frame_{self._saves:03d}"
            self._saves += 1
        folder = st.out / name
        with tempfile.TemporaryDirectory(prefix=f".{name}-", dir=st.out) as tmp:
            cam_file, light_file = Path(tmp) / "camera.json", Path(tmp) / "light.exr"
            io.write_json(cam_file, {"cameras": [camera_record(name, c2w, intr, width, height)]})
            envmap.write(light_file, self.env(label, rotation))
            argv = [str(self.frames.asset), "--env", str(light_file), "--out", str(folder), "--cameras", str(cam_file)]
            argv += ["--device", str(self.frames.device), "--seed", str(st.seed)]
            argv += ["--spp", str(st.spp)] if st.spp else []
            parser = argparse.ArgumentParser(prog="frng render-asset")
            render_asset.add_arguments(parser)
            with self.frames._lock:  # one render at a time on the device
                render_asset.render(parser.parse_args(argv))
            os.replace(light_file, folder / "light.exr")
        rerun = ["frng render-asset", str(self.frames.asset), "--env", str(folder / "light.exr"), "--cameras"]
        rerun += [str(folder / "cameras.json"), "--out", "OUT", "--seed", str(st.seed)]
        rerun += ["--spp", str(st.spp)] if st.spp else []
        io.write_png(folder / "display.png", display(io.read_rgba(folder / f"{name}.exr"), exposure))
        io.write_json(
            folder / "view.json",
            {
                "map": label,
                "map_file": str(self.by_label[label].path),
                "rotation_deg": float(rotation),
                "exposure_ev": float(exposure),
                "spp": st.spp or self.frames.spp,
                "seed": st.seed,
                "device": str(self.frames.device),
                "command": " ".join(rerun),
            },
        )
        return folder

    def export(self, label: str, rotation: float, exposure: float, fmt: str) -> tuple[Path, float]:
        """Bake the asset under the map ``label`` rotated by ``rotation`` degrees at ``exposure`` EV with
        ``frng export-asset`` itself (its parser and :func:`~frng.apps.export.export`) into
        ``{out}/export_NNN.{fmt}`` (and ``export_NNN.json``: the light and the command that writes it again);
        returns (that file, the SH fit's held-out PSNR)."""
        from frng.apps import export

        st = self.settings
        with self._save_lock:
            st.out.mkdir(parents=True, exist_ok=True)
            k = 0
            while any((st.out / f"export_{k:03d}.{x}").exists() for x in (fmt, "json")):
                k += 1
            path = st.out / f"export_{k:03d}.{fmt}"
            io.write_json(path.with_suffix(".json"), {"map": label, "rotation_deg": rotation, "exposure_ev": exposure})
        light = self.by_label[label].path
        argv = [str(self.frames.asset), "--env", str(light), "--rotation", repr(float(rotation)), "--exposure",
                repr(float(exposure)), "--format", fmt, "--out", str(path), "--device", str(self.frames.device)]  # fmt: skip
        argv += ["--spp", str(st.spp)] if st.spp else []
        parser = argparse.ArgumentParser(prog="frng export-asset")
        export.add_arguments(parser)
        with self.frames._lock:  # one job at a time on the device
            info = export.export(parser.parse_args(argv))
        io.write_json(
            path.with_suffix(".json"),
            {"map": label, "map_file": str(light), "rotation_deg": rotation, "exposure_ev": exposure, "format": fmt,
             "fit_psnr_db": info["fit_psnr_db"], "command": " ".join(["frng export-asset", *argv])},
        )  # fmt: skip
        return path, float(info["fit_psnr_db"])


class _Session:
    """One browser tab: its panel, its camera's state and the thread that renders its frames (low while things
    move, full once they rest for :data:`REST_S`)."""

    def __init__(self, viewer: Viewer, client):
        self.viewer, self.client = viewer, client
        self.changed = time.monotonic()
        self.wake = threading.Event()
        self.closed = threading.Event()
        self.shown: tuple | None = None  # the key of the frame on screen
        self.last: tuple[tuple, np.ndarray, float] | None = None  # (render key, rgba, seconds)
        self.count = 0
        self._ignored: str | None = None  # the last bad client value logged
        self._build_panel()
        client.camera.on_update(lambda _cam: self.touch())
        self.thread = threading.Thread(target=self._loop, name=f"frng-view-{client.client_id}", daemon=True)
        self.thread.start()

    def _build_panel(self) -> None:
        v, gui = self.viewer, self.client.gui
        labels = [x.label for x in v.lights]
        with gui.add_folder("Light"):
            self.map = gui.add_dropdown("map", labels, initial_value=labels[0])
            self.thumb = gui.add_image(thumbnail(v.lights[0].image), label="map (thumbnail)", format="png")
            self.rotation = gui.add_slider("rotation (deg)", min=-180.0, max=180.0, step=1.0, initial_value=0.0)
            self.exposure = gui.add_slider("exposure (EV)", min=-4.0, max=4.0, step=0.1, initial_value=0.0)
        self.status = gui.add_markdown("waiting for the first frame")
        self.save_button = gui.add_button("Save frame")
        self.saved = gui.add_markdown("")
        from frng.apps.export import FORMATS

        self.export_format = gui.add_dropdown("export format", list(FORMATS), initial_value="glb")
        self.export_button = gui.add_button("Export splat")
        self.exported = gui.add_markdown("")
        for h in (self.map, self.rotation, self.exposure):
            h.on_update(lambda _e: self.light_changed())
        self.save_button.on_click(lambda _e: self.save())
        self.export_button.on_click(lambda _e: self.export())
        t = v.test_object
        if t is not None:
            with gui.add_folder("Test object"):
                options = ["(free camera)"] + [f"{view} · {light}" for view, light in t.targets()]
                self.target = gui.add_dropdown("target view · light", options, initial_value=options[0])
                self.compare = gui.add_image(
                    np.zeros((TILE_MIN, 3 * TILE_MIN + 4, 3), np.uint8), label="ground truth | F-RNG | backbone",
                    format="png", visible=False,
                )  # fmt: skip
            self.target.on_update(lambda _e: self.target_changed())

    # -- events --
    def touch(self) -> None:
        self.changed = time.monotonic()
        self.wake.set()

    def light_changed(self) -> None:
        try:
            label, rot, _ = self._light()
        except confine.UntrustedInputError as e:
            self._ignore(e)
            return
        self.thumb.image = thumbnail(self.viewer.env(label, rot))
        self.touch()

    def _ignore(self, e: Exception) -> None:
        """A bad value from the browser: ignored (the last frame stays), logged once per distinct message."""
        msg = str(e).splitlines()[0]
        if msg != self._ignored:
            self._ignored = msg
            self.viewer.log(f"frng view: ignored a client value: {msg}")

    def _light(self) -> tuple[str, float, float]:
        """(map label, rotation, exposure) from the panel, checked (:func:`client_light`)."""
        return client_light(self.viewer.by_label, self.map.value, self.rotation.value, self.exposure.value,
                            source=f"client {self.client.client_id}")  # fmt: skip

    def target_changed(self) -> None:
        t = self.viewer.test_object
        if self.target.value not in {f"{v} · {light}" for v, light in t.targets()}:
            self.compare.visible = False
            return
        view, light = self.target.value.split(" · ", 1)
        c2w, intr, _, h = t.camera(view)
        pose = camera_pose(c2w, intr, h)
        cam = self.client.camera
        with self.client.atomic():
            cam.position = pose["position"]
            cam.look_at = pose["look_at"]
            cam.up_direction = pose["up_direction"]
            cam.fov = pose["fov"]
        label = next((x.label for x in self.viewer.lights if x.label.split(" · ")[0] == light), None)
        if label is not None:
            self.rotation.value = 0.0
            self.map.value = label
        self.compare.image = t.side_by_side(view, light, self.exposure.value)
        self.compare.visible = True
        self.touch()

    def save(self) -> None:
        self.saved.content = "saving..."
        try:
            c2w, intr, w, h, label, rot, ev = self._view(FULL)
            folder = self.viewer.save(c2w, intr, w, h, label, rot, ev)
        except Exception as e:  # shown in the panel: the server keeps running
            self.saved.content = f"save failed: {str(e).splitlines()[0]}"
            return
        self.saved.content = f"saved `{folder}` (EXR, PNG, cameras.json)"

    def export(self) -> None:
        self.exported.content = "exporting..."
        try:
            label, rot, ev = self._light()
            path, psnr = self.viewer.export(label, rot, ev, str(self.export_format.value))
        except Exception as e:  # shown in the panel: the server keeps running
            self.exported.content = f"export failed: {str(e).splitlines()[0]}"
            return
        self.exported.content = f"exported `{path}` (SH fit {psnr:.1f} dB)"

    def close(self) -> None:
        self.closed.set()
        self.wake.set()

    # -- rendering --
    def _view(self, quality: str):
        """(c2w, intr, width, height, map label, rotation, exposure) of the current state at ``quality``."""
        cam, st = self.client.camera, self.viewer.settings
        res = st.resolution if quality == FULL else max(MIN_LOW_HEIGHT, st.resolution // LOW_DIVISOR)
        source = f"client {self.client.client_id}"
        size = confine.finite([cam.image_width, cam.image_height], source=source, field="camera.image size",
                              minimum=0, maximum=1e6)  # fmt: skip
        aspect = size[0] / max(size[1], 1) if size[1] else 1.0
        aspect = min(max(aspect, 1.0 / MAX_ASPECT), float(MAX_ASPECT))
        w, h = frame_size(res, aspect)
        position, wxyz, fov = client_camera(cam.position, cam.wxyz, cam.fov, source=source)
        c2w, intr = viewport_camera(position, wxyz, fov, w, h)
        return c2w, intr, w, h, *self._light()

    def _spp(self, quality: str) -> int:
        full = self.viewer.settings.spp or self.viewer.frames.spp
        return full if quality == FULL else max(1, full // LOW_SPP_DIVISOR)

    def _loop(self) -> None:
        while not self.closed.is_set():
            moving = time.monotonic() - self.changed < REST_S
            quality = LOW if moving else FULL
            try:
                view = self._view(quality)
            except (AssertionError, AttributeError):  # no camera message yet
                view = None
            except confine.UntrustedInputError as e:  # a bad value from the browser: the last frame stays
                self._ignore(e)
                view = None
            if view is not None:
                key = (quality, view[0].tobytes(), *view[2:], self._spp(quality))
                if key != self.shown:
                    try:
                        self._show(key, view, quality)
                    except Exception as e:  # a failed frame is reported in the panel, the loop goes on
                        self.status.content = f"frame failed: {str(e).splitlines()[0]}"
                        self.shown = key
            if moving:
                self.wake.wait(max(0.01, REST_S - (time.monotonic() - self.changed)))
            else:
                self.wake.wait(1.0)
            self.wake.clear()

    def _show(self, key: tuple, view: tuple, quality: str) -> None:
        c2w, intr, w, h, label, rot, ev = view
        spp = self._spp(quality)
        render_key = (key[1], w, h, label, rot, spp)
        if self.last is not None and self.last[0] == render_key:  # only the exposure changed
            rgba, seconds = self.last[1], self.last[2]
        else:
            env = self.viewer.env(label, rot)
            rgba, seconds = self.viewer.frames.frame(c2w, intr, w, h, env, spp, fast=quality == LOW)
            self.last = (render_key, rgba, seconds)
        self.client.scene.set_background_image(display(rgba, ev), format="png")
        self.count += 1
        self.shown = key
        self.status.content = (
            f"**{quality}** frame {self.count}: {w}×{h} px, {spp} spp, **{seconds * 1000:.0f} ms** on "
            f"{self.viewer.frames.device.type} · {label}"
        )


# -- opening a viewer from the command line's arguments -----------------------------------------------------------


def open_viewer(
    asset: str | None,
    env: Sequence[str] = (),
    object_id: str | None = None,
    results: str | Path | None = None,
    resolution: int | None = None,
    spp: int | None = None,
    device: str = "auto",
    out: str = "frng-view",
) -> Viewer:
    """Check every input and load the asset and the maps (everything that can fail on bad input), without listening
    yet: a :class:`Viewer` to :meth:`~Viewer.start`. ``asset`` or ``object_id`` (+ ``results``, the results folder
    of the config the stage read: its test maps and the object's relit images)."""

    results = Path(results) if results is not None else None
    test_object = None
    if object_id is not None:
        if results is None:
            raise ViewError("--object needs --config (the pipeline config whose results folder holds the object)")
        if asset is not None:
            raise ViewError("give an ASSET folder or --object, not both")
        test_object = TestObject(results, object_id)
        asset = RelightFolder(Layout(results).relight_run(test_object.run, object_id)).asset()
    elif asset is None:
        raise ViewError("give an ASSET folder (asset.json, gaussians.ply, decoder.safetensors) or --object OBJ")

    top = MAX_RESOLUTION // MAX_ASPECT  # a frame's width stays within what render-asset renders (Save frame)
    if resolution is not None and not 8 <= resolution <= top:
        raise ViewError(f"--resolution {resolution}: must be 8..{top} px (frames up to {MAX_ASPECT}:1 wide)")
    if spp is not None and not 1 <= spp <= MAX_SPP:
        raise ViewError(f"--spp {spp}: must be 1..{MAX_SPP}")
    frames = FrameRenderer(asset, device)  # AssetError: missing / malformed asset, one line
    asset_path = Path(asset)
    meta = frames.renderer.meta
    if results is None:
        results = results_of_asset(asset_path)
    oid = object_id or str(meta.get("object_id"))
    if test_object is None and results is not None:  # a relit test object's asset: its images side by side too
        for run in ASSET_RUNS:
            same = Path(RelightFolder(Layout(results).relight_run(run, oid)).asset()).resolve() == asset_path.resolve()
            if same and Path(Layout(results).relight_record(run, oid)).exists():
                try:
                    test_object = TestObject(results, oid, run)
                except ViewError:
                    test_object = None
    lights = collect_lights(asset_path, results, env, oid)
    # the first camera: the test object's first target view, else the asset's rig as render-asset's turntable
    obj_meta = Path(Layout(results).object_meta(oid)) if results is not None else None
    if test_object is not None:
        c2w, intr, _, h = test_object.camera(test_object.views[0])
    elif obj_meta is not None and obj_meta.exists() and (io.read_json(obj_meta).get("views") or {}).get("targets"):
        cam = io.read_json(obj_meta)["views"]["targets"][0]
        c2w, intr, h = np.asarray(cam["c2w"]), np.asarray(cam["intrinsics"]), int(cam["height"])
    else:
        rig = frames.renderer.rig
        res = int(rig.get("resolution", FALLBACK_RESOLUTION))
        cam = turntable(1, 20.0, float(rig.get("camera_distance", 4.0)), float(rig.get("fov_deg", 40.0)), res)[0]
        c2w, intr, h = np.asarray(cam["c2w"]), np.asarray(cam["intrinsics"]), res
    settings = Settings(
        resolution=int(resolution or frames.renderer.rig.get("resolution", h)),
        spp=spp,
        out=Path(out),
        initial=(np.asarray(c2w, np.float64), np.asarray(intr, np.float64), int(h)),
    )
    return Viewer(frames, lights, settings, test_object)


def measure(viewer: Viewer, repeats: int = 5, aspect: float = 16 / 9) -> dict:
    """Frame times without a browser: the first camera's frame at full and at low quality (as a viewport of
    ``aspect`` shows them), rasterized and shaded, the median of ``repeats`` renders after a warm-up each
    (:func:`frng.device.median_time`); ``frng view ASSET --measure N``."""
    from frng.device import median_time

    c2w, intr, height = viewer.settings.initial
    spp_full = viewer.settings.spp or viewer.frames.spp
    out = {"device": viewer.frames.device.type, "repeats": int(repeats)}
    for quality, res, spp in (
        (FULL, viewer.settings.resolution, spp_full),
        (LOW, max(MIN_LOW_HEIGHT, viewer.settings.resolution // LOW_DIVISOR), max(1, spp_full // LOW_SPP_DIVISOR)),
    ):
        w, h = frame_size(res, aspect)
        f = float(intr[1]) * h / height
        cam = (c2w, np.array([f, f, w / 2, h / 2]), w, h, viewer.lights[0].image, spp, 0, quality == LOW)

        def one(cam=cam):  # a new camera each frame, as while moving: rasterized again
            viewer.frames.forget()
            return viewer.frames.frame(*cam)

        seconds, _ = median_time(one, viewer.frames.device, repeats)
        out[quality] = {"width": w, "height": h, "spp": spp, "ms": seconds * 1000.0}
    return out


def serve(viewer: Viewer, port: int, stop: threading.Event, log=print) -> None:
    """Start the viewer on ``port``, print its URL and the SSH tunnel line, serve until ``stop`` is set, stop."""
    viewer.warm_up()
    url = viewer.start(port)
    try:
        log(
            f"frng view: {url} ({len(viewer.lights)} maps, {viewer.frames.device.type}, frames "
            f"{viewer.settings.resolution} px tall); on a remote machine: ssh -L {port}:{HOST}:{port} HOST, then open "
            f"the URL locally. Ctrl-C stops.",
        )
        while not stop.wait(0.5):
            pass
    finally:
        viewer.stop()


__all__ = [
    "FrameRenderer",
    "Light",
    "TestObject",
    "ViewError",
    "Viewer",
    "camera_pose",
    "camera_record",
    "check_port",
    "client_camera",
    "client_light",
    "collect_lights",
    "display",
    "frame_size",
    "measure",
    "open_viewer",
    "own_page_only",
    "quat_to_matrix",
    "serve",
    "thumbnail",
    "viewport_camera",
]
