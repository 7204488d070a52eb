"""Config validation: the shipped configs pass; bad ones fail naming the key."""

import copy
import json

import pytest
import yaml

from frng.plan import config as cfg


@pytest.mark.parametrize("name", ["config.yaml", "smoke.yaml", "paper.yaml"])
def test_shipped_configs_validate(root, name):
    c = cfg.load(root / "config" / name)
    assert c["model"]["patch_size"] == (12 if name == "config.yaml" else 8)  # default tier: 96 px, 8 x 8 tokens
    assert c["render"]["resolution"] % c["model"]["patch_size"] == 0


def _base(root):
    return yaml.safe_load((root / "config" / "smoke.yaml").read_text())


@pytest.mark.parametrize(
    "mutate, key",
    [
        (lambda c: c.update(bogus=1), "bogus"),
        (lambda c: c["render"].update(resolution="64"), "render.resolution"),
        (lambda c: c["render"].update(resolution=36), "render.resolution"),
        (lambda c: c["render"].update(resolution=32.0), "render.resolution"),  # JSON Schema's integer takes 32.0
        (lambda c: c["render"].update(spp=True), "render.spp"),
        (lambda c: c["render"].update(unknown_key=3), "render.unknown_key"),
        (lambda c: c["objects"].update(count=3, test_count=3), "objects.count"),
        (lambda c: c["objects"].update(test_count=0), "objects.test_count"),
        (
            lambda c: c["objects"].update(material_mix={"diffuse": 0.5, "specular": 0.4, "fur": 0.2}),
            "objects.material_mix",
        ),
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


# -- issue 12, point 6: a bad config file ends in one line naming the file (and line), not a traceback ------------


def test_float_resolution_names_key(root):
    c = _base(root)
    c["render"]["resolution"] = 32.0
    with pytest.raises(cfg.ConfigError, match=r"'render.resolution': 32.0 is not of type 'integer'"):
        cfg.validate(c)


def test_yaml_syntax_error_names_file_and_line(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text("tier: smoke\nrender:\n  resolution: 32\n  spp: [8\nseed: 0\n")
    with pytest.raises(cfg.ConfigError) as e:
        cfg.load(p)
    assert str(p) in str(e.value) and "line " in str(e.value) and "invalid YAML" in str(e.value), str(e.value)


def test_missing_config_names_file(tmp_path):
    with pytest.raises(cfg.ConfigError, match="does not exist"):
        cfg.load(tmp_path / "nope.yaml")


def _stage_stderr(argv, capsys):
    from frng.cli import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    return e.value.code, err


@pytest.mark.parametrize(
    "content, words",
    [("tier: smoke\nrender: {resolution: 32\n", ["line 3", "invalid YAML"]), (None, ["does not exist"])],
)
def test_stage_with_bad_config_file_prints_one_line(tmp_path, capsys, content, words):
    p = tmp_path / "stage.yaml"
    if content is not None:
        p.write_text(content)
    code, err = _stage_stderr(["envmaps", "--config", str(p), "--out", str(tmp_path / "out")], capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert str(p) in err and all(w in err for w in words), err
    assert not (tmp_path / "out").exists()


def test_stage_with_unwritable_output_prints_one_line(monkeypatch, capsys, tmp_path):
    """A read-only results folder (simulated: tests may run as root, who can write anywhere)."""
    from frng import cli

    def run(args):
        raise PermissionError(13, "Permission denied", str(tmp_path / "results" / "envmaps"))

    code = cli.run_stage("envmaps", run, None)
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{tmp_path / 'results' / 'envmaps'}: Permission denied" in err, err


def test_record_refuses_a_different_config_naming_keys(tmp_path, root):
    c = cfg.validate(_base(root))
    path = tmp_path / "results" / "config.yaml"
    assert cfg.record(c, path) == "written"
    mtime = path.stat().st_mtime_ns
    assert cfg.record(copy.deepcopy(c), path) == "unchanged" and path.stat().st_mtime_ns == mtime
    other = copy.deepcopy(c)
    other["render"]["spp"] = 99
    with pytest.raises(cfg.ConfigError) as e:
        cfg.record(other, path)
    assert str(path) in str(e.value) and "render.spp: recorded 8, now 99" in str(e.value)
    assert cfg.record(other, path, overwrite=True) == "replaced"
    assert cfg.read_recorded(path) == other


def test_record_into_unwritable_folder_names_it(tmp_path, root, monkeypatch):
    import pathlib

    def refuse(self, *a, **k):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(pathlib.Path, "write_text", refuse)
    path = tmp_path / "results" / "config.yaml"
    with pytest.raises(cfg.ConfigError, match=r"cannot write .*config.yaml: Permission denied"):
        cfg.record(cfg.validate(_base(root)), path)
    assert not list((tmp_path / "results").iterdir())  # no temporary file left behind


def test_read_only_results_folder_names_it(tmp_path, root, monkeypatch):
    """os.access is simulated: tests may run as root, for whom chmod 0555 does not stop writes."""
    import os

    results = tmp_path / "results"
    results.mkdir()
    monkeypatch.setattr(os, "access", lambda path, mode: str(path) != str(results))
    with pytest.raises(cfg.ConfigError, match=f"results folder {results} is not writable"):
        cfg.record(cfg.validate(_base(root)), results / "config.yaml")
    assert not list(results.iterdir())


@pytest.mark.skipif(
    not hasattr(__import__("os"), "geteuid") or __import__("os").geteuid() == 0,
    reason="root writes into read-only folders",
)
def test_read_only_results_folder_for_real(tmp_path, root):
    results = tmp_path / "results"
    results.mkdir()
    results.chmod(0o555)
    try:
        with pytest.raises(cfg.ConfigError, match="is not writable"):
            cfg.record(cfg.validate(_base(root)), results / "config.yaml")
    finally:
        results.chmod(0o755)


def test_corrupt_record_is_replaced_only_on_overwrite(tmp_path, root):
    c = cfg.validate(_base(root))
    path = tmp_path / "config.yaml"
    path.write_text("tier: [smoke\n")
    with pytest.raises(cfg.ConfigError, match=r"config.yaml, line 2 .*overwrite_config=true"):
        cfg.record(c, path)
    assert cfg.record(c, path, overwrite=True) == "replaced"
    assert cfg.read_recorded(path) == c


def test_cli_config_merges_overlays_and_names_them(tmp_path, root, capsys):
    """`frng config PATH OVERLAY`: what `make seeds` checks before snakemake merges the same files."""
    from frng.cli import main

    base = tmp_path / "base.yaml"
    base.write_text(yaml.safe_dump(_base(root)))
    good, bad = tmp_path / "seeds.yaml", tmp_path / "bad.yaml"
    good.write_text(yaml.safe_dump({"train": {"seeds": [0, 1]}}))
    bad.write_text(yaml.safe_dump({"train": {"seeds": [1, 1]}}))
    with pytest.raises(SystemExit) as e:
        main(["config", "--json", str(base), str(good)])
    assert e.value.code == 0
    assert json.loads(capsys.readouterr().out)["train"]["seeds"] == [0, 1]
    assert cfg.load_overlaid(base, good)["train"]["seeds"] == [0, 1]
    with pytest.raises(SystemExit) as e:
        main(["config", "--check", str(base), str(bad)])
    out = capsys.readouterr().out
    assert e.value.code == 1 and f"{base} + {bad}" in out and "train.seeds" in out, out
