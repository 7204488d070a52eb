# Shared helpers: config validation, object/light lists, output paths.
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir).parent))  # import frng without installing (conda users)

from frng import config as frng_config

try:
    frng_config.validate(config)
except frng_config.ConfigError as e:
    raise WorkflowError(f"invalid config: {e}")

RESULTS = config["results"]
ROOT = Path(workflow.basedir).parent
# The validated config (defaults filled, --config overrides applied) that every stage reads via
# `--config {CONFIG_FILE}`. Rewritten only when its content changes, one per results folder.
CONFIG_FILE = str(Path(RESULTS, "config.yaml"))
frng_config.write_resolved(config, CONFIG_FILE)
# Python running the stages: the interpreter snakemake runs in (the project's venv) unless --sdm conda.
PY = sys.executable


def res(*parts):
    return str(Path(RESULTS, *parts))


_TARGETS = []


def add_targets(*paths):
    """Stage rule files register what `rule all` should build."""
    _TARGETS.extend(paths)


def all_targets():
    return list(_TARGETS)
