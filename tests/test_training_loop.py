"""The one training loop (frng.training.loop.fit) behind frng backbone-train / idm-train / train: honest resume.

- a run killed with SIGKILL (and its loss.csv deleted, as Snakemake does with a failed job's outputs) and rerun
  ends bit-identical to an uninterrupted run, weights and loss.csv (every step 1..N, but the wall-clock column);
- a checkpoint of another training config is not resumed (the rerun equals a fresh run of the new config), one
  whose only change is ``checkpoint_every`` is;
- a finished checkpoint whose model was deleted (``snakemake -f``) or kept (a manual rerun) trains again;
- a step whose gradient norm is not finite makes no update; two gloo ranks resume bit-exactly (per-rank random
  states); the IDM trainer's cue cache gives bit-identical cues whatever order it met the lights in.

The trainer here is the learned IDM on the analytic sphere of tests/test_idm_generalise.py (no curated data)."""

from __future__ import annotations

import csv
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import torch.multiprocessing as mp
from test_idm_generalise import TINY, sphere_object, train_idm, trainer_config

from frng import io
from frng.training import idm as idm_train
from frng.training import loop as tr
from frng.typedconfig import typed

HERE = Path(__file__).resolve().parent
STEPS = 10


def _config(**train):
    t = {"steps": STEPS, "lr": 3e-3, "warmup": 2, "bf16": False, "checkpoint_every": 3} | train
    return typed(trainer_config(t))


def _objects():
    obj = sphere_object()
    v = obj.inputs["l0"]  # a second input light: the cue cache's reuse path is exercised too
    obj.inputs["l1"] = type(v)(v.names, v.rgb * torch.tensor([0.6, 1.0, 1.4]), v.alpha, v.c2w, v.intr)
    return [obj]


def _weights(out: Path) -> dict:
    return torch.load(out / "model.pt", weights_only=False)["state_dict"]


def _rows(out: Path) -> list[dict]:
    with open(out / "loss.csv") as f:
        return list(csv.DictReader(f))


def _losses(out: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "elapsed_s"} for r in _rows(out)]


def _assert_same_weights(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    differ = [k for k in a if not torch.equal(a[k], b[k])]
    assert not differ, differ


_KILLED_RUN = """
import os, signal, sys
import torch
sys.path.insert(0, {here!r})
torch.set_num_threads({threads})
from frng import io
from frng.training import idm as idm_train
import test_training_loop as t

save = io.save_torch
def save_then_die(obj, path):
    save(obj, path)
    if isinstance(obj, dict) and obj.get("step") == {kill_at}:
        os.kill(os.getpid(), signal.SIGKILL)  # no cleanup, no finally: as a killed job
io.save_torch = save_then_die
t.train_idm(t._config(), t._objects(), __import__("pathlib").Path({out!r}))
"""


def test_killed_then_resumed_equals_uninterrupted(tmp_path):
    torch.manual_seed(0)
    train_idm(_config(), _objects(), tmp_path / "a")
    b = tmp_path / "b"
    code = _KILLED_RUN.format(here=str(HERE), threads=torch.get_num_threads(), kill_at=6, out=str(b))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert torch.load(b / "checkpoint.pt", weights_only=False)["step"] == 6 and not (b / "model.pt").exists()
    (b / "loss.csv").unlink()  # Snakemake deletes a failed job's outputs; the checkpoint carries the history
    train_idm(_config(), _objects(), b)
    _assert_same_weights(_weights(tmp_path / "a"), _weights(b))
    assert [int(r["step"]) for r in _rows(b)] == list(range(1, STEPS + 1))
    assert _losses(b) == _losses(tmp_path / "a")
    for out in (tmp_path / "a", b):
        assert (out / "loss.png").exists() and (out / "train.json").exists()


def test_changed_config_does_not_resume(tmp_path):
    out = tmp_path / "run"
    train_idm(_config(), _objects(), out, stop_after=4)
    assert torch.load(out / "checkpoint.pt", weights_only=False)["step"] == 4
    train_idm(_config(lr=1e-3), _objects(), out)  # another learning rate: trains from step 0
    train_idm(_config(lr=1e-3), _objects(), tmp_path / "fresh")
    _assert_same_weights(_weights(out), _weights(tmp_path / "fresh"))
    assert _losses(out) == _losses(tmp_path / "fresh")
    assert [int(r["step"]) for r in _rows(out)] == list(range(1, STEPS + 1))
    # the digest covers the steps and the training data as well
    fp = torch.load(out / "checkpoint.pt", weights_only=False)["fingerprint"]
    assert fp["train"]["lr"] == 1e-3 and fp["steps"] == STEPS and "data" in fp


def test_changed_checkpoint_every_still_resumes(tmp_path, monkeypatch):
    out = tmp_path / "run"
    train_idm(_config(), _objects(), out, stop_after=4)
    calls = []
    loss = idm_train.idm_mod.idm_loss
    monkeypatch.setattr(idm_train.idm_mod, "idm_loss", lambda *a, **k: calls.append(1) or loss(*a, **k))
    train_idm(_config(checkpoint_every=5), _objects(), out)
    assert len(calls) == STEPS - 4  # resumed at step 4
    train_idm(_config(), _objects(), tmp_path / "a")
    _assert_same_weights(_weights(out), _weights(tmp_path / "a"))


@pytest.mark.parametrize("keep_model", [False, True])
def test_finished_checkpoint_trains_again(tmp_path, monkeypatch, keep_model):
    """``snakemake -f .../model.pt`` deletes the model (and the other outputs) but not checkpoint.pt, whose step is
    the total: the rerun must train again (it used to resume the final checkpoint, re-save the old weights and
    write a header-only loss.csv). A manual rerun with the model still there trains again too."""
    out = tmp_path / "run"
    train_idm(_config(), _objects(), out)
    assert torch.load(out / "checkpoint.pt", weights_only=False)["step"] == STEPS
    first = _weights(out)
    if not keep_model:
        for name in ("model.pt", "loss.csv", "loss.png", "train.json"):
            (out / name).unlink()
    calls = []
    loss = idm_train.idm_mod.idm_loss
    monkeypatch.setattr(idm_train.idm_mod, "idm_loss", lambda *a, **k: calls.append(1) or loss(*a, **k))
    train_idm(_config(), _objects(), out)
    assert len(calls) == STEPS  # every step ran again
    assert [int(r["step"]) for r in _rows(out)] == list(range(1, STEPS + 1))
    _assert_same_weights(first, _weights(out))  # same config and seed: the same model, retrained
    assert (out / "train.json").exists() and (out / "loss.png").exists()


def _toy_fit(out: Path, total: int, stop_after=None, info=None, nan_at=None) -> Path:
    """A small MLP fitted by :func:`frng.training.loop.fit` on batches drawn from its own ``random.Random``, with
    dropout (the global torch generator, seeded per rank): what a resume must restore. ``info``: this rank of a
    process group (DDP through :func:`frng.training.distributed.fit_hooks`). ``nan_at``: that step's loss is NaN."""
    import random

    from frng.training import distributed

    rank = info.rank if info else 0
    torch.manual_seed(7)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Dropout(0.3), torch.nn.Linear(8, 1))
    net = distributed.wrap(model, info) if info else model
    torch.manual_seed(100 + rank)
    rng = random.Random(rank)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-2)

    def step_fn(step):
        x = torch.tensor([[rng.uniform(-1, 1) for _ in range(4)] for _ in range(3)])
        loss = (net(x) - x.sum(1, keepdim=True)).pow(2).mean()
        if step == nan_at:
            loss = loss * float("nan")
        loss.backward()
        return {"total": float(loss.detach())}

    tcfg = SimpleNamespace(lr=1e-2, warmup=2, grad_clip=1.0, checkpoint_every=100)
    trainer = tr.Trainer(
        model=model,
        optimizer=opt,
        step=step_fn,
        save_model=lambda p: io.save_torch({"state_dict": model.state_dict()}, p),
        summary=lambda run: {"steps": run.steps, "skipped": run.skipped},
        loss_names=["total"],
        title="toy",
        desc="toy",
        rngs={"sample": rng},
        device="cpu",
        hooks=distributed.fit_hooks(info) if info else tr.FitHooks(),
    )
    return tr.fit(trainer, tcfg, out=out, total=total, fingerprint={"toy": 1}, stop_after=stop_after)


def test_nonfinite_step_makes_no_update(tmp_path, monkeypatch):
    steps = []
    orig = torch.optim.AdamW.step
    monkeypatch.setattr(torch.optim.AdamW, "step", lambda self, *a, **k: steps.append(1) or orig(self, *a, **k))
    _toy_fit(tmp_path / "nan", 4, nan_at=2)
    assert len(steps) == 3  # 4 steps, one skipped
    assert all(torch.isfinite(v).all() for v in _weights(tmp_path / "nan").values())
    assert [r["total"] for r in _rows(tmp_path / "nan")][2] == "nan"  # the step is still logged
    assert io.read_json(tmp_path / "nan" / "train.json")["skipped"] == 1


def _ddp_worker(rank: int, world: int, port: int, out: str, stop_after) -> None:
    from test_distributed import gloo_init

    from frng.training import distributed

    info = gloo_init(rank, world, port)
    try:
        _toy_fit(Path(out), 8, stop_after=stop_after, info=info)
    finally:
        distributed.cleanup()


def test_two_gloo_ranks_resume_bit_exactly(tmp_path):
    from test_distributed import _free_port

    mp.spawn(_ddp_worker, args=(2, _free_port(), str(tmp_path / "a"), None), nprocs=2, join=True)
    mp.spawn(_ddp_worker, args=(2, _free_port(), str(tmp_path / "b"), 3), nprocs=2, join=True)
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["step"] == 3
    mp.spawn(_ddp_worker, args=(2, _free_port(), str(tmp_path / "b"), None), nprocs=2, join=True)
    _assert_same_weights(_weights(tmp_path / "a"), _weights(tmp_path / "b"))
    assert _losses(tmp_path / "a") == _losses(tmp_path / "b")
    assert len(_rows(tmp_path / "b")) == 8


def test_cue_cache_is_bit_identical_whatever_the_light_order():
    """The IDM trainer's cue cache is data: a resumed run (empty cache) must see exactly the cues an uninterrupted
    one (a cache that met the object's lights in another order) sees."""
    from frng.priors.idm import IDMConfig, LearnedIDM

    obj = _objects()[0]
    model = LearnedIDM(IDMConfig.from_dict(TINY))
    idx = list(range(len(obj.inputs["l0"])))
    warm = idm_train.CueCache()
    warm.get(model, obj, "l0", idx, obj.inputs["l0"])
    for light in ("l1", "l0"):
        got = warm.get(model, obj, light, idx, obj.inputs[light])
        cold = idm_train.CueCache().get(model, obj, light, idx, obj.inputs[light])
        for k in cold:
            assert torch.equal(got[k], cold[k]), (light, k)
