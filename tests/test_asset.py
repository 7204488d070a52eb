"""Relightable asset format (frng.apps.asset): exact round trip, a standard PLY header, validation, atomic writes."""

import json

import numpy as np
import pytest
import torch

from frng.apps.asset import (
    BASE_PROPERTIES,
    AssetError,
    load_asset,
    read_ply,
    read_ply_header,
    save_asset,
    write_ply,
)
from frng.gaussians import Gaussians

N, C = 300, 8
META = {
    "object_id": "chair_012",
    "source_views": ["v0", "v1", "v2"],
    "decoder": {"width": 32, "depth": 2, "input_encoding": "features+dirs"},
}


def _asset():
    g = torch.Generator().manual_seed(0)
    q = torch.randn(N, 4, generator=g)
    gauss = Gaussians(
        means=torch.randn(N, 3, generator=g) * 0.5,
        quats=q / q.norm(dim=1, keepdim=True),
        scales=torch.exp(torch.randn(N, 3, generator=g) - 3.0),
        opacities=torch.rand(N, generator=g).clamp(1e-4, 1 - 1e-4),
    )
    feats = torch.randn(N, C, generator=g)
    torch.manual_seed(0)
    dec = torch.nn.Sequential(torch.nn.Linear(C, 32), torch.nn.GELU(), torch.nn.Linear(32, 3)).state_dict()
    return gauss, feats, dec


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    gauss, feats, dec = _asset()
    preview = torch.rand(N, 3, generator=torch.Generator().manual_seed(1))
    folder = save_asset(tmp_path_factory.mktemp("a") / "asset", gauss, feats, dec, META, preview_rgb=preview)
    return folder, gauss, feats, dec, preview


def test_round_trip(saved):
    folder, gauss, feats, dec, preview = saved
    g2, f2, dec2, meta = load_asset(folder)
    assert torch.equal(g2.means, gauss.means) and torch.equal(g2.quats, gauss.quats)
    assert torch.equal(f2, feats) and torch.equal(g2.features, feats)
    # opacity/scale pass through float32 logit/log: exact to float32 precision
    torch.testing.assert_close(g2.opacities, gauss.opacities, rtol=1e-6, atol=0)
    torch.testing.assert_close(g2.scales, gauss.scales, rtol=1e-6, atol=0)
    assert dec2.keys() == dec.keys() and all(torch.equal(dec2[k], dec[k]) for k in dec)
    torch.testing.assert_close(meta["preview_rgb"], preview, atol=2e-6, rtol=0)
    assert meta["version"] == 1 and meta["feature_dim"] == C and meta["num_gaussians"] == N
    assert meta["object_id"] == "chair_012" and meta["source_views"] == ["v0", "v1", "v2"]
    assert meta["decoder"]["width"] == 32 and "Z up" in meta["conventions"]["world"]


def test_ply_is_standard_3dgs(saved):
    folder = saved[0]
    raw = (folder / "gaussians.ply").read_bytes()
    head = raw[: raw.index(b"end_header\n") + len(b"end_header\n")].decode("ascii").splitlines()
    assert head[0] == "ply" and head[1] == "format binary_little_endian 1.0"
    assert f"element vertex {N}" in head
    props = [l.split() for l in head if l.startswith("property")]
    assert all(p[1] == "float" for p in props)
    names = [p[2] for p in props]
    assert names == list(BASE_PROPERTIES) + [f"feat_{i}" for i in range(C)]
    assert head[-1] == "end_header"
    assert len(raw) - len("\n".join(head)) - 1 == N * len(names) * 4  # exactly N rows of float32 after header
    # values as 3DGS stores them: logit opacity, log scale
    gauss = saved[1]
    fields = read_ply(folder / "gaussians.ply")
    np.testing.assert_allclose(1 / (1 + np.exp(-fields["opacity"])), gauss.opacities.numpy(), rtol=1e-6)
    np.testing.assert_allclose(np.exp(fields["scale_1"]), gauss.scales[:, 1].numpy(), rtol=1e-6)
    assert np.all(fields["nx"] == 0)


def test_ply_alone_mixed_types_and_ascii(tmp_path):
    fields = {
        "a": np.arange(5, dtype=np.float64),
        "b": np.arange(5, dtype=np.uint8),
        "c": -np.arange(5, dtype=np.int32),
    }
    write_ply(tmp_path / "x.ply", fields, element="point", comments=["hello"])
    back = read_ply(tmp_path / "x.ply", element="point")
    assert list(back) == ["a", "b", "c"] and all(
        np.array_equal(back[k], fields[k]) and back[k].dtype == fields[k].dtype for k in fields
    )
    assert read_ply_header(tmp_path / "x.ply")["comments"] == ["hello"]
    (tmp_path / "t.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty uchar k\nend_header\n1.5 3\n-2 4\n"
    )
    back = read_ply(tmp_path / "t.ply")
    assert back["x"].tolist() == [1.5, -2.0] and back["k"].tolist() == [3, 4]


def _copy(saved, tmp_path):
    import shutil

    dst = tmp_path / "copy"
    shutil.copytree(saved[0], dst)
    return dst


def test_missing_and_corrupt_files(saved, tmp_path):
    d = _copy(saved, tmp_path)
    (d / "decoder.safetensors").unlink()
    with pytest.raises(AssetError, match="decoder.safetensors: missing file"):
        load_asset(d)
    with pytest.raises(AssetError, match="does not exist"):
        load_asset(tmp_path / "nope")

    d = _copy(saved, tmp_path / "b")
    (d / "decoder.safetensors").write_bytes(b"garbage")
    with pytest.raises(AssetError, match="decoder.safetensors: cannot read"):
        load_asset(d)

    d = _copy(saved, tmp_path / "c")
    raw = (d / "gaussians.ply").read_bytes()
    (d / "gaussians.ply").write_bytes(raw[:-10])
    with pytest.raises(AssetError, match="gaussians.ply: PLY truncated"):
        load_asset(d)


def test_wrong_version_and_counts(saved, tmp_path):
    d = _copy(saved, tmp_path)
    meta = json.loads((d / "asset.json").read_text())
    (d / "asset.json").write_text(json.dumps({**meta, "version": 99}))
    with pytest.raises(AssetError, match=r"asset.json: field 'version' is 99"):
        load_asset(d)
    (d / "asset.json").write_text(json.dumps({**meta, "feature_dim": C + 1}))
    with pytest.raises(AssetError, match=rf"gaussians.ply: has {C} feat_\* properties .* 'feature_dim' says {C + 1}"):
        load_asset(d)
    (d / "asset.json").write_text("{not json")
    with pytest.raises(AssetError, match="asset.json: invalid JSON"):
        load_asset(d)


def test_nan_field_named(saved, tmp_path):
    d = _copy(saved, tmp_path)
    fields = read_ply(d / "gaussians.ply")
    fields["feat_3"][7] = np.nan
    write_ply(d / "gaussians.ply", fields)
    with pytest.raises(
        AssetError, match=r"gaussians.ply: field 'feat_3' has 1 non-finite value\(s\) \(first at row 7\)"
    ):
        load_asset(d)


def test_atomic_write(tmp_path, monkeypatch):
    gauss, feats, dec = _asset()
    bad = {**dec, "oops": "not a tensor"}
    with pytest.raises(ValueError, match="oops"):
        save_asset(tmp_path / "asset", gauss, feats, bad, META)
    assert list(tmp_path.iterdir()) == []

    # a failure after some files are written leaves neither the final folder nor the temporary one
    import safetensors.torch

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(safetensors.torch, "save", boom)
    with pytest.raises(OSError, match="disk full"):
        save_asset(tmp_path / "asset", gauss, feats, dec, META)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()

    # overwrite replaces a previous asset whole
    save_asset(tmp_path / "asset", gauss, feats, dec, META)
    save_asset(tmp_path / "asset", gauss[:10], feats[:10], dec, {**META, "object_id": "other"})
    g2, _, _, meta = load_asset(tmp_path / "asset")
    assert len(g2) == 10 and meta["object_id"] == "other"
    assert [p.name for p in tmp_path.iterdir()] == ["asset"]


def test_meta_required(tmp_path):
    gauss, feats, dec = _asset()
    with pytest.raises(ValueError, match="input_encoding"):
        save_asset(tmp_path / "a", gauss, feats, dec, {"object_id": "x", "decoder": {"width": 1, "depth": 1}})
    with pytest.raises(ValueError, match=r"features must be \(N=300, C\)"):
        save_asset(tmp_path / "a", gauss, feats[:5], dec, META)
    assert not (tmp_path / "a").exists()


def test_renderer_applies_the_saved_coverage_head_and_refuses_stray_weights(tmp_path):
    """An asset from a model with the silhouette rim's coverage head (frng.coverage_head) renders with it: the
    head's weights ride in decoder.safetensors under ``coverage.`` and AssetRenderer.rasterize applies them as
    FRNG.rasterize does (without them ``frng reconstruct`` + ``render-asset`` missed ``frng relight`` by up to 1 dB
    at the rim). Weights without ``decoder.coverage_hidden`` are refused, naming the file."""
    from test_untrusted_outputs import tiny_asset

    from frng.apps.asset import AssetRenderer
    from frng.model.coverage import COVERAGE_PREFIX, CoverageHead

    plain = AssetRenderer(tiny_asset(tmp_path / "plain"))
    g, feats, state, meta = load_asset(tmp_path / "plain")
    meta.pop("preview_rgb")  # decoded from the PLY, not an asset.json field
    torch.manual_seed(1)
    head = CoverageHead(feats.shape[1], 4)
    torch.nn.init.constant_(head.net[-1].bias, -2.0)  # a trained head that thins the rim
    weights = {**state, **{COVERAGE_PREFIX + k: v for k, v in head.state_dict().items()}}
    meta["decoder"] = {**meta["decoder"], "coverage_hidden": 4}
    with_head = AssetRenderer(save_asset(tmp_path / "cov", g, feats, weights, meta))
    c2w = torch.eye(4)[None].clone()
    c2w[0, 2, 3] = -3.0  # 3 units back along -z, looking at the origin (OpenCV: +z forward)
    intr = torch.tensor([[20.0, 20.0, 8.0, 8.0]])
    maps, alpha, _, _ = plain.rasterize(c2w, intr, 16, 16)
    maps_c, alpha_c, _, _ = with_head.rasterize(c2w, intr, 16, 16)
    with torch.no_grad():
        want_maps, want_alpha = head(maps, alpha)
    assert (alpha_c < alpha - 1e-4).any(), "the head thins no rim pixel"
    torch.testing.assert_close(alpha_c, want_alpha)
    torch.testing.assert_close(maps_c, want_maps)
    meta["decoder"]["coverage_hidden"] = 0
    save_asset(tmp_path / "stray", g, feats, weights, meta)
    with pytest.raises(AssetError, match=r"decoder\.safetensors: does not fit .*coverage-head tensors"):
        AssetRenderer(tmp_path / "stray")
