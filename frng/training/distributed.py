"""torch.distributed helpers for the training stages (backbone, IDM, F-RNG).

One code path for every launcher::

    info = distributed.init()                 # torchrun, srun, or a plain single process
    distributed.seed_everything(cfg["seed"], info)
    model = distributed.wrap(model.to(info.device), info)
    for batch in loader:
        local = distributed.shard(batch, info)  # this rank's slice of the global batch
        loss = model(local).mean(); loss.backward(); opt.step()
        logs = distributed.all_reduce_scalars({"loss": loss.item()}, info)
        distributed.print0(info, logs)
    distributed.save0(info, distributed.unwrap(model).state_dict(), path)
    distributed.cleanup()

Launch modes (rank, world size and local rank are read in this order):

- ``torchrun --standalone --nproc-per-node=N -m frng train ...``: ``RANK``/``WORLD_SIZE``/``LOCAL_RANK`` plus
  ``MASTER_ADDR``/``MASTER_PORT`` are set by torchrun.
- ``srun --ntasks=N python -m frng train ...`` (one task per GPU, also across nodes): ``SLURM_PROCID``/
  ``SLURM_NTASKS``/``SLURM_LOCALID``; the master is the first host of ``SLURM_JOB_NODELIST`` (or ``MASTER_ADDR``),
  the port ``MASTER_PORT`` or one derived from ``SLURM_JOB_ID`` (so two jobs on one node do not collide).
- nothing set: a single process, no process group; every helper degrades to the obvious no-op.

Backend: NCCL when the device is CUDA, gloo on CPU. Gradients are averaged by DistributedDataParallel, so a
step on equal shards of a global batch equals the single-process step over the whole batch when the loss is a
mean over the batch (``tests/test_distributed.py`` checks this with 2 gloo processes).
"""

from __future__ import annotations

import datetime
import os
import random
import re
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist

from frng.device import deterministic_kernels, training_threads
from frng.plan.variants import torchrun_command  # noqa: F401  (torch-free, used by the rule files)

DEFAULT_PORT = 29500


@dataclass(frozen=True)
class DistInfo:
    """Where this process sits in the job."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    backend: str | None = None  # None: no process group (single process)
    device: torch.device = torch.device("cpu")

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def env_ranks(environ: Mapping[str, str] | None = None) -> tuple[int, int, int]:
    """(rank, world_size, local_rank) from torchrun's variables, else SLURM's, else (0, 1, 0)."""
    env = os.environ if environ is None else environ
    if "RANK" in env and "WORLD_SIZE" in env:
        rank, world = int(env["RANK"]), int(env["WORLD_SIZE"])
        local = int(env.get("LOCAL_RANK", rank))
        return rank, world, local
    if "SLURM_PROCID" in env and "SLURM_NTASKS" in env:
        return int(env["SLURM_PROCID"]), int(env["SLURM_NTASKS"]), int(env.get("SLURM_LOCALID", 0))
    return 0, 1, 0


def _first_host(nodelist: str) -> str:
    """First host of a SLURM node list (``scontrol show hostnames`` when present, else a parse of ``a[1-3],b``)."""
    try:
        out = subprocess.run(
            ["scontrol", "show", "hostnames", nodelist], capture_output=True, text=True, timeout=10, check=True
        ).stdout.split()
        if out:
            return out[0]
    except (OSError, subprocess.SubprocessError):
        pass
    first = re.split(r",(?![^\[]*\])", nodelist)[0]
    m = re.match(r"^(.*)\[([^\]]+)\](.*)$", first)
    if m:
        lo = re.split(r"[-,]", m.group(2))[0]
        return f"{m.group(1)}{lo}{m.group(3)}"
    return first


def master_addr_port(environ: Mapping[str, str] | None = None) -> tuple[str, int]:
    """The rendezvous address: MASTER_ADDR/PORT if set, else derived from the SLURM job, else localhost."""
    env = os.environ if environ is None else environ
    addr = env.get("MASTER_ADDR")
    if not addr:
        nodelist = env.get("SLURM_JOB_NODELIST") or env.get("SLURM_NODELIST")
        addr = _first_host(nodelist) if nodelist else "127.0.0.1"
    port = env.get("MASTER_PORT")
    if port:
        return addr, int(port)
    job = env.get("SLURM_JOB_ID")
    return addr, (20000 + int(job) % 20000) if job and job.isdigit() else DEFAULT_PORT


def pick_device(device: str | torch.device | None, local_rank: int) -> torch.device:
    """``auto``/None: cuda:<local_rank> when CUDA is present, else CPU."""
    if device is None or str(device) == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(device)
    if device.type == "cuda" and device.index is None:
        device = torch.device("cuda", local_rank % max(torch.cuda.device_count(), 1))
    return device


def init(
    device: str | torch.device | None = "auto",
    backend: str | None = None,
    timeout_s: float = 600,
    environ: Mapping[str, str] | None = None,
) -> DistInfo:
    """Join the process group the launcher set up (a no-op for a single process).

    ``backend`` defaults to NCCL on CUDA and gloo on CPU. Returns this process's :class:`DistInfo`.
    """
    env = os.environ if environ is None else environ
    rank, world, local = env_ranks(env)
    dev = pick_device(device, local)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if world <= 1:
        return DistInfo(0, 1, 0, None, dev)
    backend = backend or ("nccl" if dev.type == "cuda" else "gloo")
    if dist.is_initialized():
        return DistInfo(dist.get_rank(), dist.get_world_size(), local, dist.get_backend(), dev)
    addr, port = master_addr_port(env)
    dist.init_process_group(
        backend=backend,
        init_method=f"tcp://{addr}:{port}",
        rank=rank,
        world_size=world,
        timeout=datetime.timedelta(seconds=timeout_s),
        **({"device_id": dev} if dev.type == "cuda" else {}),
    )
    return DistInfo(rank, world, local, backend, dev)


def cleanup() -> None:
    """Leave the process group (safe to call when none exists)."""
    if dist.is_available() and dist.is_initialized():
        try:
            dist.barrier()
        finally:
            dist.destroy_process_group()


def barrier(info: DistInfo) -> None:
    if info.distributed and dist.is_initialized():
        dist.barrier()


def wrap(model: torch.nn.Module, info: DistInfo, **ddp_kwargs: Any) -> torch.nn.Module:
    """DistributedDataParallel around ``model`` (already on ``info.device``); the model itself when single-process."""
    if not info.distributed:
        return model
    from torch.nn.parallel import DistributedDataParallel as DDP

    if info.device.type == "cuda":
        ddp_kwargs.setdefault("device_ids", [info.device.index])
        ddp_kwargs.setdefault("output_device", info.device.index)
    return DDP(model, **ddp_kwargs)


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    """The module inside a DDP wrapper (what checkpoints store)."""
    return getattr(model, "module", model)


def rank_seed(seed: int, info: DistInfo, per_rank: bool = True) -> int:
    """The seed one rank uses: distinct per rank (data order, noise) unless ``per_rank`` is False."""
    return (int(seed) * 1_000_003 + (info.rank if per_rank else 0)) % (2**31 - 1)


def seed_everything(seed: int, info: DistInfo, per_rank: bool = True) -> int:
    """Seed python, numpy and torch for this rank, fix the thread count and, on a CPU, switch torch's deterministic
    kernels on (:func:`frng.device.deterministic_kernels`). Model init must use ``per_rank=False`` (or be broadcast:
    DDP broadcasts rank 0's parameters when it wraps the model). Returns the seed used."""
    s = rank_seed(seed, info, per_rank)
    training_threads()
    deterministic_kernels(info.device)
    random.seed(s)
    try:
        import numpy as np

        np.random.seed(s)
    except ImportError:  # pragma: no cover
        pass
    torch.manual_seed(s)
    return s


def local_batch_size(global_batch: int, info: DistInfo) -> int:
    """Per-rank batch size; the global batch must split evenly (DDP averages gradients with equal weights)."""
    if global_batch % info.world_size:
        raise ValueError(f"global batch {global_batch} does not split evenly over {info.world_size} ranks")
    return global_batch // info.world_size


def shard_range(n: int, info: DistInfo) -> range:
    """Indices [start, stop) of this rank's contiguous slice of ``n`` items (``n`` divisible by world size)."""
    b = local_batch_size(n, info)
    return range(info.rank * b, (info.rank + 1) * b)


def shard(batch: Any, info: DistInfo) -> Any:
    """This rank's slice (dim 0) of a global batch: a tensor, or a dict/list/tuple of tensors."""
    if isinstance(batch, torch.Tensor):
        r = shard_range(batch.shape[0], info)
        return batch[r.start : r.stop]
    if isinstance(batch, Mapping):
        return {k: shard(v, info) for k, v in batch.items()}
    if isinstance(batch, (list, tuple)):
        return type(batch)(shard(v, info) for v in batch)
    return batch


def shard_items(items: list, info: DistInfo) -> list:
    """Round-robin split of a list (objects, files) over ranks; uneven lengths are fine here."""
    return items[info.rank :: info.world_size]


def all_reduce_scalars(values: Mapping[str, float], info: DistInfo, op: str = "mean") -> dict[str, float]:
    """Mean (or sum/max/min) of scalar logs over ranks; every rank gets the result."""
    keys = sorted(values)
    if not info.distributed or not keys:
        return {k: float(values[k]) for k in keys}
    t = torch.tensor([float(values[k]) for k in keys], dtype=torch.float64)
    if info.backend == "nccl":
        t = t.to(info.device)
    red = {"mean": dist.ReduceOp.SUM, "sum": dist.ReduceOp.SUM, "max": dist.ReduceOp.MAX, "min": dist.ReduceOp.MIN}
    dist.all_reduce(t, op=red[op])
    if op == "mean":
        t /= info.world_size
    return {k: float(v) for k, v in zip(keys, t.cpu().tolist())}


def print0(info: DistInfo, *args: Any, **kwargs: Any) -> None:
    """print on rank 0 only."""
    if info.is_main:
        print(*args, **kwargs, flush=True)


def save0(info: DistInfo, obj: Any, path: str | Path) -> None:
    """torch.save on rank 0 (atomically: temp file + rename), then every rank waits for it."""
    if info.is_main:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".tmp-{path.name}")
        torch.save(obj, tmp)
        tmp.replace(path)
    barrier(info)


def all_gather(obj: Any, info: DistInfo) -> list:
    """Every rank's picklable ``obj``, in rank order (a collective); ``[obj]`` for a single process."""
    if not info.distributed:
        return [obj]
    out: list = [None] * info.world_size
    dist.all_gather_object(out, obj)
    return out


def fit_hooks(info: DistInfo):
    """The data-parallel hooks of :func:`frng.training.loop.fit` for this process: logs averaged over ranks, random
    states and data digests gathered from every rank, files written by rank 0."""
    from frng.training.loop import FitHooks

    return FitHooks(
        rank=info.rank,
        world_size=info.world_size,
        reduce_logs=lambda logs: all_reduce_scalars(logs, info),
        gather=lambda obj: all_gather(obj, info),
        barrier=lambda: barrier(info),
    )
