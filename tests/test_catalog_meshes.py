"""The built-in mesh pool only holds meshes that can be curated (no NaN or collapsed vertices)."""

import numpy as np

from frng.plan import catalog, object_files


def _usable(path) -> bool:
    rows = [line.split()[1:4] for line in path.read_text(errors="ignore").splitlines() if line.startswith("v ")]
    try:
        v = np.array(rows, dtype=float)
    except ValueError:
        return False
    return len(v) >= 4 and bool(np.isfinite(v).all()) and float(np.ptp(v, axis=0).max()) > 1e-6


def test_broken_random_urdfs_list_matches_a_scan():
    root = object_files.pybullet_data_dir() / "random_urdfs"
    broken = {i for i in range(object_files.PYBULLET_RANDOM) if not _usable(root / f"{i:03d}" / f"{i:03d}.obj")}
    assert broken == set(object_files.PYBULLET_BROKEN)


def test_pool_excludes_broken_meshes():
    paths = [entry[0] for entry in catalog._pybullet_pool(0)]
    assert not any(f"random_urdfs/{i:03d}/" in p for p in paths for i in object_files.PYBULLET_BROKEN)
