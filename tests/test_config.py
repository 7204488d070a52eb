"""Config validation: the shipped configs pass; bad ones fail naming the key."""

import copy

import pytest
import yaml

from frng import config as cfg


@pytest.mark.parametrize("name", ["config.yaml", "smoke.yaml", "paper.yaml"])
def test_shipped_configs_validate(root, name):
    c = cfg.load(root / "config" / name)
    assert c["model"]["patch_size"] == 8
    assert c["render"]["resolution"] % c["model"]["patch_size"] == 0


def _base(root):
    return yaml.safe_load((root / "config" / "smoke.yaml").read_text())


@pytest.mark.parametrize(
    "mutate, key",
    [
        (lambda c: c.update(bogus=1), "bogus"),
        (lambda c: c["render"].update(resolution="64"), "render.resolution"),
        (lambda c: c["render"].update(resolution=36), "render.resolution"),
        (lambda c: c["render"].update(unknown_key=3), "render.unknown_key"),
        (lambda c: c["objects"].update(count=3, test_count=3), "objects.count"),
        (lambda c: c["objects"].update(test_count=0), "objects.test_count"),
        (lambda c: c["objects"].update(material_mix={"diffuse": 0.5, "specular": 0.4, "fur": 0.2}), "objects.material_mix"),
        (lambda c: c["envmaps"].update(extra=[{"path": "x"}]), "envmaps.extra[0]"),
    ],
)
def test_bad_config_names_key(root, mutate, key):
    c = _base(root)
    mutate(c)
    with pytest.raises(cfg.ConfigError) as e:
        cfg.validate(copy.deepcopy(c))
    assert f"'{key}" in str(e.value), str(e.value)


def test_defaults_filled(root):
    c = cfg.validate(_base(root))
    assert c["seed"] == 0 and c["device"] == "auto"
    assert c["envmaps"]["skies"]["turbidity"] == 3.0


def test_cli_config_reports_error(tmp_path, root, capsys):
    bad = _base(root)
    bad["render"]["resolution"] = 30
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(bad))
    from frng.cli import main

    with pytest.raises(SystemExit) as e:
        main(["config", str(p)])
    assert e.value.code == 1
    assert "render.resolution" in capsys.readouterr().out
