"""The curated images' Monte-Carlo noise floor (``frng bench targets-noise``, :mod:`frng.diagnostics.bench_targets_noise`):
target views of planned objects rendered exactly as curation renders them (:func:`frng.data.curate.object_scene`:
the same mesh, material, seed and rig views) under several sampling settings (:class:`Sampling`: samples per pixel,
OpenImageDenoise, Cycles' clamps) and scored against a high-spp reference of the same view with the pipeline's
metrics (:func:`frng.metrics.evaluate_pair`).

The reference is the mean of two raw, unclamped renders of ``reference_spp`` samples with two other Cycles seeds
than the settings' (its noise is independent of theirs); row ``reference-half`` scores one of them against the other:
where noise dominates, the reference's own MSE is a quarter of that row's (6 dB above it). Setting ``tier`` is the
config's own ``render.*``: its images are the dataset's, bit for bit (tests/test_clean_targets.py).

Setting specs ``SPP[+oidn[=P]][+noclamp|+clamp=D/I]``: SPP samples per pixel, raw (no denoising) and Blender's
default clamps (direct 0, indirect 10) unless ``oidn`` (OpenImageDenoise with albedo + normal passes,
:func:`frng.blender.scene.set_sampling`; ``=P`` its prefilter of those passes, ``none`` (default), ``fast`` or
``accurate``), ``noclamp`` (clamps 0 / 0) or ``clamp=D/I``; or ``tier``.

Render times are wall-clock of :func:`frng.blender.scene.render_to`; each setting's first view per object and light
re-syncs the scene (as curation's first render does), the others reuse it (``use_persistent_data``, as curation).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from frng.plan.layout import EnvmapFolder

BLENDER_CLAMPS = (0.0, 10.0)  # Cycles' default sample_clamp_direct / sample_clamp_indirect
TIER = "tier"
REFERENCE = "reference"
PREFILTERS = ("none", "fast", "accurate")  # frng.blender.scene.DENOISE_PREFILTERS (that module needs bpy)
HALF = "reference-half"  # the second reference render scored against the first
_SPEC = re.compile(r"^(?P<spp>[0-9]+)(?P<rest>(\+[a-z]+(=[a-z0-9./]+)?)*)$")


@dataclasses.dataclass(frozen=True)
class Sampling:
    """One sampling setting: its name (the ``--settings`` spec) and Cycles' values."""

    name: str
    spp: int
    denoise: bool
    clamp_direct: float
    clamp_indirect: float
    prefilter: str  # OIDN's prefilter of the albedo / normal passes (frng.blender.scene.DENOISE_PREFILTERS)


def parse_setting(spec: str, render) -> Sampling:
    """``--settings`` spec -> :class:`Sampling`; ``render``: the config's render section (for ``tier``)."""
    if spec == TIER:
        return Sampling(
            TIER, render.spp, render.denoise, render.clamp_direct, render.clamp_indirect, render.denoise_prefilter
        )
    m = _SPEC.match(spec)
    if m is None or int(m["spp"]) < 1:
        raise ValueError(f"--settings {spec!r}: expected 'tier' or SPP[+oidn[=P]][+noclamp|+clamp=D/I], e.g. 32+oidn")
    denoise, prefilter, (cd, ci) = False, PREFILTERS[0], BLENDER_CLAMPS
    for token in filter(None, m["rest"].split("+")):
        if token == "oidn" or (token.startswith("oidn=") and token[len("oidn=") :] in PREFILTERS):
            denoise, prefilter = True, token.partition("=")[2] or PREFILTERS[0]
        elif token == "noclamp":
            cd, ci = 0.0, 0.0
        elif token.startswith("clamp="):
            try:
                cd, ci = (float(x) for x in token[len("clamp=") :].split("/"))
            except ValueError:
                raise ValueError(f"--settings {spec!r}: {token!r} is not clamp=DIRECT/INDIRECT (numbers)") from None
        else:
            raise ValueError(
                f"--settings {spec!r}: unknown part {token!r} (oidn, oidn=none|fast|accurate, noclamp, clamp=D/I)"
            )
    return Sampling(spec, int(m["spp"]), denoise, cd, ci, prefilter)


def renders_per_object(render) -> int:
    """Images one curation job renders: (6 + extra) input views x input lights + target views x target lights."""
    return (render.input_views + render.extra_input_views) * render.input_lights + (
        render.target_views * render.target_lights
    )


def default_objects(plan) -> list[str]:
    """The first test object of each material (``diffuse``, ``specular``, ``fur``, ``own``) of the plan."""
    seen: dict[str, str] = {}
    for spec in plan.objects:
        if spec.split == "test":
            seen.setdefault(spec.material, spec.id)
    return list(seen.values())


def render_images(
    plan,
    objaverse,
    render,
    envmaps_width: int,
    env_dir: Path,
    objects: list[str],
    lights: list[str] | None,
    n_views: int,
    n_lights: int | None,
    reference_spp: int,
    settings: list[Sampling],
    out: Path,
    save_images: bool,
    log,
) -> list[dict]:
    """Inside Blender: every (object, light, view) under the two references and each setting; ``plan``: the dataset
    plan (:func:`frng.plan.catalog.plan`), ``render`` its render section (resolution and threads as wanted),
    ``lights``: maps of ``env_dir`` (None: each object's target lights), ``n_views``: the rig's first target views.
    ``n_lights``: with ``lights`` None, only each object's first ``n_lights`` target lights (None: all). With
    ``save_images`` every render is written as ``out/images/{obj}/{light}/{view}/{setting}.exr``. Returns one
    record per image: keys object, material, light, view, setting, spp, denoise, clamp_direct, clamp_indirect,
    seconds, rgba ((H, W, 4) float32); the references' settings are ``reference`` (seed + 1) and ``reference-half``
    (seed + 2), the settings' seed the object's own."""
    from frng import io
    from frng.blender import scene as bscene
    from frng.blender import world
    from frng.data import rig
    from frng.data.curate import object_scene

    folder = EnvmapFolder(Path(env_dir))
    reference = Sampling(REFERENCE, reference_spp, False, 0.0, 0.0, PREFILTERS[0])
    plans = [reference, dataclasses.replace(reference, name=HALF)] + list(settings)
    seed_offset = {REFERENCE: 1, HALF: 2}
    raw = Path(out) / ".render" / "raw.exr"
    raw.parent.mkdir(parents=True, exist_ok=True)
    records = []
    for oid in objects:
        spec = plan.object(oid)
        rig_rng = np.random.default_rng(np.random.SeedSequence(spec.seed).spawn(3)[0])
        _, targets = rig.object_views(rig_rng, render)
        views = targets[:n_views]
        scene, cam, *_ = object_scene(plan, objaverse, render, spec, log)
        for light in lights or spec.target_lights[:n_lights]:
            path = Path(folder.envmap(light))
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such env map (--lights / --envmaps)")
            world.set_envmap(scene, path, sample_map_resolution=max(64, envmaps_width))
            for s in plans:
                bscene.set_sampling(scene, s.spp, s.denoise, s.clamp_direct, s.clamp_indirect, s.prefilter)
                scene.cycles.seed = (spec.seed + seed_offset.get(s.name, 0)) % (2**31 - 1)
                for i, view in enumerate(views):
                    bscene.set_camera_pose(cam, view.c2w)
                    # a setting's first render rebuilds Blender's render session: with use_persistent_data the
                    # sampling pattern of the session's first render (its sample count) stays for the later ones,
                    # so a 32-spp image after a 512-spp one would not be the one curation renders
                    scene.render.use_persistent_data = i > 0
                    dt = bscene.render_to(scene, raw)
                    rgba = bscene.read_passes(raw)["rgba"].copy()
                    if save_images:
                        io.write_exr(
                            Path(out) / "images" / oid / light / view.name / f"{s.name}.exr", rgba, list("RGBA")
                        )
                    records.append(
                        dict(object=oid, material=spec.material, light=light, view=view.name, setting=s.name)
                        | dict(spp=s.spp, denoise=s.denoise, prefilter=s.prefilter, clamp_direct=s.clamp_direct)
                        | dict(clamp_indirect=s.clamp_indirect, seconds=round(dt, 4), rgba=rgba)
                    )
                log(
                    f"[{oid}] {light} {s.name}: {len(views)} views, "
                    f"{np.mean([r['seconds'] for r in records[-len(views) :]]):.3f} s/view"
                )
    raw.unlink(missing_ok=True)
    raw.parent.rmdir()
    return records


def score(records: list[dict], protocol: str, background=None) -> list[dict]:
    """The rows of ``renders.csv``: each setting's record scored against the mean of the two reference renders of
    its (object, light, view), ``reference-half`` against ``reference``, with every per-image metric of
    :func:`frng.metrics.evaluate_pair` (the ``reference`` rows carry seconds only); ``background``: the metrics'
    (None: :data:`frng.metrics.DEFAULT_BACKGROUND`)."""
    from frng.metrics import DEFAULT_BACKGROUND, evaluate_pair

    key = lambda r: (r["object"], r["light"], r["view"])  # noqa: E731
    first = {key(r): r["rgba"] for r in records if r["setting"] == REFERENCE}
    second = {key(r): r["rgba"] for r in records if r["setting"] == HALF}
    rows = []
    for r in records:
        row = {k: v for k, v in r.items() if k != "rgba"}
        if r["setting"] != REFERENCE:
            ref = first[key(r)] if r["setting"] == HALF else 0.5 * (first[key(r)] + second[key(r)])
            m = evaluate_pair(r["rgba"], ref, protocol=protocol, background=background or DEFAULT_BACKGROUND)
            row |= m
        rows.append(row)
    return rows


LADDER_METHODS = {TIER: "targets-vs-high-spp", HALF: "high-spp-reference-half"}
"""The ``method`` of the noise floor's rows in the quality ladder's input (:func:`ladder_rows`): the tier's targets
against the reference (the ladder's step 0), and one reference render against the other (step 0r)."""


def ladder_rows(rows: list[dict]) -> list[dict]:
    """:func:`score`'s rows of the ``tier`` and ``reference-half`` settings in the layout of the priors' evaluation
    (``metrics/backbone.csv``: task, object, light, view, method, metrics), the rows the quality ladder reads
    (:data:`frng.report.ladder.LADDER_STEPS`, steps 0 and 0r): task ``relight`` (the held-out relighting images'
    objects, lights and views), method :data:`LADDER_METHODS`."""
    out = []
    for r in rows:
        if r["setting"] in LADDER_METHODS:
            out.append({"task": "relight", "method": LADDER_METHODS[r["setting"]]} | r)
    return out


def summary(rows: list[dict], render, n_per_object: int | None) -> str:
    """Markdown tables of ``rows`` (:func:`score`): per setting, per material x setting and per light x setting."""
    import pandas as pd

    df = pd.DataFrame(rows)
    order = list(dict.fromkeys(df["setting"]))
    scored = df[df["setting"] != REFERENCE]
    g = scored.groupby("setting", sort=False)
    table = pd.DataFrame(
        {
            "n": g.size(),
            "PSNR": g["psnr"].mean().round(2),
            "min PSNR": g["psnr"].min().round(2),
            "SSIM": g["ssim"].mean().round(4),
            "LPIPS": g["lpips"].mean().round(4),
            "s/view": df.groupby("setting", sort=False)["seconds"].mean().round(3),
        }
    ).reindex(order)
    if n_per_object:
        table["s/object"] = (table["s/view"] * n_per_object).round(1)
    spp = df[df["setting"] == REFERENCE]["spp"].iloc[0]
    parts = [
        f"Reference: the mean of two renders of {spp} spp (raw, no clamps, other seeds); {HALF}: one against the "
        "other; "
        f"{render.resolution} px, {render.threads} Cycles thread(s); "
        + (f"s/object: s/view x {n_per_object} renders per object. " if n_per_object else "")
        + "PSNR in dB.",
        "",
        table.reset_index().to_markdown(index=False),
    ]
    for by in ("material", "light"):
        pivot = scored.pivot_table(index="setting", columns=by, values="psnr", aggfunc="mean", sort=False)
        pivot = pivot.reindex([s for s in order if s != REFERENCE]).round(2)
        parts += ["", f"PSNR by {by}:", "", pivot.reset_index().to_markdown(index=False)]
    return "\n".join(parts) + "\n"
