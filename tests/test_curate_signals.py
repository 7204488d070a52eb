"""A curation stops at once on SIGINT (Ctrl-C, also through a shell as Snakemake runs it) and SIGTERM (scancel, a
scheduler's kill), also in the middle of a render, with a non-zero exit status and nothing that looks complete (nor
Blender's temporary folder left in $TMPDIR);
staging folders left by a SIGKILLed curation are removed when the same object is curated again (never another
object's). Renders are made slow on purpose (many samples) so that the signal lands mid-render."""

import os
import signal
import subprocess
import sys
import time

import pytest
from data_helpers import frng, write_config

pytestmark = pytest.mark.blender

SLOW = {"resolution": 96, "spp": 4096, "threads": 1, "extra_input_views": 0, "target_views": 1}  # seconds per image
FAST = {"resolution": 16, "spp": 1, "threads": 1, "extra_input_views": 0, "target_views": 1}


@pytest.fixture(scope="module")
def envmaps(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("signals")
    cfg = write_config(tmp / "fast.yaml", tmp / "results", render=FAST)
    frng("envmaps", "--config", str(cfg))
    return tmp


def _start(tmp, shell: bool) -> subprocess.Popen:
    cfg = write_config(tmp / "slow.yaml", tmp / "results", render=SLOW)
    cmd = [sys.executable, "-m", "frng", "curate", "--config", str(cfg), "--object", "obj_0000"]
    log = tmp / "curate.log"
    log.unlink(missing_ok=True)
    env = {**os.environ, "TMPDIR": str(_tmpdir(tmp))}  # Blender makes its blender_* folder there
    if shell:  # as Snakemake's shell: directive runs it; Ctrl-C signals the whole process group
        cmd = ["bash", "-c", " ".join(cmd) + f" > {log} 2>&1"]
        proc = subprocess.Popen(cmd, start_new_session=True, env=env)
    else:
        proc = subprocess.Popen(cmd, stdout=open(log, "w"), stderr=subprocess.STDOUT, start_new_session=True, env=env)
    deadline = time.monotonic() + 60
    while not log.exists() or "spp" not in log.read_text():  # the first render has started
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, "curation did not start"
        time.sleep(0.1)
    time.sleep(1.0)
    return proc


def _tmpdir(tmp):
    d = tmp / "tmpdir"
    d.mkdir(exist_ok=True)
    return d


def _objects(tmp):
    return sorted(p.name for p in (tmp / "results" / "objects").iterdir())


@pytest.mark.parametrize(
    "sig, shell",
    [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGINT, True)],
    ids=["sigint", "sigterm", "ctrl-c-through-shell"],
)
def test_signal_stops_curation_at_once_leaving_nothing(envmaps, sig, shell):
    tmp = envmaps
    proc = _start(tmp, shell)
    t0 = time.monotonic()
    if shell:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    try:
        rc = proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        pytest.fail(f"{sig.name}: still running 10 s later")
    took = time.monotonic() - t0
    log = (tmp / "curate.log").read_text()
    assert rc == 128 + sig, (rc, log)
    assert took < 5, f"{sig.name}: took {took:.1f} s to stop"
    assert f"stopped by {sig.name}" in log, log
    assert _objects(tmp) == [], "a final or staging folder was left behind"
    assert not list(_tmpdir(tmp).iterdir()), "Blender's temporary folder was left behind"


def test_sigkilled_staging_folder_is_removed_by_the_next_run_of_the_same_object_only(envmaps):
    tmp = envmaps
    objects = tmp / "results" / "objects"
    other = objects / ".tmp-obj_0001-abcd1234"  # another object's staging folder (its job may be running)
    proc = _start(tmp, shell=False)
    proc.kill()
    proc.wait()
    left = [p for p in _objects(tmp) if p.startswith(".tmp-obj_0000-")]
    assert left, "SIGKILL should leave the staging folder (nothing can clean up after it)"
    other.mkdir()
    cfg = write_config(tmp / "fast.yaml", tmp / "results", render=FAST)
    frng("curate", "--config", str(cfg), "--object", "obj_0000")
    assert _objects(tmp) == [".tmp-obj_0001-abcd1234", "obj_0000"]
    other.rmdir()
    (objects / "obj_0000").rename(tmp / "done")  # leave the folder as the other tests expect it
