"""The one variant table (frng.variants.VARIANTS): the schema, the model, the tables and the rules all read it."""

from pathlib import Path

import pytest
import yaml

from frng import config as frng_config
from frng import variants as V

ROOT = Path(__file__).resolve().parents[1]


def test_schema_enum_is_the_table():
    schema = yaml.safe_load((ROOT / "config" / "schema.yaml").read_text())
    prop = schema["properties"]["frng"]["properties"]["variants"]
    assert tuple(prop["items"]["enum"]) == V.BASE_VARIANTS
    assert tuple(prop["default"]) == V.BASE_VARIANTS


def test_variant_config_applies_the_table():
    from frng.model.frng import variant_config

    config = frng_config.load(ROOT / "config" / "smoke.yaml")
    full, ind_full = variant_config(config, "full")
    assert full.fine and full.prior_dim > 0 and full.head == "neural" and ind_full.lambda_c > 0
    assert not variant_config(config, "no-fine")[0].fine
    assert variant_config(config, "no-idm")[0].prior_dim == 0 and not variant_config(config, "no-idm")[0].uses_priors
    ind = variant_config(config, "no-ind")[1]
    assert ind.lambda_c == 0 and ind.lambda_kld == 0
    assert variant_config(config, "no-neural")[0].head == "pbr"
    assert variant_config(config, "k8")[0].top_k == pytest.approx(0.08)
    k_full = V.k_variant(config["frng"]["top_k_percent"])
    assert variant_config(config, k_full) == (full, ind_full)  # the K-sweep entry equal to K is the full model
    for bad in ("no-such", "kx", "k0", "k200"):
        with pytest.raises(ValueError, match=bad):
            variant_config(config, bad)


def test_labels_and_priors_come_from_the_table():
    from frng.report.paper_tables import VARIANT_LABELS

    assert VARIANT_LABELS == {n: v.label for n, v in V.VARIANTS.items()}
    assert [n for n in V.BASE_VARIANTS if not V.reads_priors(n)] == ["no-idm"]
    assert V.reads_priors("k4")
