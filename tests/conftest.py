import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
# snakemake arguments of the smoke tier (the workflow and config/smoke.yaml)
SMOKE_ARGS = ["--snakefile", str(ROOT / "workflow" / "Snakefile"), "--configfile", str(ROOT / "config" / "smoke.yaml")]

os.environ.setdefault("OMP_NUM_THREADS", "2")


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def shared() -> Path:
    return SHARED


def venv_bin(name: str) -> str:
    """Path of a console script next to the running interpreter (the project's venv)."""
    return str(Path(sys.executable).parent / name)


@pytest.fixture(scope="session")
def smoke_pipeline(tmp_path_factory) -> Path:
    """The results folder of one finished smoke-tier run: ``snakemake`` on config/smoke.yaml (every rule, the local
    profile, 2 cores), once per test session, shared by the modules that need trained smoke models
    (tests/test_smoke_workflow.py checks it; tests/test_reconstruct.py and tests/test_benchmarks_workflow.py build
    on it). Read it; to run more rules, copy it first (:func:`copy_results`)."""
    pytest.importorskip("bpy")
    import subprocess

    results = tmp_path_factory.mktemp("smoke_e2e") / "results"
    r = subprocess.run(
        [
            venv_bin("snakemake"),
            *SMOKE_ARGS,
            "--profile",
            str(ROOT / "profiles" / "local"),
            "--config",
            f"results={results}",
            "--cores",
            "2",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=1500,
    )
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    return results


@dataclass(frozen=True)
class PaperDryRun:
    """One ``snakemake -n --quiet rules`` of config/paper.yaml (see :func:`paper_dry_run`)."""

    proc: subprocess.CompletedProcess
    cpu_s: float  # the planning process's CPU seconds (wall time on a shared 2-core machine is noisy)
    wall_s: float
    recorded: Path  # the results folder's config.yaml, written before the dry run as ``frng config`` prints it
    recorded_before: bytes

    @property
    def output(self) -> str:
        return self.proc.stdout + self.proc.stderr


@pytest.fixture(scope="session")
def paper_dry_run(tmp_path_factory) -> PaperDryRun:
    """The paper tier planned once per test session (~18 s CPU): a config that is config/paper.yaml with ``results``
    in a temporary folder, whose ``config.yaml`` already records what ``frng config`` prints for it, dry-run from the
    repository as ``make dry-run`` does. Its planning time, its job counts (tests/test_workflow_dag.py,
    tests/test_workflow_dryrun.py) and its provenance check (tests/test_provenance.py) read this one run."""
    import resource
    import time

    import yaml

    folder = tmp_path_factory.mktemp("paper_dry_run")
    results = folder / "results"
    cfg = yaml.safe_load((ROOT / "config" / "paper.yaml").read_text())
    cfg["results"] = str(results)
    path = folder / "paper.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    printed = subprocess.run([venv_bin("frng"), "config", str(path)], capture_output=True, text=True, timeout=120)
    assert printed.returncode == 0, printed.stdout + printed.stderr
    results.mkdir()
    recorded = results / "config.yaml"
    recorded.write_text(yaml.safe_dump(yaml.safe_load(printed.stdout), sort_keys=False))
    before = recorded.read_bytes()
    cmd = [venv_bin("snakemake"), "--snakefile", str(ROOT / "workflow" / "Snakefile"), "--configfile", str(path)]
    cmd += ["-n", "--quiet", "rules", "--cores", "1"]
    usage = lambda: (lambda r: r.ru_utime + r.ru_stime)(resource.getrusage(resource.RUSAGE_CHILDREN))  # noqa: E731
    t0, c0 = time.monotonic(), usage()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    cpu, wall = usage() - c0, time.monotonic() - t0
    print(f"\npaper dry-run: {cpu:.1f} s CPU, {wall:.1f} s wall")
    return PaperDryRun(proc, cpu, wall, recorded, before)


def copy_results(results: Path, dest: Path) -> Path:
    """A copy of a results folder (timestamps kept, so Snakemake finds its outputs up to date) at ``dest``."""
    import shutil

    shutil.copytree(results, dest, symlinks=True)
    return dest


@pytest.fixture(scope="session")
def smoke_dataset(smoke_pipeline, tmp_path_factory):
    """The smoke tier's curated dataset (env maps + every object): the ``envmaps/`` and ``objects/`` of the session's
    smoke run (:func:`smoke_pipeline`), so that a test session curates once.

    Returns (config path, validated config) of config/smoke.yaml with ``results`` = that run's folder (read it, never
    write there). Consumers that write outputs should use :func:`smoke_results` (their own results folder linking to
    this data)."""
    import yaml

    from frng.plan import config as frng_config

    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(smoke_pipeline)
    path = tmp_path_factory.mktemp("smoke_dataset") / "smoke.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, frng_config.load(path)


def smoke_results(smoke_dataset, folder: Path, link=("envmaps", "objects"), **overrides) -> tuple[Path, dict]:
    """A fresh results folder whose ``link`` subfolders (default ``envmaps``, ``objects``) link to those of the shared
    smoke run (read-only use); top-level config keys in ``overrides`` are merged (dicts one level deep). Returns
    (config path, config)."""
    import yaml

    from frng.plan import config as frng_config

    src_path, _ = smoke_dataset
    cfg = yaml.safe_load(Path(src_path).read_text())
    src = Path(cfg["results"])
    for k, v in overrides.items():
        cfg[k] = {**cfg.get(k, {}), **v} if isinstance(v, dict) else v
    cfg["results"] = str(folder / "results")
    (folder / "results").mkdir(parents=True, exist_ok=True)
    for sub in link:
        (folder / "results" / sub).symlink_to(src / sub, target_is_directory=True)
    path = folder / "smoke.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, frng_config.load(path)


def record_instances(monkeypatch, module, name: str) -> list:
    """Replace the class ``module.<name>`` by a subclass that records every instance made; returns that list."""
    made = []
    base = getattr(module, name)

    class Recorded(base):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(module, name, Recorded)
    return made


def assert_same_weights(a: Path, b: Path) -> None:
    """Two saved models (``{"state_dict": ...}`` files) hold the same weights, bit for bit."""
    import torch

    sa = torch.load(a, weights_only=False)["state_dict"]
    sb = torch.load(b, weights_only=False)["state_dict"]
    assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa), (a, b)
