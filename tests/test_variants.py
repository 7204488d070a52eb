"""The one variant table (frng.plan.variants.VARIANTS): the schema, the model, the tables and the rules all read it."""

from pathlib import Path

import pytest
import yaml

from frng.plan import config as frng_config
from frng.plan import variants as V
from frng.typedconfig import typed

ROOT = Path(__file__).resolve().parents[1]


def test_schema_enum_is_the_table():
    schema = yaml.safe_load((ROOT / "config" / "schema.yaml").read_text())
    prop = schema["properties"]["frng"]["properties"]["variants"]
    assert tuple(prop["items"]["enum"]) == tuple(V.VARIANTS)
    assert tuple(prop["default"]) == V.BASE_VARIANTS
    assert set(V.VARIANTS) - set(V.BASE_VARIANTS) == set(V.LEAVE_OUT_VARIANTS)  # plus-no-{addition}, opt-in


def test_each_leave_out_variant_is_f_rng_plus_with_one_addition_off():
    """plus-no-{addition} (the additions table): F-RNG+'s configuration with exactly that addition's paper-form
    fields, every other addition kept."""
    from frng.training.frng_trainer import ModelSections, variant_config

    sections = ModelSections.of(typed(frng_config.load(ROOT / "config" / "config.yaml")))
    plus, ind_plus = variant_config(sections, V.PLUS)
    assert set(V.LEAVE_OUT_VARIANTS.values()) == set(V.ADDITIONS)
    for name, key in V.LEAVE_OUT_VARIANTS.items():
        cfg, ind = variant_config(sections, name)
        a = V.ADDITIONS[key]
        assert {k: getattr(cfg, k) for k in a.arch} == a.arch and {k: getattr(ind, k) for k in a.loss} == a.loss
        others = {f for b in V.ADDITIONS.values() if b is not a for f in b.arch if f not in a.arch}
        assert {f: getattr(cfg, f) for f in others} == {f: getattr(plus, f) for f in others}, name
        assert V.variant(name + "@s1") == V.VARIANTS[name] and V.reads_priors(name)
    assert V.leave_out_variant("pixel_head") == "plus-no-pixel-head"


def test_variant_config_applies_the_table():
    from frng.training.frng_trainer import ModelSections, variant_config

    config = frng_config.load(ROOT / "config" / "smoke.yaml")
    sections = ModelSections.of(typed(config))
    full, ind_full = variant_config(sections, "full")
    assert full.fine and full.prior_dim > 0 and full.head == "neural" and ind_full.lambda_c > 0
    assert not variant_config(sections, "no-fine")[0].fine
    assert (
        variant_config(sections, "no-idm")[0].prior_dim == 0 and not variant_config(sections, "no-idm")[0].uses_priors
    )
    ind = variant_config(sections, "no-ind")[1]
    assert ind.lambda_c == 0 and ind.lambda_kld == 0
    assert variant_config(sections, "no-neural")[0].head == "pbr"
    assert variant_config(sections, "k8")[0].top_k == pytest.approx(0.08)
    k_full = V.k_variant(config["frng"]["top_k_percent"])
    assert variant_config(sections, k_full) == (full, ind_full)  # the K-sweep entry equal to K is the full model
    for bad in ("no-such", "kx", "k0", "k200"):
        with pytest.raises(ValueError, match=bad):
            variant_config(sections, bad)


def test_labels_and_priors_come_from_the_table():
    from frng.report.paper_tables import VARIANT_LABELS

    assert VARIANT_LABELS == {n: v.label for n, v in V.VARIANTS.items()}
    assert [n for n in V.BASE_VARIANTS if not V.reads_priors(n)] == ["no-idm"]  # F-RNG+ reads them
    assert V.reads_priors("k4")


def _cfg(**train):
    config = frng_config.load(ROOT / "config" / "smoke.yaml")
    config["train"].update(train)
    return config


def test_training_seeds_add_seeded_variants_and_runs():
    config = _cfg(seeds=[0, 1, 3])
    assert V.model_seed(config) == 0 and V.extra_seeds(config) == [1, 3]
    seeded = V.seeded_variants(config)
    assert seeded == [
        V.seed_variant(v, s) for s in (1, 3) for v in dict.fromkeys(["full", *config["frng"]["variants"]])
    ]
    assert "full@s1" in V.trained_variants(config) and "no-fine@s3" in V.all_variants(config)
    assert not any("@" in v for v in V.all_variants(config) if v.startswith("k"))  # the K sweep is not repeated
    assert V.split_seed("no-fine@s3") == ("no-fine", 3) and V.split_seed("full") == ("full", None)
    assert V.canonical_variant(config, "k" + format(config["frng"]["top_k_percent"], "g") + "@s1") == "full@s1"
    assert V.variant("no-idm@s1") == V.VARIANTS["no-idm"] and not V.reads_priors("no-idm@s1")
    runs = {r.name: r for r in V.runs(config)}
    assert runs["no-ind@s3"].seed == 3 and runs["no-ind@s3"].variant == "no-ind@s3" and runs["full"].seed is None
    assert not any(r.startswith("full-v") and "@" in r for r in runs)
    with pytest.raises(ValueError, match="training seed"):
        V.split_seed("full@sx")
    # the models' seed is the plain name: train_seed 1 with seeds [0, 1] adds @s0
    assert V.extra_seeds(_cfg(seeds=[0, 1]) | {"train_seed": 1}) == [0]
    assert V.seeded_variants(_cfg(seeds=[0])) == []


def test_relighting_groups_partition_the_runs():
    """One relighting job per group (rules/relight.smk): ``main`` (the models' seed and the backbone) and one per
    other training seed; the groups partition the runs, each reads only its own models."""
    plan = V.RunPlan.of(_cfg(seeds=[0, 1, 3]))
    assert plan.groups() == [V.MAIN_GROUP, "1", "3"]
    every = [r.name for r in plan.runs()]
    grouped = [r.name for g in plan.groups() for r in plan.runs(group=g)]
    assert sorted(grouped) == sorted(every) and len(set(grouped)) == len(grouped)
    main = plan.runs(group=V.MAIN_GROUP)
    assert {"full", V.BACKBONE} <= {r.name for r in main} and all(r.seed is None for r in main)
    assert {r.name for r in plan.runs(group="3")} == {V.seed_variant(v, 3) for v in ["full", *plan.variants]}
    assert plan.model_variants("1") == [V.seed_variant(v, 1) for v in dict.fromkeys(["full", *plan.variants])]
    assert not any("@" in v for v in plan.model_variants(V.MAIN_GROUP))
    with pytest.raises(ValueError, match="relighting group '2'"):
        plan.runs(group="2")
    assert V.RunPlan.of(_cfg(seeds=[0])).groups() == [V.MAIN_GROUP]


def test_lambertian_base_run_needs_the_cosine_decoder():
    config = _cfg()
    base = [r for r in V.runs(config) if r.name == V.BASE_RUN]
    assert len(base) == 1 and base[0].decoder == "base" and base[0].variant == V.PLUS and base[0].priors == "idm"
    config["shading"]["decoder_cosine"] = False
    assert V.BASE_RUN not in [r.name for r in V.runs(config)]


def test_only_the_labelled_oracle_run_is_told_the_input_light():
    config = _cfg()
    told = [r for r in V.runs(config) if r.light != "estimated"]
    assert [(r.name, r.variant, r.light) for r in told] == [(V.KNOWN_LIGHT_RUN, V.PLUS, "known")]
    config["frng"]["variants"] = [v for v in config["frng"]["variants"] if v != V.PLUS]
    assert all(r.light == "estimated" and r.variant != V.PLUS for r in V.runs(config))


def test_full_and_the_ablations_are_the_paper_form_and_plus_has_the_additions():
    """Every variant but F-RNG+ has every addition off (frng.plan.variants.ADDITIONS); F-RNG+ keeps the config's."""
    from frng.training.frng_trainer import ModelSections, variant_config

    config = frng_config.load(ROOT / "config" / "config.yaml")
    sections = ModelSections.of(typed(config))
    arch_off, loss_off = V.paper_form()
    for name in [*V.ABLATION_VARIANTS, "k4"]:
        cfg, ind = variant_config(sections, name)
        assert {k: getattr(cfg, k) for k in arch_off} == arch_off, name
        assert {k: getattr(ind, k) for k in loss_off} == loss_off, name
    plus, ind_plus = variant_config(sections, V.PLUS)
    assert plus.pixel_head > 0 and plus.decoder_cosine and plus.opacity_head and ind_plus.pixels
    assert plus.fine and plus.prior_dim > 0 and plus.head == "neural" and ind_plus.lambda_c > 0
    assert V.PLUS not in V.ABLATION_VARIANTS and set(V.ABLATION_VARIANTS) | {V.PLUS} == set(V.BASE_VARIANTS)


def test_tier_seeds():
    default = frng_config.load(ROOT / "config" / "config.yaml")
    assert default["train"]["seeds"] == [0] and V.extra_seeds(default) == []
    seeds = frng_config.load_overlaid(ROOT / "config/config.yaml", ROOT / "config/seeds.yaml")
    assert seeds["train"]["seeds"] == [0, 1] and V.extra_seeds(seeds) == [1]  # `make seeds`
    for tier in ("smoke.yaml", "paper.yaml"):
        assert V.extra_seeds(frng_config.load(ROOT / "config" / tier)) == [], tier


def test_train_stage_trains_a_seeded_variant_with_its_seed(monkeypatch, tmp_path):
    import argparse

    from frng.stages import train as stage

    seen = {}
    monkeypatch.setattr(
        stage,
        "train",
        lambda sections, tcfg, job, variant, out, backbone, steps=None, geometry="backbone": (
            seen.update(variant=variant, seed=job.seed, out=out, geometry=geometry) or out / "model.pt"
        ),
    )
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(_cfg(seeds=[0, 2]) | {"results": str(tmp_path)}))
    parser = argparse.ArgumentParser()
    stage.configure(parser)
    assert stage.run(parser.parse_args(["--config", str(cfg), "--variant", "no-fine@s2"])) == 0
    assert seen["variant"] == "no-fine" and seen["seed"] == 2 and seen["out"].name == "no-fine@s2"
    assert seen["geometry"] == "backbone"  # the pipeline's models sit on the backbone's geometry
