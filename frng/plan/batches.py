"""Batches of objects for the short per-object prior rules (rules/priors.smk): one job caches a batch of objects in one
process, so that the torch import, the model load and Snakemake's per-job overhead are paid once per batch instead of
once per object, while every object still gets its own output file (the same bytes as one job per object).

Torch-free: the rule files plan with it and the tests count jobs with it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence

DEFAULT_BATCH_OBJECTS = 32
"""Objects per job of the batched rules unless ``--config priors_batch=N`` says otherwise."""

BATCHED_RULES = ("backbone_cache", "idm_priors")
"""The rule families cut into batches: each batch is its own rule ``{family}_{batch}`` (Snakemake cannot declare a
varying list of per-object outputs for one wildcard rule), e.g. ``backbone_cache_train0``."""

SWITCH = "priors_batch"
"""The ``--config`` switch setting the batch size (not part of the config: it changes how jobs are cut, no file)."""

_BATCH_RULE = re.compile(rf"^({'|'.join(BATCHED_RULES)})_[a-z]+\d+$")


def batches(ids: Sequence[str], size: int) -> list[list[str]]:
    """``ids`` in order, cut into ceil(n / size) consecutive batches whose sizes differ by at most one."""
    if size < 1:
        raise ValueError(f"batch size must be >= 1, got {size}")
    n = len(ids)
    k = math.ceil(n / size)
    bounds = [round(i * n / k) for i in range(k + 1)] if k else [0]
    return [list(ids[a:b]) for a, b in zip(bounds, bounds[1:])]


def object_batches(splits: Mapping[str, Sequence[str]], size: int) -> dict[str, list[str]]:
    """Batch name -> its objects, batching each split on its own (``train0``, ``train1``, ..., ``test0``): the
    training split's batches are all F-RNG training waits for."""
    return {f"{split}{k}": b for split, ids in splits.items() for k, b in enumerate(batches(ids, size))}


def batch_size(config: dict) -> int:
    """Pop the ``priors_batch`` switch from a Snakemake config (default :data:`DEFAULT_BATCH_OBJECTS`)."""
    value = config.pop(SWITCH, DEFAULT_BATCH_OBJECTS)
    try:
        size = int(value)
    except (TypeError, ValueError):
        size = 0
    if size < 1 or str(value).strip() != str(size):
        raise ValueError(f"{SWITCH}: objects per job of {', '.join(BATCHED_RULES)}: a positive integer, got {value!r}")
    return size


def rule_family(name: str) -> str:
    """The rule a generated batch rule belongs to (``backbone_cache_train0`` -> ``backbone_cache``); other names
    are returned as they are. Config digests, profile settings and job counts go by the family."""
    m = _BATCH_RULE.match(name)
    return m.group(1) if m else name


def add_batch_arguments(parser, what: str, kind: str, default: str) -> None:
    """``--object A B ...`` (required) and ``--out FA FB ...`` of a batch stage (:func:`object_outputs` reads them):
    ``what`` it does to an object, the ``kind`` of file it writes and the ``default`` path, for the help."""
    parser.add_argument("--object", nargs="+", required=True, metavar="OBJ", help=f"the object(s) to {what}")
    parser.add_argument("--out", nargs="+", help=f"{kind} file per object, in --object order (default {default})")


def object_outputs(objects: Sequence[str], outs: Sequence[str] | None, default) -> list[str]:
    """The output file of each object of a batch stage (``--object A B ... --out FA FB ...``): ``outs`` in the
    same order, or ``default(obj)`` for each when none are given."""
    if not outs:
        return [default(o) for o in objects]
    if len(outs) != len(objects):
        raise ValueError(f"--out names {len(outs)} files for {len(objects)} objects (one per object, in order)")
    if len(set(objects)) != len(objects):
        raise ValueError("--object names an object twice")
    return list(outs)
