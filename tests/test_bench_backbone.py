"""frng.diagnostics.bench_backbone's --model argument: NAME=PATH with inference settings, bad input named."""

import argparse
from pathlib import Path

import pytest

from frng.diagnostics.bench_backbone import _model_arg
from frng.priors.backbone_settings import BackboneSettings


def test_model_takes_a_path_and_settings():
    assert _model_arg("bb=results/backbone/model.pt") == ("bb", Path("results/backbone/model.pt"), BackboneSettings())
    name, path, s = _model_arg("g2=m.pt,guidance=2,normals=gbuffer,head=zero")
    assert (name, path, s) == ("g2", Path("m.pt"), BackboneSettings(2.0, "gbuffer", "zero"))
    assert s.describe() == "guidance 2, normals gbuffer, head zero" and BackboneSettings().describe() == "as trained"


@pytest.mark.parametrize(
    "text, message",
    [
        ("m.pt", "NAME=PATH"),
        ("bb=", "NAME=PATH"),
        ("bb=m.pt,cue=2", r"unknown setting\(s\) \['cue'\]"),
        ("bb=m.pt,guidance", "not key=value"),
        ("bb=m.pt,guidance=two", "guidance must be a number"),
        ("bb=m.pt,normals=mesh", "normals must be one of"),
        ("bb=m.pt,head=none", "head must be one of"),
        ("bb@sone=m.pt", "training seed"),
    ],
)
def test_bad_models_are_named(text, message):
    with pytest.raises(argparse.ArgumentTypeError, match=message):
        _model_arg(text)
