"""The viewer answers only its own page (issue 87, docs/reliability.md): a running ``frng view`` on 127.0.0.1 refuses a
websocket handshake from a foreign Origin and a request with a foreign Host (DNS rebinding) with 403 and one log
line, and serves its own page; values a client sends (an unknown map label, a NaN rotation, a field of view of 0)
are ignored with one log line and never end that client's render thread.

Built on a tiny asset (tests/test_untrusted_outputs.tiny_asset) and an 8x16 map; no smoke pipeline. Bounded: the
viewer's start is waited for at most 120 s, each request times out after 10 s, five requests in all.
"""

from __future__ import annotations

import http.client
import socket
import subprocess
import sys
import time
from types import SimpleNamespace
from unittest import mock

import numpy as np
import pytest
from conftest import ROOT
from test_untrusted_outputs import _env, tiny_asset

from frng import confine


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_local_request_rules():
    ok = {"Host": "127.0.0.1:8080"}
    assert confine.local_request(ok, 8080) is None
    assert confine.local_request({"Host": "LOCALHOST:8080", "Origin": "http://localhost:8080"}, 8080) is None
    for headers, what in (
        ({"Host": "evil.example:8080"}, "Host 'evil.example:8080'"),
        ({"Host": "127.0.0.1:9999"}, "Host '127.0.0.1:9999'"),
        ({}, "0 Host headers"),
        ({**ok, "Origin": "http://evil.example"}, "Origin 'http://evil.example'"),
        ({**ok, "Origin": "null"}, "Origin 'null'"),
        ({**ok, "Origin": "http://127.0.0.1:3000"}, "Origin 'http://127.0.0.1:3000'"),
        ({**ok, "Origin": "https://127.0.0.1:8080"}, "Origin 'https://127.0.0.1:8080'"),
    ):
        why = confine.local_request(headers, 8080)
        assert why is not None and what in why and "\n" not in why, (headers, why)


def _get(port: int, host: str, origin: str | None = None) -> int:
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        c.putrequest("GET", "/", skip_host=True)
        c.putheader("Host", host)
        if origin:
            c.putheader("Origin", origin)
        c.endheaders()
        return c.getresponse().status
    finally:
        c.close()


def _ws(port: int, origin: str, host: str = "127.0.0.1") -> int:
    """The HTTP status of a websocket handshake (101: accepted) to 127.0.0.1:port, sent with ``Host: {host}:{port}``
    and ``origin``."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    try:
        with connect(f"ws://{host}:{port}/", sock=sock, origin=origin, subprotocols=["viser-v0"], open_timeout=10,
                     close_timeout=2):  # fmt: skip
            return 101
    except InvalidStatus as e:
        return e.response.status_code
    finally:
        sock.close()


def test_running_viewer_refuses_a_foreign_origin_and_host(tmp_path):
    asset = tiny_asset(tmp_path / "asset")
    env = _env(tmp_path / "env.exr")
    port = _free_port()
    log = tmp_path / "view.log"
    out = tmp_path / "frames"
    with open(log, "w") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "frng", "view", str(asset), "--env", str(env), "--port", str(port)]
            + ["--device", "cpu", "--resolution", "16", "--spp", "1", "--out", str(out)],
            cwd=ROOT,
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    try:
        t0 = time.monotonic()
        while "frng view: http://" not in log.read_text():
            assert proc.poll() is None, log.read_text()[-2000:]
            assert time.monotonic() - t0 < 120, log.read_text()[-2000:]
            time.sleep(0.2)
        own = f"127.0.0.1:{port}"
        assert _get(port, own) == 200  # its own page
        assert _get(port, f"evil.example:{port}") == 403  # DNS rebinding
        assert _ws(port, "http://evil.example") == 403  # a foreign page's websocket
        assert _ws(port, f"http://evil.example:{port}", host="evil.example") == 403
        assert _ws(port, f"http://localhost:{port}", host="localhost") == 101  # the viewer's own page
        time.sleep(0.5)
        assert proc.poll() is None, log.read_text()[-2000:]
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    lines = log.read_text().splitlines()
    refused = [ln for ln in lines if ln.startswith("frng view: refused")]
    assert len(refused) == 3, lines
    assert "Host 'evil.example:" in refused[0] and "Origin 'http://evil.example'" in refused[1], refused
    assert not any("Traceback" in ln for ln in lines), lines
    assert not out.exists(), "a refused client wrote frames"


# -- client values --------------------------------------------------------------------------------------------------


def test_client_values_are_checked():
    from frng.apps.view_scene import client_camera, client_light

    pos, q, fov = client_camera((0, 0, 3), (1, 0, 0, 0), 0.7, source="client 0")
    assert fov == 0.7 and pos.tolist() == [0, 0, 3]
    for args, field in (
        (((0, 0, 3), (1, 0, 0, 0), 0.0), "camera.fov"),
        (((0, 0, 3), (1, 0, 0, 0), float("nan")), "camera.fov"),
        (((0, 0, 3), (1, 0, 0, 0), np.pi), "camera.fov"),
        (((0, float("inf"), 3), (1, 0, 0, 0), 0.7), "camera.position"),
        (((0, 0, 1e30), (1, 0, 0, 0), 0.7), "camera.position"),
        (((0, 0, 3), (0, 0, 0, 0), 0.7), "camera.wxyz"),
        (((0, 0, 3), (float("nan"), 0, 0, 0), 0.7), "camera.wxyz"),
    ):
        with pytest.raises(confine.UntrustedInputError, match=rf"client 0: field '{field}'"):
            client_camera(*args, source="client 0")
    maps = {"a · file": None}
    assert client_light(maps, "a · file", 10, -1, source="c") == ("a · file", 10.0, -1.0)
    for args, field in (
        (("nope", 0, 0), "map"),
        (("a · file", float("nan"), 0), "rotation"),
        (("a · file", 0, float("inf")), "exposure"),
        (("a · file", 1e9, 0), "rotation"),
        (("a · file", "x", 0), "rotation"),
    ):
        with pytest.raises(confine.UntrustedInputError, match=rf"c: field '{field}'"):
            client_light(maps, *args, source="c")


def test_a_bad_client_value_never_ends_a_render_thread(tmp_path):
    """A tab's session with a fake viser client: fov 0, an unknown map, a NaN rotation are each logged once and
    ignored; the render thread lives on and renders once the values are good again."""
    from frng.apps import view

    asset = tiny_asset(tmp_path / "asset")
    env = _env(tmp_path / "env.exr")
    viewer = view.open_viewer(str(asset), [str(env)], resolution=16, spp=1, device="cpu", out=str(tmp_path / "f"))
    logged: list[str] = []
    viewer.log = logged.append
    label = viewer.lights[0].label
    values = {"map": label, "rotation (deg)": 0.0, "exposure (EV)": 0.0}

    def handle(name, *a, initial_value=None, **k):
        return SimpleNamespace(value=values.get(name, initial_value), on_update=lambda f: None,
                               on_click=lambda f: None, content="", image=None, visible=True)  # fmt: skip

    gui = mock.MagicMock()
    gui.add_dropdown.side_effect = lambda name, options, initial_value=None: handle(name, initial_value=initial_value)
    gui.add_slider.side_effect = lambda name, **k: handle(name, **k)
    gui.add_markdown.side_effect = lambda text: handle("md", initial_value=text)
    gui.add_button.side_effect = lambda name: handle(name)
    gui.add_image.side_effect = lambda *a, **k: handle("img")
    camera = SimpleNamespace(position=(0.0, -3.0, 0.0), wxyz=(1.0, 0.0, 0.0, 0.0), fov=0.0, image_width=32,
                             image_height=32, on_update=lambda f: None)  # fmt: skip
    client = SimpleNamespace(client_id=7, gui=gui, camera=camera, scene=mock.MagicMock())
    session = view._Session(viewer, client)

    def settle(cond, timeout=30.0):
        t0 = time.monotonic()
        while not cond():
            assert session.thread.is_alive(), logged
            assert time.monotonic() - t0 < timeout, logged
            session.touch()
            time.sleep(0.05)

    try:
        settle(lambda: any("camera.fov" in m for m in logged))
        camera.fov = 0.7
        settle(lambda: session.count >= 1)
        session.map.value = "evil"
        settle(lambda: any("field 'map'" in m for m in logged))
        session.map.value, session.rotation.value = label, float("nan")
        settle(lambda: any("field 'rotation'" in m for m in logged))
        session.light_changed()  # the panel's callback: ignored too, no exception
        session.rotation.value = 30.0
        n = session.count
        settle(lambda: session.count > n)
        assert session.thread.is_alive()
    finally:
        session.close()
        session.thread.join(timeout=30)
    assert len(logged) == len(set(logged)) == 3, logged
    assert all(m.startswith("frng view: ignored a client value: client 7: field ") for m in logged), logged
