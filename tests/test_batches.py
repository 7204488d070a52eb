"""Batches of the per-object prior rules (frng/plan/batches.py, rules/priors.smk): every object in exactly one batch, in
order, sizes within one of each other; the `priors_batch` switch; batch rule names map back to their family."""

import pytest

from frng.plan.batches import DEFAULT_BATCH_OBJECTS, batch_size, batches, object_batches, object_outputs, rule_family


@pytest.mark.parametrize("n", [0, 1, 5, 16, 31, 32, 33, 104, 900])
@pytest.mark.parametrize("size", [1, 3, 32])
def test_batches_cover_every_object_once_in_order(n, size):
    ids = [f"obj_{i:04d}" for i in range(n)]
    got = batches(ids, size)
    assert [o for b in got for o in b] == ids
    assert len(got) == -(-n // size)
    assert all(1 <= len(b) <= size for b in got)
    assert not got or max(map(len, got)) - min(map(len, got)) <= 1


def test_object_batches_per_split():
    got = object_batches({"train": [f"a{i}" for i in range(104)], "test": [f"b{i}" for i in range(16)]}, 32)
    assert list(got) == ["train0", "train1", "train2", "train3", "test0"]
    assert [len(b) for b in got.values()] == [26, 26, 26, 26, 16]


def test_batch_size_switch():
    config = {"results": "r", "priors_batch": "8"}
    assert batch_size(config) == 8 and "priors_batch" not in config  # popped: never recorded with the config
    assert batch_size({}) == DEFAULT_BATCH_OBJECTS
    for bad in (0, -1, "x", 2.5, "3.0"):
        with pytest.raises(ValueError, match="priors_batch"):
            batch_size({"priors_batch": bad})


def test_rule_family():
    assert rule_family("backbone_cache_train0") == "backbone_cache"
    assert rule_family("idm_priors_test12") == "idm_priors"
    for name in ("backbone_cache", "backbone_train", "train", "relight", "training_set_caches"):
        assert rule_family(name) == name


def test_object_outputs():
    assert object_outputs(["a", "b"], None, lambda o: f"{o}.st") == ["a.st", "b.st"]
    assert object_outputs(["a", "b"], ["x", "y"], str) == ["x", "y"]
    with pytest.raises(ValueError, match="one per object"):
        object_outputs(["a", "b"], ["x"], str)
    with pytest.raises(ValueError, match="twice"):
        object_outputs(["a", "a"], ["x", "y"], str)


def test_batch_rules_inherit_their_familys_profile_settings():
    """rules/common.smk's inherit_profile_settings reads `--set-threads` / `--set-resources` through Snakemake's
    public ResourceSettings fields (as its CLI parses them): a batch rule gets its family's threads and resources,
    and its own entries win."""
    import re
    import types
    from pathlib import Path

    from snakemake.cli import parse_set_resources, parse_set_threads
    from snakemake.resources import Resources
    from snakemake.settings.types import ResourceSettings

    text = (Path(__file__).resolve().parent.parent / "rules" / "common.smk").read_text()
    source = re.search(r"(?ms)^def inherit_profile_settings\(name\):\n.*?(?=^\S)", text).group(0)
    settings = ResourceSettings(
        overwrite_threads=parse_set_threads(["backbone_cache=3", "idm_priors_test0=2"]),
        overwrite_resources=parse_set_resources(
            ["backbone_cache:mem_mb=1234", "idm_priors:mem_mb=500", "idm_priors_test0:mem_mb=700"]
        ),
    )
    rules = {n: types.SimpleNamespace(resources=Resources()) for n in ("backbone_cache_train0", "idm_priors_test0")}
    for r in rules.values():
        r.resources["_cores"] = 1
    workflow = types.SimpleNamespace(resource_settings=settings, get_rule=rules.__getitem__)
    namespace = {"workflow": workflow, "rule_family": rule_family}
    exec(source, namespace)
    for name in rules:
        namespace["inherit_profile_settings"](name)
    cache, priors = (dict(rules[n].resources.unwrapped_items()) for n in rules)
    assert cache["_cores"] == 3 and cache["mem_mb"] == 1234
    assert priors["_cores"] == 1 and priors["mem_mb"] == 700  # its own --set-threads entry Snakemake applies itself
