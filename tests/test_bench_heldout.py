"""frng.diagnostics.bench_heldout's report: models named NAME@sS are training seeds of NAME, compared as one model."""

import argparse

import numpy as np
import pandas as pd
import pytest

from frng.diagnostics._heldout import _model_arg, seed_groups, summary


def _rows(model, shift):
    return [
        dict(
            model=model,
            decoder="full",
            object=o,
            light=l,
            view="v0",
            psnr=18.0 + shift + 0.5 * j + 0.25 * i,
            ssim=0.5,
            lpips=0.1,
            psnr_other_light=17.0,
            **{"class": "diffuse"},
        )
        for j, o in enumerate(("o0", "o1", "o2"))
        for i, l in enumerate(("l0", "l1"))
    ]


def test_seed_groups_follow_the_pipeline_naming():
    assert seed_groups(["full", "full@s1", "x", "x@s1", "y"]) == {
        "full": ["full", "full@s1"],
        "x": ["x", "x@s1"],
        "y": ["y"],
    }
    with pytest.raises(argparse.ArgumentTypeError, match="training seed"):
        _model_arg("full@sone=m.pt")


def test_seeds_are_averaged_and_resampled_in_the_comparison():
    df = pd.DataFrame(
        _rows("full", 0.0) + _rows("full@s1", 0.2) + _rows("x", 1.0) + _rows("x@s1", 1.4) + _rows("y", 0.5)
    )
    out = summary(df, ["full", "full@s1", "x", "x@s1", "y"])
    assert "x: 2 training seeds, PSNR x 19.6250, x@s1 20.0250 (spread 0.4000)" in out, out
    # x - full: seed means +1.2 - +0.1 = +1.1; the seed draws reach +1.0 - 0.2 = 0.8 and +1.4 - 0.0 = 1.4
    line = next(ln for ln in out.splitlines() if ln.startswith("x - full:"))
    assert "psnr +1.1000 [+0.8000, +1.4000]" in line and "training seeds (2 vs 2)" in line, line
    # y (one seed) against full's two: +0.5 - {0.0, 0.1, 0.2}
    line = next(ln for ln in out.splitlines() if ln.startswith("y - full:"))
    assert "psnr +0.4000 [+0.3000, +0.5000]" in line and "(1 vs 2)" in line, line
    # no seeds: the object bootstrap of before, and no seed lines
    plain = summary(df[df["model"].isin(["full", "y"])], ["full", "y"])
    assert "y - full: psnr +0.5000 [+0.5000, +0.5000]" in plain and "training seeds" not in plain
    # a lone seed keeps its own name
    lone = summary(df[df["model"].isin(["full", "x@s1"])], ["full", "x@s1"])
    assert "x@s1 - full: psnr +1.4000" in lone, lone
    assert np.isfinite(df["psnr"]).all()


def test_validation_objects_are_every_fifth_of_the_sorted_training_split():
    from frng.diagnostics._heldout import validation_objects

    train = [f"obj_{i:04d}" for i in range(12, 0, -1)] + ["libero_mug"]
    assert validation_objects(train) == ["libero_mug", "obj_0005", "obj_0010"]


def test_selected_objects_names_what_is_wrong(tmp_path, capsys):
    """Repeated model names, a missing model file and objects outside the config are errors naming them; otherwise
    the --split's (or --objects') objects."""
    from frng.diagnostics._heldout import selected_objects

    class Plan:
        object_ids = ["a", "b", "c", "t"]

        def split(self, name):
            return {"train": ["a", "b", "c"], "test": ["t"]}[name]

    model = tmp_path / "model.pt"
    model.write_bytes(b"")
    args = argparse.Namespace(objects=None, split="test")
    assert selected_objects(Plan(), args, [("x", model)], "heldout") == ["t"]
    assert selected_objects(Plan(), argparse.Namespace(objects=None, split="val"), [], "heldout") == ["a"]
    for models, objects, message in [
        ([("x", model), ("x", model)], None, "model names repeat: ['x', 'x']"),
        ([("x", tmp_path / "none.pt")], None, f"model x: {tmp_path / 'none.pt'} does not exist"),
        ([("x", model)], ["t", "zz"], "not objects of this config: ['zz']"),
    ]:
        out = selected_objects(Plan(), argparse.Namespace(objects=objects, split="test"), models, "backbone")
        assert out is None
        assert f"frng bench backbone: error: {message}" in capsys.readouterr().err
