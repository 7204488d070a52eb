"""Per-run memo of tensors that are a fixed function of the data, kept from their first use within a byte budget.

Training steps recompute per-object quantities that no weight or random draw enters (the backbone's multi-view cues
of the rig views, F-RNG's per-pixel maps): a kept entry is the tensor a recomputation would give (computed at the
same place, under the same autocast), so training with or without the memo is bit-identical (tested beside each
user). Entries past the budget are computed every time."""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence

import torch

DEFAULT_MAX_BYTES = 2 * 1024**3


class TensorMemo:
    """``get(key, compute)``: the kept tensors of ``key``, else ``compute()`` (a tensor or a sequence of tensors),
    kept while the kept bytes stay within ``max_bytes``. ``hits`` and ``bytes`` say how much it was used."""

    def __init__(self, max_bytes: int = DEFAULT_MAX_BYTES):
        self.max_bytes = max_bytes
        self.bytes = 0
        self.hits = 0
        self._entries: dict[Hashable, torch.Tensor | Sequence[torch.Tensor]] = {}

    def get(self, key: Hashable, compute: Callable[[], torch.Tensor | Sequence[torch.Tensor]]):
        kept = self._entries.get(key)
        if kept is not None:
            self.hits += 1
            return kept
        value = compute()
        tensors = [value] if isinstance(value, torch.Tensor) else list(value)
        size = sum(t.numel() * t.element_size() for t in tensors)
        if self.bytes + size <= self.max_bytes:
            self._entries[key] = value
            self.bytes += size
        return value
