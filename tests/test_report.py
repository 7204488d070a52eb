"""Snakemake report captions (workflow/report/*.rst) render as snakemake renders them: jinja2 then docutils."""

from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
CAPTIONS = sorted((ROOT / "workflow" / "report").glob("*.rst"))


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")  # docutils writer_name, as snakemake calls it
@pytest.mark.parametrize("tier", ["smoke.yaml", "config.yaml", "paper.yaml"])
def test_captions_render(tier):
    from docutils.core import publish_parts
    from jinja2 import Environment, StrictUndefined

    cfg_path = ROOT / "config" / tier
    if not cfg_path.exists():
        pytest.skip(f"{cfg_path} not present")
    config = yaml.safe_load(cfg_path.read_text())
    config.setdefault("render", {})
    config["render"].setdefault("resolution", 64)  # defaults the schema would fill
    config["render"].setdefault("spp", 32)

    class Snakemake:  # what snakemake passes to the global description and captions
        pass

    Snakemake.config = config
    assert len(CAPTIONS) >= 10
    env = Environment(undefined=StrictUndefined)
    for path in CAPTIONS:
        text = env.from_string(path.read_text()).render(snakemake=Snakemake, categories={}, files={})
        html = publish_parts(text, writer_name="html", settings_overrides={"halt_level": 2, "report_level": 5})
        assert html["body"].strip(), path.name
