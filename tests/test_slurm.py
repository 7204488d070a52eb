"""End to end on a real one-node SLURM cluster (munge + slurmctld + slurmd on 127.0.0.1) via Snakemake's slurm
executor and profiles/slurm-ci.

- test_interrupted_run_resumes: a per-object job is scancel'ed mid-way; nothing that looks complete is left, and
  the rerun finishes the remaining object without redoing the finished ones (a tiny self-contained workflow,
  tests/slurm_toy/Snakefile, with the pipeline's shape: per-object jobs, then a table over all objects).
- test_smoke_workflow_on_slurm: the real workflow on config/smoke.yaml, with one curate job scancel'ed mid-way:
  nothing complete-looking is left, the rerun finishes the rest without redoing finished objects, and every
  `rule all` target comes out. The toy test then skips itself (it re-checks the same on a toy workflow).

The cluster is installed from Debian's packages when missing (apt-get, bounded) and skipped, with the reason,
where that cannot happen (not root, no apt-get, no network, ports taken). Daemons are stopped by PID at the end.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import SMOKE_ARGS as SMOKE
from slurm_cluster import Cluster, Unavailable, ensure_installed

ROOT = Path(__file__).resolve().parent.parent
SNAKEMAKE = str(Path(sys.executable).parent / "snakemake")
# the cluster runs: Snakemake with the slurm plugin's status polls at most 1 s apart (the launcher's docstring)
SNAKEMAKE_CLUSTER = [sys.executable, str(ROOT / "tests" / "slurm_toy" / "snakemake_fast_poll.py")]
PROFILE = str(ROOT / "profiles" / "slurm-ci")
TOY = str(ROOT / "tests" / "slurm_toy" / "Snakefile")
# the smoke tier without the baselines and the ablations (one job per rule, tests/slurm_toy/cluster_overlay.yaml):
# SMOKE ends with its --configfile, the overlay joins it (merged over it)
SMOKE_SLURM = [*SMOKE, str(ROOT / "tests" / "slurm_toy" / "cluster_overlay.yaml")]

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def cluster():
    if os.environ.get("FRNG_SKIP_SLURM"):
        pytest.skip("FRNG_SKIP_SLURM is set")
    try:
        ensure_installed(timeout_s=300)
    except Unavailable as e:
        print(f"SKIP SLURM tests: {e}")
        pytest.skip(f"SLURM unavailable: {e}")
    c = Cluster()
    try:
        c.start()
    except Unavailable as e:
        c.stop()
        print(f"SKIP SLURM tests: {e}")
        pytest.skip(f"SLURM unavailable: {e}")
    except BaseException:
        c.stop()
        raise
    try:
        yield c
    finally:
        c.stop()


def _snakemake(*args: str, workdir: Path | None = None, snakefile: str = TOY) -> list[str]:
    cmd = [*SNAKEMAKE_CLUSTER, "--snakefile", snakefile, "--profile", PROFILE]
    if workdir is not None:
        cmd += ["--slurm-logdir", str(workdir / "slurm_logs"), "--directory", str(workdir)]
    return cmd + list(args)


def _run(cmd: list[str], timeout: float, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as e:
        # snakemake's own SIGTERM handling cancels its SLURM jobs; the fixture cancels the rest
        pytest.fail(f"snakemake did not finish within {timeout} s:\n{(e.stderr or b'')[-4000:]!r}")


def _tail(r: subprocess.CompletedProcess | str, n: int = 4000) -> str:
    text = r if isinstance(r, str) else (r.stdout or "") + (r.stderr or "")
    return text[-n:]


def _wait(pred, timeout: float, what: str, proc: subprocess.Popen | None = None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = pred()
        if got:
            return got
        if proc is not None and proc.poll() is not None:
            pytest.fail(f"snakemake exited ({proc.returncode}) while waiting for {what}")
        time.sleep(0.5)
    pytest.fail(f"timed out after {timeout} s waiting for {what}")


def test_interrupted_run_resumes(cluster, tmp_path):
    """The harness on the toy workflow: runs only where the real smoke workflow cannot plan (or FRNG_SLURM_TOY=1),
    since test_smoke_workflow_on_slurm covers the same on the real workflow and CI time is bounded."""
    if not os.environ.get("FRNG_SLURM_TOY") and _smoke_plans(tmp_path / "plan")[0]:
        pytest.skip("covered by test_smoke_workflow_on_slurm (set FRNG_SLURM_TOY=1 to run it too)")
    wd = tmp_path / "toy"
    objs = ["a", "b", "c"]
    cfg = ["--config", f"objects={json.dumps(objs)}", "slow=c"]
    log = (tmp_path / "run1.log").open("w")
    run1 = subprocess.Popen(
        _snakemake(*cfg, "slow_s=300", workdir=wd), cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, text=True
    )
    job = None
    try:
        done = lambda o: (wd / "objects" / o / "meta.json").exists()  # noqa: E731
        # c's job is mid-way: its first file is written, the job still runs
        _wait(
            lambda: done("a") and done("b") and (wd / "objects/c/image.txt").exists(),
            240,
            "a and b to finish and c to start",
            run1,
        )
        c_log = wd / "logs" / "curate" / "c.log"
        job = _wait(lambda: c_log.exists() and c_log.read_text().split()[-1:], 30, "c's SLURM job id")[0]
        running = {j["id"]: j["state"] for j in cluster.jobs()}
        assert running.get(job) == "RUNNING", (job, running)
    finally:
        rc1 = _cancel_and_stop(run1, log, job, 240)
    out1 = (tmp_path / "run1.log").read_text()
    assert rc1 != 0, _tail(out1)
    # no output that looks complete: the killed job's outputs are removed (or at least its last file never written)
    assert not (wd / "objects/c/meta.json").exists(), _tail(out1)
    assert not (wd / "tables/summary.csv").exists()
    finished = {p: p.stat().st_mtime_ns for o in ("a", "b") for p in (wd / "objects" / o).iterdir()}
    assert len(finished) == 4

    # rerun: only c (and the table) are redone
    r = _run(_snakemake(*cfg, "slow_s=0", workdir=wd), timeout=240)
    assert r.returncode == 0, _tail(r)
    assert {p: p.stat().st_mtime_ns for p in finished} == finished, "finished objects were redone"
    meta = json.loads((wd / "objects/c/meta.json").read_text())
    assert meta["object"] == "c" and meta["job"] not in ("none", job)  # ran again, inside a new SLURM job
    assert (wd / "tables/summary.csv").read_text().split() == ["object", *objs]
    assert "curate" in r.stderr and "wildcards: obj=a" not in r.stderr
    # and a third run has nothing to do
    r = _run(_snakemake(*cfg, "slow_s=0", "-n", workdir=wd), timeout=60)
    assert r.returncode == 0 and "Nothing to be done" in (r.stdout + r.stderr), _tail(r)


# --- the real workflow ---------------------------------------------------------------------------------------


def _smoke_plans(results: Path) -> tuple[bool, str]:
    r = subprocess.run(
        [SNAKEMAKE, *SMOKE_SLURM, "--config", f"results={results}", "-n", "-q", "rules", "--cores", "1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    return r.returncode == 0, _tail(r, 300)


def _targets(results: Path) -> list[Path]:
    """Every file the workflow makes for `rule all`, from snakemake itself (`--summary` of the DAG)."""
    r = subprocess.run(
        [SNAKEMAKE, *SMOKE_SLURM, "--config", f"results={results}", "--summary", "--cores", "1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert r.returncode == 0, _tail(r)
    rows = [line.split("\t") for line in r.stdout.splitlines()[1:] if "\t" in line]
    return [Path(row[0]) if Path(row[0]).is_absolute() else ROOT / row[0] for row in rows]


def _files(folder: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


def test_smoke_workflow_on_slurm(cluster, tmp_path):
    results = tmp_path / "results"
    ok, why = _smoke_plans(results)
    if not ok:
        pytest.skip(f"the smoke workflow does not plan yet: {why}")
    targets = _targets(results)
    assert targets, "snakemake listed no targets for the smoke workflow"
    objects = results / "objects"
    meta = lambda o: objects / o / "meta.json"  # noqa: E731  the file that marks an object complete
    cmd = [
        *SNAKEMAKE_CLUSTER,
        *SMOKE_SLURM,
        "--profile",
        PROFILE,
        "--config",
        f"results={results}",
        "--slurm-logdir",
        str(tmp_path / "slurm_logs"),
    ]

    # run 1: once one object is curated, cancel a curate job that is running (mid-way) for another
    log = (tmp_path / "run1.log").open("w")
    run1 = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, text=True)
    job = cancelled = None
    try:

        def running_unfinished():
            if not list(objects.glob("*/meta.json")):
                return None
            for j in cluster.jobs("RUNNING"):
                m = re.match(r"rule_curate_wildcards_(\w+)$", j["comment"])
                if m and not meta(m.group(1)).exists():
                    return j["id"], m.group(1)
            return None

        job, cancelled = _wait(running_unfinished, 360, "a finished object and a running curate job", run1)
    finally:
        rc1 = _cancel_and_stop(run1, log, job, 900)  # a hang guard: snakemake finishes the running jobs, then stops
    out1 = (tmp_path / "run1.log").read_text()
    assert rc1 != 0, _tail(out1)
    assert not meta(cancelled).exists(), f"cancelled object {cancelled} looks complete\n{_tail(out1)}"
    done = [m.parent.name for m in objects.glob("*/meta.json")]
    assert done, _tail(out1)
    before = {p: t for o in done for p, t in _files(objects / o).items()}

    # run 2 finishes the rest and redoes no finished object (the timeout only guards against a hang: the smoke
    # tier takes ~4 min on an idle 2-core machine, several times that beside another torch job)
    r = _run(cmd, timeout=1500)
    assert r.returncode == 0, _tail(r)
    after = {p: p.stat().st_mtime_ns if p.exists() else None for p in before}
    redone = sorted(str(p.relative_to(results)) for p in before if after[p] != before[p])
    assert not redone, f"finished objects were redone: {redone[:10]}"
    assert meta(cancelled).exists()
    missing = [str(t) for t in targets if not t.exists()]
    assert not missing, f"targets not made: {missing[:10]}"
    # the paper's tables came out of the cluster run with their columns and at least one row each, but the Lambertian
    # table: it scores F-RNG+ (plus) and its base, which the overlay leaves out
    import pandas as pd

    from frng.report.tables import TABLE_COLUMNS

    for name, cols in TABLE_COLUMNS.items():
        table = pd.read_csv(results / "tables" / f"{name}.csv")
        assert set(cols) <= set(table.columns), f"{name}.csv: {list(table.columns)}"
        # the SLURM overlay's run trains no F-RNG+: no Lambertian-base rows and no additions
        assert len(table) or name in ("lambertian", "additions"), f"{name}.csv: no rows"
    again = subprocess.run(
        [SNAKEMAKE, *SMOKE_SLURM, "--config", f"results={results}", "-n", "--cores", "1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert "Nothing to be done" in again.stdout + again.stderr, _tail(again)


def _cancel_and_stop(run: subprocess.Popen, log, job: str | None, timeout: float) -> int | None:
    """Cancel SLURM job ``job`` (None: it was never found) and wait for the snakemake run to stop by itself; terminate
    it if it has not (a failed wait). Returns its exit status, None if it had to be terminated."""
    rc = None
    try:
        if job is not None:
            subprocess.run(["scancel", job], check=True, timeout=20)
            rc = run.wait(timeout=timeout)
    finally:
        if run.poll() is None:
            run.terminate()
            run.wait(timeout=60)
        log.close()
    return rc
