"""The examples of each step, drawn from (seed, step) alone, and the processes that assemble them.

The examples of step s are positions ``s*B .. s*B+B-1`` of a sequence of per-epoch permutations
seeded by (seed, epoch), and a loss's randomness comes from a generator seeded by (seed, step,
rank): a resumed run continues exactly, and DDP processes each take their slice of the same batch.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

import numpy as np
import torch

from convodrive.plumbing.errors import UserError
from convodrive.training import distributed
from convodrive.training.config import TrainConfig, augmentation
from convodrive.training.recipe import Batch, Examples


class StepBatches(torch.utils.data.Dataset):
    """The batch of each step, a pure function of the step (module doc), so that worker processes
    can assemble batches ahead and the run stays the same with any number of them."""

    def __init__(self, windows: Examples, config: TrainConfig, rank: int, local_batch: int) -> None:
        self.windows, self.config, self.rank, self.local_batch = windows, config, rank, local_batch
        self.augment = augmentation(config)

    def __len__(self) -> int:
        return self.config.steps

    def __getitem__(self, step: int) -> Batch:
        indices = batch_indices(self.config.seed, step, len(self.windows), self.config.batch_size)
        mine = indices[self.rank * self.local_batch : (self.rank + 1) * self.local_batch]
        return self.windows.step_batch(mine, step, self.config.seed, self.augment)


def step_batches(
    windows: Examples, config: TrainConfig, rank: int, local_batch: int, steps: range, workers: int
) -> Iterable[Batch]:
    """This process's batches of ``steps``, in order, assembled by ``workers`` processes (0: here)."""
    dataset = StepBatches(windows, config, rank, local_batch)
    if workers == 0:
        return (dataset[s] for s in steps)
    return torch.utils.data.DataLoader(
        dataset,
        batch_size=None,
        sampler=steps,
        num_workers=workers,
        prefetch_factor=4,
        multiprocessing_context="fork",
        generator=torch.Generator(),  # its workers' seeds; drawn from torch's global one, they would move dropout's
    )


def default_workers(procs: distributed.Processes) -> int:
    """See ``TrainRequest.workers``."""
    if procs.device.type != "cuda":
        return 0
    return max(0, min(6, (os.cpu_count() or 1) // procs.world_size - 1))


def batch_indices(seed: int, step: int, count: int, batch_size: int) -> np.ndarray:
    """The example indices of step ``step``: positions of per-epoch permutations (see module doc)."""
    positions = step * batch_size + np.arange(batch_size, dtype=np.int64)
    epochs, offsets = np.divmod(positions, count)
    out = np.empty(batch_size, np.int64)
    for epoch in np.unique(epochs):
        perm = np.random.default_rng([seed, int(epoch)]).permutation(count)
        sel = epochs == epoch
        out[sel] = perm[offsets[sel]]
    return out


def step_seed(seed: int, step: int, rank: int) -> int:
    return int(np.random.SeedSequence([seed, step, rank]).generate_state(1)[0])


def check_batch_fits(windows: Examples, local_batch: int, batch_size: int) -> None:
    """Refuse, before the first step, a batch whose examples alone take more than half the memory
    free now: it would page for minutes with no output, then fail."""
    one = sum(t.element_size() * t.numel() for t in windows.batch(np.zeros(1, np.int64)).values())
    free = available_memory()
    if free is not None and one * local_batch > free // 2:
        raise UserError(
            f"--batch-size {batch_size}: one batch holds {one * local_batch / 2**30:.1f} GiB of examples, "
            f"more than half the memory free ({free / 2**30:.1f} GiB); choose a smaller batch"
        )


def available_memory() -> int | None:
    """Bytes of memory free for a new allocation (Linux's MemAvailable), None where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None
