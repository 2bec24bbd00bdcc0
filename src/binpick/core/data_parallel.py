"""Data-parallel training over a ``torch.distributed`` process group: the collective steps binpick's
trainers share (Ray Train starts the group: ``binpick train CONFIG --address ... --workers N``).

Every trainer keeps its single-process loop and asks its :class:`Group` at the few places where the
processes must agree: all start from rank 0's weights (:meth:`Group.share`), each computes its part of
every global batch (:meth:`Group.part`, or a ``DistributedSampler`` shard), gradients are averaged after
the backward pass (:meth:`Group.average_gradients`) so a step sees the config's batch size and its
learning-rate schedule is the single process's, and rank 0 alone evaluates and writes while the others
follow its decisions (:meth:`Group.agree`). A process outside any group is :data:`ALONE`, for which
every one of these is a no-op.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import torch

from binpick.core.errors import ConfigError


@dataclass(frozen=True)
class Group:
    """This process's place among ``world`` training processes."""

    rank: int = 0
    world: int = 1

    @classmethod
    def joined(cls) -> Group:
        """The process group this process belongs to (one Ray Train worker's)."""
        import torch.distributed as dist

        if not dist.is_available() or not dist.is_initialized():
            raise ConfigError("data-parallel training needs a torch.distributed process group "
                              "(binpick train --address starts one)")
        return cls(dist.get_rank(), dist.get_world_size())

    @property
    def lead(self) -> bool:
        """Rank 0: the process that evaluates, logs and writes the run folder."""
        return self.rank == 0

    def split(self, batch_size: int, field: str = "batch_size") -> int:
        """Each process's share of a global batch; a batch that does not split evenly is one line."""
        if batch_size % self.world:
            raise ConfigError(f"{field} {batch_size} does not split over {self.world} workers: give a multiple of the worker count")
        return batch_size // self.world

    def part(self, items: torch.Tensor) -> torch.Tensor:
        """This process's slice of a global batch (indices, flips, ...), the same slice every step."""
        return items if self.world == 1 else items[self.rank::self.world]

    def share(self, tensors: Iterable[torch.Tensor]) -> None:
        """Rank 0's values in every process (weights and buffers before the first step)."""
        if self.world == 1:
            return
        import torch.distributed as dist

        for tensor in tensors:
            dist.broadcast(tensor.data, 0)

    def agree(self, flag: bool) -> bool:
        """Rank 0's ``flag`` on every process: all stop, or go on, together."""
        if self.world == 1:
            return flag
        import torch.distributed as dist

        value = torch.tensor([float(flag)])
        dist.broadcast(value, 0)
        return bool(value.item())

    def average_gradients(self, parameters: Iterable[torch.nn.Parameter]) -> None:
        """Every process's gradients averaged in one all-reduce over a flat buffer: with equal parts of
        a batch and a mean loss, the gradient of the whole batch."""
        if self.world == 1:
            return
        import torch.distributed as dist

        params = [p for p in parameters if p.requires_grad]
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        flat = torch.cat([g.reshape(-1) for g in grads])
        dist.all_reduce(flat)
        flat /= self.world
        offset = 0
        for p, g in zip(params, grads):
            p.grad = flat[offset:offset + g.numel()].view_as(g).clone()
            offset += g.numel()

    def wait(self) -> None:
        """Every process here before any goes on (rank 0 has written what the others read)."""
        if self.world > 1:
            import torch.distributed as dist

            dist.barrier()


ALONE = Group()
