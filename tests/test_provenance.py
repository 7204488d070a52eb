"""Provenance (issue 12, problems 1 and 2): a results folder records one effective config, written only when jobs
run (never by a dry run), a run with a different config is refused unless asked to overwrite, and a
``--configfile`` is the whole config (no silent merge of config/config.yaml), so ``frng config X`` prints exactly
what Snakemake runs for X.

"Runs" here are ``snakemake --touch``: the workflow starts for real (the ``onstart`` handler records the config)
but no stage runs (touching outputs that do not exist only warns), so no Blender and no training. Every call uses
its own results folder and its own working directory (``--directory``), never the repository's ``results/``."""

import os
import subprocess

import pytest
import yaml
from conftest import ROOT, venv_bin

from frng.plan import config as frng_config


def snakemake(configfile, *args, targets=(), workdir=None, timeout=300):
    """Run snakemake on the project's Snakefile from the repository, as users do; ``workdir``: its ``--directory``
    (where ``.snakemake`` goes). Targets go first: ``--configfile`` and ``--config`` take every argument after
    them."""
    cmd = [venv_bin("snakemake"), "--snakefile", str(ROOT / "workflow" / "Snakefile"), *map(str, targets)]
    if workdir is not None:
        workdir.mkdir(exist_ok=True)
        cmd += ["--directory", str(workdir)]
    if configfile is not None:
        cmd += ["--configfile", str(configfile)]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd + list(args), cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)


def touch_run(tmp_path, configfile, results, *extra):
    """A real (non-dry) run that executes no stage: the env-map job, touched. Its ``.snakemake`` (locks, metadata)
    lives under ``tmp_path``, not in the repository."""
    return snakemake(
        configfile,
        "--touch",
        "--cores",
        "1",
        *extra,
        targets=[results / "envmaps" / "index.json"],
        workdir=tmp_path / "workdir",
    )


def dry_run(configfile, *extra):
    """A dry run from the repository (writes nothing there: no locks, no metadata)."""
    return snakemake(configfile, "-n", "--quiet", "rules", *extra)


def write_config(path, config):
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def smoke_config(results, **changes):
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(results)
    for section, values in changes.items():
        cfg[section] = {**cfg.get(section, {}), **values}
    return cfg


def minimal_config(results):
    """A custom config that leaves most sections out: the schema's defaults must fill them, not the default tier."""
    smoke = smoke_config(results)
    return {
        "tier": "custom",
        "results": str(results),
        "objects": smoke["objects"],
        "envmaps": smoke["envmaps"],
        "render": {"resolution": 32, "spp": 4, "target_views": 2, "target_lights": 2},
    }


def frng_config_output(path) -> dict:
    """What ``frng config PATH`` prints, parsed."""
    r = subprocess.run([venv_bin("frng"), "config", str(path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    return yaml.safe_load(r.stdout)


def assert_same_keys(expected: dict, actual: dict, what: str):
    """Key by key (dotted leaves), listing every difference."""
    a, b = frng_config.flatten(expected), frng_config.flatten(actual)
    diff = [
        f"{k}: frng config {a.get(k, '<absent>')!r}, snakemake {b.get(k, '<absent>')!r}"
        for k in sorted(set(a) | set(b))
        if a.get(k, "<absent>") != b.get(k, "<absent>")
    ]
    assert not diff, f"{what}: {len(diff)} key(s) differ:\n" + "\n".join(diff)


def _out(proc):
    return (proc.stdout + proc.stderr)[-4000:]


# -- problem 1: one effective config per results folder, written only when jobs run ------------------------------


def test_dry_run_writes_no_config(tmp_path):
    results = tmp_path / "results"
    proc = dry_run(write_config(tmp_path / "a.yaml", smoke_config(results)))
    assert proc.returncode == 0, _out(proc)
    assert not (results / "config.yaml").exists(), "a dry run wrote the effective config"
    assert not results.exists(), "a dry run created the results folder"


def test_dry_run_leaves_a_running_folders_config_alone(tmp_path):
    """Run A records its config; a dry run of B on the same folder reports the difference and changes nothing."""
    results = tmp_path / "results"
    a = write_config(tmp_path / "a.yaml", smoke_config(results))
    proc = touch_run(tmp_path, a, results)
    assert proc.returncode == 0, _out(proc)
    recorded = results / "config.yaml"
    before, mtime = recorded.read_bytes(), recorded.stat().st_mtime_ns
    b = write_config(tmp_path / "b.yaml", smoke_config(results, render={"resolution": 64}))
    proc = dry_run(b)
    assert proc.returncode == 0, _out(proc)
    assert recorded.read_bytes() == before and recorded.stat().st_mtime_ns == mtime
    assert "render.resolution: recorded 32, now 64" in proc.stdout + proc.stderr, _out(proc)  # (the whole output)


def test_run_refuses_a_different_config_unless_overwrite(tmp_path):
    results = tmp_path / "results"
    a = write_config(tmp_path / "a.yaml", smoke_config(results))
    assert touch_run(tmp_path, a, results).returncode == 0
    recorded = results / "config.yaml"
    assert_same_keys(frng_config_output(a), yaml.safe_load(recorded.read_text()), "recorded config of run A")
    before = recorded.read_bytes()

    b = write_config(tmp_path / "b.yaml", smoke_config(results, render={"spp": 16}))
    proc = touch_run(tmp_path, b, results)
    assert proc.returncode != 0, "a run with a different config was not refused"
    out = _out(proc)
    assert str(recorded) in out and "render.spp: recorded 8, now 16" in out and "overwrite_config=true" in out, out
    assert recorded.read_bytes() == before

    proc = touch_run(tmp_path, b, results, "--config", "overwrite_config=true")
    assert proc.returncode == 0, _out(proc)
    assert_same_keys(frng_config_output(b), yaml.safe_load(recorded.read_text()), "replaced config")
    assert "overwrite_config" not in recorded.read_text()  # the switch is not part of the config


def test_same_config_keeps_the_recorded_file(tmp_path):
    results = tmp_path / "results"
    a = write_config(tmp_path / "a.yaml", smoke_config(results))
    assert touch_run(tmp_path, a, results).returncode == 0
    recorded = results / "config.yaml"
    mtime = recorded.stat().st_mtime_ns
    proc = touch_run(tmp_path, a, results)
    assert proc.returncode == 0, _out(proc)
    assert recorded.stat().st_mtime_ns == mtime


def test_each_shipped_tier_has_its_own_results_folder():
    folders = {
        name: frng_config.load(ROOT / "config" / name)["results"]
        for name in ("config.yaml", "smoke.yaml", "paper.yaml")
    }
    assert folders == {"config.yaml": "results", "smoke.yaml": "results/smoke", "paper.yaml": "results/paper"}


# -- problem 2: a --configfile is the whole config ---------------------------------------------------------------


def test_snakemake_runs_what_frng_config_prints(tmp_path):
    """Key by key: the effective config a run records for a minimal custom config == ``frng config`` of it."""
    results = tmp_path / "results"
    path = write_config(tmp_path / "minimal.yaml", minimal_config(results))
    proc = touch_run(tmp_path, path, results)
    assert proc.returncode == 0, _out(proc)
    assert_same_keys(frng_config_output(path), yaml.safe_load((results / "config.yaml").read_text()), "minimal config")


def test_dry_run_matches_frng_config(tmp_path):
    """``frng config X`` recorded in X's results folder; a dry run of X from the repository (as ``make dry-run``)
    sees no difference (it would name every differing key) and leaves the file alone."""
    results = tmp_path / "results"
    path = write_config(tmp_path / "minimal.yaml", minimal_config(results))
    results.mkdir()
    recorded = results / "config.yaml"
    recorded.write_text(yaml.safe_dump(frng_config_output(path), sort_keys=False))
    before = recorded.read_bytes()
    proc = dry_run(path)
    assert proc.returncode == 0, _out(proc)
    assert "records a different config" not in proc.stdout + proc.stderr, _out(proc)
    assert_same_keys(yaml.safe_load(before), yaml.safe_load(recorded.read_text()), "minimal: config after a dry run")


def test_paper_dry_run_matches_frng_config(paper_dry_run):
    """The same for config/paper.yaml: the session's paper dry run (conftest.py) ran over a results folder that
    records what ``frng config`` prints for it."""
    proc = paper_dry_run.proc
    assert proc.returncode == 0, _out(proc)
    assert "records a different config" not in paper_dry_run.output, _out(proc)
    after = yaml.safe_load(paper_dry_run.recorded.read_text())
    assert_same_keys(yaml.safe_load(paper_dry_run.recorded_before), after, "paper: config after a dry run")


def test_config_without_objects_is_an_error_not_the_default_tier(tmp_path):
    cfg = minimal_config(tmp_path / "results")
    del cfg["objects"]
    proc = dry_run(write_config(tmp_path / "no_objects.yaml", cfg))
    assert proc.returncode != 0, "a config without objects: planned the default tier's objects"
    assert "objects" in _out(proc)


def test_no_configfile_runs_the_default_tier(tmp_path):
    results = tmp_path / "results"
    proc = touch_run(tmp_path, None, results, "--config", f"results={results}")
    assert proc.returncode == 0, _out(proc)
    expected = frng_config.load(ROOT / "config" / "config.yaml", {"results": str(results)})
    assert_same_keys(expected, yaml.safe_load((results / "config.yaml").read_text()), "default tier")


@pytest.mark.parametrize(
    "value, expected",
    [(True, True), ("true", True), ("True", True), ("1", True), (False, False), ("false", False), (None, False)],
)
def test_overwrite_switch_is_popped(value, expected):
    cfg = {"results": "x", frng_config.OVERWRITE_SWITCH: value}
    assert frng_config.pop_switch(cfg) is expected
    assert cfg == {"results": "x"}


def test_overwrite_switch_rejects_non_boolean():
    with pytest.raises(frng_config.ConfigError, match="overwrite_config"):
        frng_config.pop_switch({"overwrite_config": "maybe"})


# -- point 6: outputs honour the umask ---------------------------------------------------------------------------


@pytest.fixture
def umask():
    """Set the process umask for one test (restored after)."""
    old = os.umask(0o022)
    yield lambda mask: os.umask(mask)
    os.umask(old)


@pytest.mark.parametrize(
    "mask, file_mode, dir_mode", [(0o022, 0o644, 0o755), (0o002, 0o664, 0o775), (0o077, 0o600, 0o700)]
)
def test_outputs_honour_the_umask(tmp_path, umask, mask, file_mode, dir_mode):
    import numpy as np

    from frng import io

    umask(mask)
    io.write_json(tmp_path / "a.json", {"x": 1})
    io.write_png(tmp_path / "a.png", np.zeros((4, 4, 3), np.float32))
    io.write_exr(tmp_path / "a.exr", np.zeros((4, 4, 4), np.float32))
    for name in ("a.json", "a.png", "a.exr"):
        assert (tmp_path / name).stat().st_mode & 0o777 == file_mode, name
    staged = io.temp_dir(".tmp-x-", tmp_path)
    assert staged.stat().st_mode & 0o777 == dir_mode


def test_recorded_config_honours_the_umask(tmp_path, umask):
    umask(0o002)
    path = tmp_path / "results" / "config.yaml"
    frng_config.record(frng_config.load(ROOT / "config" / "smoke.yaml"), path)
    assert path.stat().st_mode & 0o777 == 0o664
