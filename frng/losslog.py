"""A training run's loss log: ``{out}/loss.csv`` (one row per step: step, elapsed_s, then named loss terms) and
``{out}/loss.png`` (curves, log-scale y, a moving average on top of the raw values)."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from frng import io
from frng.plan.layout import TrainingFolder


class LossLog:
    """Loss CSV (one row per step, header written up front) and a PNG plot of all terms.

    ``rows`` is the history a resumed run continues (the checkpoint carries it, so the CSV covers every step even
    when the file itself was deleted, as Snakemake does with the outputs of a killed job); the CSV is rewritten
    from it at once."""

    def __init__(self, out: str | os.PathLike, names: list[str], rows: list[dict] | None = None):
        files = TrainingFolder(out)
        self.csv = Path(files.curve("csv"))
        self.png = Path(files.curve("png"))
        self.names = list(names)
        self.rows: list[dict] = [dict(r) for r in rows or []]
        self._rewrite()

    @property
    def fields(self) -> list[str]:
        return ["step", "elapsed_s"] + self.names

    def _rewrite(self) -> None:
        with io.atomic_path(self.csv) as tmp, open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=self.fields)
            w.writeheader()
            for r in self.rows:
                w.writerow({k: r.get(k, "") for k in self.fields})

    def append(self, step: int, elapsed: float, values: dict[str, float]) -> None:
        row = {"step": step, "elapsed_s": f"{elapsed:.3f}"}
        row.update({k: f"{float(v):.6g}" for k, v in values.items()})
        self.rows.append(row)
        with open(self.csv, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=self.fields).writerow({k: row.get(k, "") for k in self.fields})

    def plot(self, title: str) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
        steps = np.array([int(r["step"]) for r in self.rows])
        for name in self.names:
            vals = np.array([float(r[name]) if r.get(name) not in (None, "") else np.nan for r in self.rows])
            if not np.isfinite(vals).any():
                continue
            line = ax.plot(steps, vals, alpha=0.25, lw=0.8)[0]
            k = max(1, len(vals) // 50)
            smooth = np.convolve(np.nan_to_num(vals), np.ones(k) / k, mode="valid")
            ax.plot(steps[k - 1 :], smooth, color=line.get_color(), label=name)
        ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_title(title)
        ax.legend(fontsize=7)
        fig.tight_layout()
        with io.atomic_path(self.png) as tmp:
            fig.savefig(tmp)
        plt.close(fig)
