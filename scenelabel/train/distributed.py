"""Data-parallel training across processes and machines with ``torch.distributed``.

``torchrun --nproc-per-node N -m scenelabel build SCENE`` starts N processes; each finds its rank
in the environment torchrun sets (``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``,
``MASTER_PORT``) and :func:`init_from_env` joins the process group: backend ``gloo`` on the CPU,
``nccl`` on CUDA. The trainer (:mod:`scenelabel.train.trainer`) wraps the training render in
:class:`torch.nn.parallel.DistributedDataParallel`, so gradients are all-reduced (averaged)
every step; rank 0 alone writes checkpoints, metrics, renders and maps.

Without those variables (a plain ``scenelabel build``) nothing here does anything: a single
process is world size 1.
"""

from __future__ import annotations

import gc
import os
from dataclasses import dataclass

import numpy as np
import torch
import torch.distributed as dist

__all__ = ["DistContext", "init_from_env", "leave", "backend_for", "all_reduce_mean", "broadcast_array", "broadcast_module_buffers"]


@dataclass(frozen=True)
class DistContext:
    """Where this process stands in a data-parallel run (``world_size`` 1: not distributed)."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    owns_group: bool = False  # init_from_env joined the group (and :func:`leave` ends it)

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the one process that writes files."""
        return self.rank == 0


def backend_for(device: torch.device) -> str:
    """``nccl`` for CUDA tensors, ``gloo`` for CPU ones."""
    return "nccl" if device.type == "cuda" else "gloo"


def init_from_env(device: torch.device) -> tuple[DistContext, torch.device]:
    """Join the process group torchrun describes in the environment, if any.

    Args:
        device: the device asked for (``cuda``: each process takes GPU ``LOCAL_RANK``).
    Returns:
        (context, device): world size 1 and ``device`` unchanged when ``WORLD_SIZE`` is unset or
        1; otherwise the joined group's rank and size, and this process's device.
    """
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return DistContext(), device
    rank = int(os.environ["RANK"])
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    if device.type == "cuda":
        device = torch.device("cuda", local_rank)
        torch.cuda.set_device(device)
    owns_group = not dist.is_initialized()
    if owns_group:
        dist.init_process_group(backend_for(device))
    return DistContext(rank, world_size, local_rank, owns_group), device


def leave(context: DistContext) -> None:
    """End the process group :func:`init_from_env` joined (a group the caller made is left alone).

    Drop every DistributedDataParallel wrapper first (:meth:`scenelabel.train.trainer.Trainer.drop_data_parallel`):
    a wrapper holds the group, and a gloo group that outlives this call is freed at interpreter exit, where
    its threads can abort the process ("terminate called without an active exception", SIGABRT) after all
    the work is done. The collection here frees wrappers caught in reference cycles while the interpreter runs.
    """
    if context.owns_group and dist.is_initialized():
        gc.collect()
        dist.destroy_process_group()


def all_reduce_mean(values: torch.Tensor) -> torch.Tensor:
    """The mean of ``values`` over all ranks (the same on every rank); ``values`` itself when not distributed."""
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return values
    values = values.clone()
    dist.all_reduce(values, op=dist.ReduceOp.SUM)
    return values / dist.get_world_size()


def broadcast_array(values: np.ndarray, device: torch.device = torch.device("cpu"), src: int = 0) -> np.ndarray:
    """Rank ``src``'s float64 ``values`` on every rank (``values`` itself when not distributed);
    ``device``: where the collective runs (a CUDA device for nccl)."""
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return values
    tensor = torch.as_tensor(np.asarray(values, np.float64), device=device).clone()
    dist.broadcast(tensor, src)
    return tensor.cpu().numpy()


def broadcast_module_buffers(module: torch.nn.Module, src: int = 0) -> None:
    """Copy rank ``src``'s buffers (e.g. an density grid's) to every rank, in place."""
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return
    for buffer in module.buffers():
        if buffer.dtype == torch.bool:  # gloo does not reduce bools: go through bytes
            as_bytes = buffer.data.to(torch.uint8)
            dist.broadcast(as_bytes, src)
            buffer.data.copy_(as_bytes.bool())
        else:
            dist.broadcast(buffer.data, src)
