"""The ``frng`` command line: the commands a user runs (:data:`USER_COMMANDS`), then one subcommand per pipeline stage
(:data:`PIPELINE_STAGES`); ``frng --help`` lists them in two groups, in that order.

Each pipeline stage lives in its own module, ``frng/stages/<rule>.py`` named after the Snakemake rule that runs it
(:mod:`frng.stages`); a command no rule runs lives in :mod:`frng.commands` (``frng config`` is
:mod:`frng.commands.config`), the benchmarks behind ``frng bench`` in :mod:`frng.diagnostics`. Each module provides
two functions::

    def configure(parser: argparse.ArgumentParser) -> None   # add arguments (or sub-subcommands)
    def run(args: argparse.Namespace) -> int | None           # do the work

Modules are imported lazily so that ``frng --help`` stays fast (no torch/bpy import).
Snakemake rules call these subcommands; users can call them directly too (``tests/test_stages.py`` checks the
rule -> subcommand -> stage module map).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys

# What a user runs, name -> (module, one-line help): the commands of frng.commands (no rule runs them), `frng import`
# (also the rule import_benchmark's stage) and `frng bench` (frng.diagnostics). Listed first by `frng --help`.
USER_COMMANDS: dict[str, tuple[str, str]] = {
    "reconstruct": ("frng.commands.reconstruct", "your own photos (2-10 views) -> a relightable asset folder"),
    "render-asset": ("frng.commands.render_asset", "render an asset folder under any env map (views, turntable)"),
    "view": ("frng.commands.view", "interactive relighting viewer of an asset in the browser (127.0.0.1, viser)"),
    "export-asset": (
        "frng.commands.export_asset",
        "bake an asset under one env map into plain 3D Gaussian splatting (PLY, SPZ, glTF KHR_gaussian_splatting)",
    ),
    "import": (
        "frng.stages.import_benchmark",
        "a public benchmark scene (tensoir, orb, owl, nerf-synthetic) into the dataset contract",
    ),
    "export": ("frng.commands.export_benchmark", "a curated object in a public benchmark's published layout"),
    "export-image-inputs": (
        "frng.commands.export_image_inputs",
        "the inputs of image-based relighting methods (photo under the input light, mask, camera, target maps)",
    ),
    "bench": (
        "frng.diagnostics.bench",
        "benchmarks and diagnostics (frng.diagnostics): timings, held-out quality, noise floor",
    ),
    "results-page": (
        "frng.commands.results_page",
        "docs/results.md, the README's results block: from a results folder",
    ),
    "config": ("frng.commands.config", "validate a config file and print it with defaults filled in"),
}
# The pipeline's stages, each run by a Snakemake rule (frng.stages, one module per rule), in pipeline order.
PIPELINE_STAGES: dict[str, tuple[str, str]] = {
    "envmaps": ("frng.stages.envmaps", "collect, bake and rotate the environment maps (train/test split)"),
    "curate": ("frng.stages.curate", "render one object's views x lights + G-buffers with Blender Cycles"),
    "dataset-preview": (
        "frng.stages.dataset_preview",
        "PNG contact sheet per curated object (views x lights + G-buffers)",
    ),
    "noise-floor": (
        "frng.stages.noise_floor",
        "the curated targets' noise floor against high-spp renders of the same views (the quality ladder's step 0)",
    ),
    "curate-baselines": (
        "frng.stages.curate_baselines",
        "render one test object's target views under its input light (+ dense views) for the baselines",
    ),
    "backbone-train": ("frng.stages.backbone_train", "train the RelitLRM-style backbone (training split), then freeze"),
    "idm-train": ("frng.stages.idm_train", "train the learned IDM on the training split's G-buffers"),
    "backbone-cache": ("frng.stages.backbone_cache", "cache one object's backbone tokens + Gaussians"),
    "idm-priors": ("frng.stages.idm_priors", "write one object's IDM priors for its input views"),
    "eval-backbone": ("frng.stages.eval_backbone", "backbone NVS/relighting and IDM accuracy vs trivial baselines"),
    "train": ("frng.stages.train", "train one F-RNG variant from the cached priors (training split)"),
    "relight": ("frng.stages.relight", "relight one test object with every F-RNG run and the backbone; timings"),
    "relight-seed": (
        "frng.stages.relight_seed",
        "relight one test object's runs of another training seed (as relight)",
    ),
    "evaluate": ("frng.stages.evaluate", "per-image PSNR/SSIM/LPIPS of every relit image (configured protocol)"),
    "baseline-fit": (
        "frng.stages.baseline_fit",
        "fit one per-scene baseline (3dgs / gsir) on an object's dense views; its novel views and relit images",
    ),
    "baseline-image": (
        "frng.stages.baseline_image",
        "image-based baseline: each target view's photo decomposed by the IDM and re-shaded under the target lights",
    ),
    "baseline-frng-nvs": (
        "frng.stages.baseline_frng_nvs",
        "F-RNG's full model rendered under the input light at the target views (the views table's novel views)",
    ),
    "baseline-eval": (
        "frng.stages.baseline_eval",
        "per-image scores of the baselines, other methods' files and F-RNG (relighting and novel views)",
    ),
    "baseline-tables": (
        "frng.stages.baseline_tables",
        "the baselines' tables (vs_dense, vs_image_based, views_nvs) and their comparison figures",
    ),
    "tables": ("frng.stages.tables", "the paper's tables (vs backbone, ablation, #views, K, timing)"),
    "figures": ("frng.stages.figures", "comparison grids, ablation grid, saliency maps, loss curves"),
    "relight-benchmark": ("frng.stages.relight_benchmark", "relight one imported benchmark object (as relight)"),
    "evaluate-benchmarks": (
        "frng.stages.evaluate_benchmarks",
        "relit benchmark objects scored with each benchmark's published protocol; the benchmarks table",
    ),
}
# Every subcommand (tests/test_stages.py checks the rule -> subcommand -> module map).
STAGES: dict[str, tuple[str, str]] = {**USER_COMMANDS, **PIPELINE_STAGES}

# older spellings still accepted -> the stage they name (rules/curate.smk runs `frng dataset preview`)
ALIASES: dict[tuple[str, ...], str] = {("dataset", "preview"): "dataset-preview"}


def canonical(argv: list[str]) -> list[str]:
    """``argv`` with an older spelling of a stage (:data:`ALIASES`) replaced by the stage's name."""
    for old, name in ALIASES.items():
        if tuple(argv[: len(old)]) == old:
            return [name, *argv[len(old) :]]
    return argv


class _Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    pass


def _listing(table: dict[str, tuple[str, str]]) -> str:
    return "\n".join(f"  {name:<19} {help_}" for name, (_, help_) in table.items())


def _top_parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        prog="frng",
        formatter_class=_Formatter,
        description="F-RNG: relightable assets from a few photos, and the pipeline that reproduces the paper.\n\n"
        "commands (what you run):\n"
        + _listing(USER_COMMANDS)
        + "\n\npipeline stages (each run by a Snakemake rule of `make reproduce`, in pipeline order):\n"
        + _listing(PIPELINE_STAGES)
        + "\n\nRun `frng <command> --help` for a command's options.",
    )


def stage_parser(name: str) -> argparse.ArgumentParser:
    """Build the argument parser of one stage (imports its module)."""
    module_name, help_ = STAGES[name]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"frng {name}", description=help_, formatter_class=_Formatter)
    module.configure(parser)
    parser.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> None:
    global DEBUG
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--debug" in argv:  # global: `frng --debug STAGE ...` or anywhere among a stage's arguments
        DEBUG = True
        argv = [a for a in argv if a != "--debug"]
    argv = canonical(argv)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in STAGES:
        parser = _top_parser()
        parser.add_argument("command", choices=list(STAGES), metavar="COMMAND", help="a command or pipeline stage")
        if argv and argv[0] not in ("-h", "--help"):
            parser.error(f"unknown command {argv[0]!r}; choose from {', '.join(STAGES)}")
        parser.print_help()
        sys.exit(0 if argv else 2)
    parser = stage_parser(argv[0])
    args = parser.parse_args(argv[1:])
    run = args._run
    sys.exit(run_stage(argv[0], run, args))


# OS errors that mean "no permission" (read-only results folder, read-only file system): one line.
_UNWRITABLE = {errno.EACCES, errno.EPERM, errno.EROFS}

DEBUG = bool(os.environ.get("FRNG_DEBUG"))  # `frng --debug ...` (or FRNG_DEBUG=1): tracebacks instead of one line
_HINT = " (run with --debug for the traceback)"


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


ID_ARGUMENTS = ("object", "export_object")  # options whose values are object ids that become paths
NAME_ARGUMENTS = ("scene",)  # options whose values become one path component


def check_path_arguments(args: argparse.Namespace) -> None:
    """Every option value that becomes part of a path is a plain id before any stage reads or writes with it:
    ``--object`` / ``--export-object`` (one or several) an object id (:func:`frng.confine.check_id`), ``--scene`` a
    plain name (:func:`frng.confine.plain_name`); else an :class:`frng.confine.UntrustedInputError` (one line)."""
    from frng import confine

    for attr in ID_ARGUMENTS + NAME_ARGUMENTS:
        value = getattr(args, attr, None)
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if not isinstance(v, str):
                continue
            flag = "--" + attr.replace("_", "-")
            if attr in ID_ARGUMENTS:
                confine.check_id(v, flag)
            else:
                confine.plain_name(v, source=flag, field=None)


def run_stage(name: str, run, args: argparse.Namespace) -> int:
    """Run one stage; a bad config file, a permission error (read-only results folder), a corrupt intermediate file,
    a bad image, a bad file from outside (frng.confine), a model file that does not fit its architecture or a full
    disk ends in one line on stderr naming the file (exit 2), not a traceback; so does any other ValueError or
    KeyError a loader raises (its first line, with a hint). Under ``--debug`` every error propagates with its
    traceback. Other errors propagate."""
    from frng.confine import UntrustedInputError
    from frng.io import CorruptFileError, ImageError
    from frng.plan.config import ConfigError

    try:
        check_path_arguments(args)
    except UntrustedInputError as e:
        if DEBUG:
            raise
        print(f"frng {name}: error: {e}", file=sys.stderr)
        return 2
    try:
        return int(run(args) or 0)
    except (ConfigError, CorruptFileError, ImageError) as e:  # each names its file and the cause
        if DEBUG:
            raise
        print(f"frng {name}: error: {e}", file=sys.stderr)
        return 2
    except RuntimeError as e:  # torch's load_state_dict: a model file of another architecture
        if DEBUG or not str(e).startswith("Error(s) in loading state_dict"):
            raise
        from frng.io import last_loaded

        detail = next((ln.strip() for ln in str(e).splitlines()[1:] if ln.strip()), _first_line(e))
        path, what = last_loaded() or ("a model file", "model file")
        print(f"frng {name}: error: {path}: {what} does not fit its architecture ({detail[:300]})", file=sys.stderr)
        return 2
    except MemoryError as e:
        if DEBUG:
            raise
        print(f"frng {name}: error: out of memory ({_first_line(e)[:300]}){_HINT}", file=sys.stderr)
        return 2
    except (ValueError, KeyError) as e:  # a loader's own error (names its file), or a field it did not expect
        if DEBUG:
            raise
        what = f"missing key {e}" if isinstance(e, KeyError) else _first_line(e)
        print(f"frng {name}: error: {what[:500]}{_HINT}", file=sys.stderr)
        return 2
    except OSError as e:
        if DEBUG:
            raise
        if isinstance(e, FileNotFoundError) and e.errno is None:  # raised with a message naming the file
            print(f"frng {name}: error: {_first_line(e)}", file=sys.stderr)
            return 2
        if e.errno == errno.ENOSPC and e.filename is None:  # frng.io.write_failure: the message names the file
            print(f"frng {name}: error: {e.strerror or e}", file=sys.stderr)
            return 2
        if e.errno not in _UNWRITABLE:
            raise
        where = f"{e.filename}: " if e.filename is not None else ""
        print(f"frng {name}: error: {where}{e.strerror} (is the results folder writable?)", file=sys.stderr)
        return 2
