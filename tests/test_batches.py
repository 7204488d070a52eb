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
