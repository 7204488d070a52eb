"""A results folder stays trustworthy when it is shared or run twice (issue 24, items 6, 7 and 10).

- 6: config paths are quoted in every shell command (a `results:` with a space), and the config refuses paths a
  workflow cannot hold (braces: Snakemake wildcards; control characters);
- 7: a second snakemake on the same results folder, from another working directory, stops before its first job;
- 10: every rule `exec`s its stage, so killing a job's shell wrapper kills the stage (no orphan writing on).

Item 2 (the config digests travel with a copied folder) is in tests/test_config_digests.py.
"""

from __future__ import annotations

import fcntl
import os
import re
import shlex
import subprocess

import pytest
import yaml
from conftest import ROOT, venv_bin

from frng.plan import config as frng_config


def snakemake(configfile, *args, workdir=None, targets=()):
    cmd = [venv_bin("snakemake"), "--snakefile", str(ROOT / "workflow" / "Snakefile"), *map(str, targets)]
    if workdir is not None:
        workdir.mkdir(exist_ok=True)
        cmd += ["--directory", str(workdir)]
    cmd += ["--configfile", str(configfile), *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)


def smoke_config(tmp_path, results, name="smoke.yaml"):
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(results)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def test_paths_with_spaces_are_quoted_and_stages_are_execed(tmp_path):
    """Every command the smoke workflow would run (a dry run with -p: writes nothing) keeps the results folder's
    paths whole, redirects its log into the folder, and `exec`s its stage (or is a plain compound of `cp`s)."""
    results = tmp_path / "my results"
    proc = snakemake(smoke_config(tmp_path, results), "-n", "-p")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert not results.exists()
    commands = [line.split("Shell command: ", 1)[1] for line in out.splitlines() if "Shell command: " in line]
    commands = [c for c in commands if c != "None"]  # run: rules (indexes, digests) run no shell
    stages = {m.group(1) for c in commands for m in [re.search(r" -m frng ([\w-]+)| (train) --config", c)] if m}
    stages = {s.replace("-", "_") for s in stages} | (
        {"model_alias"} if any(c.startswith("(cp") for c in commands) else set()
    )
    assert {"curate", "train", "relight", "evaluate", "model_alias"} <= stages, stages
    for cmd in commands:
        assert cmd.startswith("exec ") or cmd.startswith("("), f"not exec'd: {cmd}"
        tokens = shlex.split(cmd)
        for t in tokens:
            if str(tmp_path) in t:
                assert t == str(results) or t.startswith(str(results) + os.sep), f"{t!r} split in: {cmd}"
        redirects = [tokens[i + 1] for i, t in enumerate(tokens) if t == ">"]
        assert redirects and all(r.startswith(str(results) + os.sep) for r in redirects), cmd


def test_every_shell_rule_execs_its_stage():
    """The rule files themselves (also rules a smoke config plans no job of): the first string of every `shell:`
    starts with `exec` (bash replaces itself with the stage: killing the job kills the stage) or is a compound."""
    found = 0
    for smk in sorted((ROOT / "rules").glob("*.smk")):
        for m in re.finditer(r"^    shell:\n\s+\"(.{0,8})", smk.read_text(), re.M):
            found += 1
            assert m.group(1).startswith(("exec ", "(")), f"{smk.name}: shell command does not exec: {m.group(1)!r}"
    assert found >= 15


@pytest.mark.parametrize("results", ["res{ults}", "res\nults"])
def test_results_paths_snakemake_cannot_hold_are_refused(results):
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = results
    with pytest.raises(frng_config.ConfigError, match="config key 'results'"):
        frng_config.validate(cfg)


def test_a_second_run_on_the_same_folder_is_refused(tmp_path):
    """The results folder's .lock is held by the running snakemake: another one, started from another working
    directory (Snakemake's own lock lives in the working directory), stops before any job, naming the folder."""
    results = tmp_path / "results"
    results.mkdir()
    config = smoke_config(tmp_path, results)
    target = results / "envmaps" / "index.json"
    fd = os.open(results / ".lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # as the other run holds it
        os.write(fd, b"pid 12345 on host, working directory /elsewhere\n")
        proc = snakemake(config, "--touch", "--cores", "1", workdir=tmp_path / "wd2", targets=[target])
        out = proc.stdout + proc.stderr
        assert proc.returncode != 0, out[-3000:]
        assert f"{results} is in use by another snakemake run" in out and "pid 12345" in out, out[-3000:]
        assert not target.exists() and not (results / "config.yaml").exists()
    finally:
        os.close(fd)
    proc = snakemake(config, "--touch", "--cores", "1", workdir=tmp_path / "wd2", targets=[target])
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    assert (results / "config.yaml").exists()  # this time the run started (--touch makes no missing output)
    # the run is over: its lock is free again, and a dry run takes none
    fd = os.open(results / ".lock", os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(fd)
