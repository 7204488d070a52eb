"""frng.training.distributed: 2 gloo processes on CPU take the same optimizer step as one process over the global batch."""

from __future__ import annotations

import socket

import pytest
import torch
import torch.multiprocessing as mp

from frng.training import distributed

GLOBAL_BATCH = 8


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _model() -> torch.nn.Module:
    torch.manual_seed(1234)
    return torch.nn.Sequential(torch.nn.Linear(5, 16), torch.nn.GELU(), torch.nn.Linear(16, 3))


def _data() -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(99)
    return torch.randn(GLOBAL_BATCH, 5, generator=g), torch.randn(GLOBAL_BATCH, 3, generator=g)


def _step(model: torch.nn.Module, x: torch.Tensor, y: torch.Tensor) -> float:
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    opt.zero_grad()
    loss = torch.nn.functional.mse_loss(model(x), y)  # mean over the (local) batch
    loss.backward()
    opt.step()
    return loss.item()


def gloo_init(rank: int, world: int, port: int):
    """One rank of a CPU (gloo) process group on this machine, one thread: ``distributed.init``'s info."""
    torch.set_num_threads(1)
    env = {
        "RANK": str(rank),
        "WORLD_SIZE": str(world),
        "LOCAL_RANK": str(rank),
        "MASTER_ADDR": "127.0.0.1",
        "MASTER_PORT": str(port),
    }
    info = distributed.init(device="cpu", environ=env, timeout_s=60)
    return info


def _worker(rank: int, world: int, port: int, out: str) -> None:
    info = gloo_init(rank, world, port)
    try:
        assert info.backend == "gloo" and info.world_size == world and info.rank == rank
        model = distributed.wrap(_model(), info)
        x, y = _data()
        loss = _step(model, distributed.shard(x, info), distributed.shard(y, info))
        logs = distributed.all_reduce_scalars({"loss": loss, "rank": float(rank)}, info)
        distributed.save0(info, {"state": distributed.unwrap(model).state_dict(), "logs": logs}, out)
    finally:
        distributed.cleanup()


def test_two_gloo_ranks_match_single_process(tmp_path):
    out = tmp_path / "ddp.pt"
    mp.spawn(_worker, args=(2, _free_port(), str(out)), nprocs=2, join=True)
    got = torch.load(out)

    single = _model()
    x, y = _data()
    full_loss = _step(single, x, y)
    for name, p in single.state_dict().items():
        torch.testing.assert_close(got["state"][name], p, rtol=1e-5, atol=1e-6, msg=name)
    # the parameters moved (a no-op step would pass trivially)
    assert not torch.allclose(got["state"]["0.weight"], _model().state_dict()["0.weight"])
    # mean of the per-rank means of equal shards = the global mean
    assert got["logs"]["loss"] == pytest.approx(full_loss, rel=1e-5)
    assert got["logs"]["rank"] == pytest.approx(0.5)


def test_env_ranks_and_master():
    assert distributed.env_ranks({}) == (0, 1, 0)
    assert distributed.env_ranks({"RANK": "3", "WORLD_SIZE": "8", "LOCAL_RANK": "1"}) == (3, 8, 1)
    slurm = {
        "SLURM_PROCID": "5",
        "SLURM_NTASKS": "8",
        "SLURM_LOCALID": "1",
        "SLURM_JOB_ID": "4242",
        "SLURM_JOB_NODELIST": "gpu[07-08],cpu1",
    }
    assert distributed.env_ranks(slurm) == (5, 8, 1)
    # torchrun's variables win over SLURM's (torchrun inside an sbatch job)
    assert distributed.env_ranks({**slurm, "RANK": "0", "WORLD_SIZE": "2"}) == (0, 2, 0)
    addr, port = distributed.master_addr_port(slurm)
    assert addr in ("gpu07", "gpu[07-08]") or addr.startswith("gpu")
    assert port == 20000 + 4242
    assert distributed.master_addr_port({"MASTER_ADDR": "h", "MASTER_PORT": "1234"}) == ("h", 1234)
    assert distributed.master_addr_port({}) == ("127.0.0.1", distributed.DEFAULT_PORT)


def test_single_process_is_a_no_op(tmp_path):
    info = distributed.init(device="cpu", environ={})
    assert not info.distributed and info.is_main and info.backend is None
    m = _model()
    assert distributed.wrap(m, info) is m
    x, _ = _data()
    assert distributed.shard(x, info) is not None and distributed.shard(x, info).shape == x.shape
    assert distributed.all_reduce_scalars({"a": 2}, info) == {"a": 2.0}
    distributed.save0(info, {"k": 1}, tmp_path / "c.pt")
    assert torch.load(tmp_path / "c.pt") == {"k": 1}
    two = [distributed.DistInfo(rank=r, world_size=2) for r in range(2)]
    assert [list(distributed.shard_range(6, i)) for i in two] == [[0, 1, 2], [3, 4, 5]]
    assert [distributed.shard_items(list("abcde"), i) for i in two] == [list("ace"), list("bd")]
    with pytest.raises(ValueError):
        distributed.local_batch_size(5, two[0])
    assert distributed.rank_seed(0, two[0]) != distributed.rank_seed(0, two[1])
    assert distributed.rank_seed(0, two[0], per_rank=False) == distributed.rank_seed(0, two[1], per_rank=False)
    assert "--nproc-per-node=8" in distributed.torchrun_command(8, python="py")
