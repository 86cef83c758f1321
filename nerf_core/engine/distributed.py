"""Data-parallel plumbing for ``torchrun``: the process group, who this rank is, and the collectives.

``torchrun --nproc_per_node N -m nerf_core train DATASET --out RUN`` starts N copies of the
trainer with ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR`` and ``MASTER_PORT`` set.
``init_from_env`` turns those into a ``Context``; without them (or with ``WORLD_SIZE=1``) the
context is inactive: no process group is made and every helper here returns at once, so a
single-process run does exactly what it did before this module existed.

Why gradients are averaged by hand (``average_gradients``) rather than by ``DistributedDataParallel``:

* DDP registers each parameter once, when it wraps the model. ``vmgrid`` grows during training
  by *replacing* its plane parameters (``training_hook`` returns True and the trainer rebuilds
  its optimiser); DDP would have to be torn down and rebuilt at every growth.
* The methods render through ``render_rays``, not ``forward``, and which parameters a step
  touches varies (vmgrid's colour network sees no sample on a batch where every ray is already
  opaque; its L1 prior starts once geometry forms). DDP would need ``find_unused_parameters``
  and a graph walk every step; here a parameter without a gradient on some rank simply
  contributes zeros there, and one without a gradient on *every* rank keeps ``grad = None``,
  exactly as in a single process (Adam then leaves it alone).
* The occupancy grid is a buffer updated outside any forward pass (``training_hook``); DDP's
  buffer broadcast happens in ``forward`` and would not cover it.
* One flat all-reduce a step also carries the few scalars the ranks must agree on (loss, elapsed
  time, stop request, ...; see ``nerf_core.engine.replicas``): one collective, where DDP plus the extra
  agreement would need several.

So each step every rank packs its gradients, a has-gradient flag per parameter and the extra
scalars into one float32 tensor, one ``all_reduce(SUM)`` adds them up, and the gradients are
divided by the world size: the gradient of the mean loss over all ranks' rays.

Backends: gloo for CPU tensors, NCCL for CUDA tensors (``cpu:gloo,cuda:nccl``), one GPU per local
rank. A collective whose peer has gone (crashed, killed) raises ``PeerLost``, a ``KeyboardInterrupt``,
so that the trainer stops the way it stops on Ctrl-C: rank 0 saves a checkpoint to resume from.
"""
from __future__ import annotations

import hashlib
import os
import re
import sys
from dataclasses import dataclass
from datetime import timedelta
from typing import List, Mapping, Optional, Sequence

import torch

ENV_VARS = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")
# Rank 0 renders previews and evaluates while the other ranks wait in the next collective; a long
# held-out evaluation must not trip the backends' default timeouts (gloo 30 min, NCCL 10 min).
TIMEOUT = timedelta(minutes=120)
CHECKSUM_ENV = "NERF_CORE_DDP_CHECKSUM"  # set to 1: each rank prints a checksum of its model at the end


class PeerLost(KeyboardInterrupt):
    """Another rank left the job (it crashed or was killed): this rank stops as if interrupted."""


@dataclass
class Context:
    """This process's place in the job. Inactive (rank 0 of 1, no process group) without torchrun."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    active: bool = False

    @property
    def is_main(self) -> bool:
        """True on the one rank that writes the run folder (rank 0; the only rank without torchrun)."""
        return self.rank == 0

    def place(self, device: torch.device) -> torch.device:
        """The device this rank trains on: ``device`` itself, or ``cuda:LOCAL_RANK`` for a CUDA device
        under torchrun (one GPU per rank). Raises ValueError for a CUDA device named by index."""
        if not self.active or device.type != "cuda":
            return device
        if device.index is not None:
            raise ValueError(f"--device {device}: under torchrun each rank trains on cuda:LOCAL_RANK; "
                             "pass --device cuda (or leave --device out)")
        if self.local_rank >= torch.cuda.device_count():
            raise ValueError(f"local rank {self.local_rank} has no GPU: only {torch.cuda.device_count()} "
                             "CUDA device(s) on this machine; lower --nproc_per_node, or train on the CPU "
                             "with --device cpu")
        torch.cuda.set_device(self.local_rank)
        return torch.device("cuda", self.local_rank)

    def agree(self, ok: bool) -> bool:
        """True when every rank passes ``ok=True`` (a collective: every rank must call it)."""
        if not self.active:
            return ok
        flag = torch.tensor([1 if ok else 0], dtype=torch.int32)
        all_reduce(flag, torch.distributed.ReduceOp.MIN)
        return bool(flag.item())

    def close(self) -> None:
        """Leave the job: wait (briefly) for the other ranks, then destroy the process group.

        Rank 0 evaluates and writes the run while the others are done; a rank that tore its gloo
        group down while a peer still held the connection sometimes aborted at exit ("terminate
        called without an active exception", SIGABRT), failing a run that had trained. A barrier lets
        the ranks tear down together; a peer that is gone (an error, a kill) ends it at once.
        """
        if self.active and torch.distributed.is_initialized():
            try:
                torch.distributed.barrier()
            except Exception:  # noqa: BLE001 - a lost peer: nothing left to wait for
                pass
            torch.distributed.destroy_process_group()


def init_from_env(environ: Optional[Mapping[str, str]] = None) -> Context:
    """The ``Context`` torchrun's environment describes, with the process group initialised; an
    inactive context when any of ``ENV_VARS`` is missing or ``WORLD_SIZE`` is 1.
    Raises ValueError naming the variables when one is not a number, or when joining fails."""
    env = os.environ if environ is None else environ
    if not all(env.get(k) for k in ENV_VARS):
        return Context()
    try:
        rank, world, local = (int(env[k]) for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK"))
    except ValueError:
        raise ValueError("RANK, WORLD_SIZE and LOCAL_RANK must be integers (set by torchrun): "
                         + ", ".join(f"{k}={env[k]!r}" for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK"))) from None
    if world <= 1:
        return Context()
    if not torch.distributed.is_available():
        raise ValueError("WORLD_SIZE > 1 but this torch build has no torch.distributed")
    backend = "cpu:gloo,cuda:nccl" if torch.cuda.is_available() else "gloo"
    try:
        torch.distributed.init_process_group(backend=backend, init_method="env://", timeout=TIMEOUT)
    except RuntimeError as exc:  # e.g. MASTER_ADDR unreachable, port taken
        raise ValueError(f"torchrun: rank {rank} cannot join the process group at {env['MASTER_ADDR']}:"
                         f"{env['MASTER_PORT']} ({str(exc).splitlines()[0]})") from None
    return Context(rank=rank, world_size=world, local_rank=local, active=True)


def all_reduce(tensor: torch.Tensor, op=None) -> torch.Tensor:
    """In-place ``all_reduce`` (SUM unless ``op``); a vanished peer raises ``PeerLost``."""
    try:
        torch.distributed.all_reduce(tensor, op=torch.distributed.ReduceOp.SUM if op is None else op)
    except RuntimeError as exc:  # gloo: "Connection closed by peer"; NCCL: a remote error or timeout
        raise PeerLost(_peer_lost(exc)) from None
    return tensor


def broadcast_module(module: torch.nn.Module, src: int = 0) -> None:
    """Make every parameter and buffer equal to rank ``src``'s (shapes must already match)."""
    try:
        for t in list(module.parameters()) + list(module.buffers()):
            torch.distributed.broadcast(t.data, src=src)
    except RuntimeError as exc:
        raise PeerLost(_peer_lost(exc)) from None


def _peer_lost(exc: BaseException) -> str:
    """'another rank left the job (Connection closed by peer [127.0.0.1]:46506)' from a backend error."""
    first = re.sub(r"^\[[^\]]*\]\s*", "", str(exc).strip().splitlines()[0] if str(exc).strip() else "")
    return f"another rank left the job ({first.split('. ')[0][:160] or type(exc).__name__})"


def max_over_ranks(value: float) -> float:
    """The largest of every rank's ``value`` (a collective)."""
    t = torch.tensor([float(value)], dtype=torch.float64)
    all_reduce(t, torch.distributed.ReduceOp.MAX)
    return float(t.item())


def average_gradients(params: Sequence[torch.Tensor], world_size: int, extra: Sequence[float]) -> List[float]:
    """Average ``p.grad`` of ``params`` (the same list, in the same order, on every rank) over the
    ranks, and sum ``extra`` (n,) scalars, in one all-reduce; returns the summed extras.

    A parameter without a gradient on this rank contributes zeros; one without a gradient on every
    rank keeps ``grad = None``. ``extra`` travels as float32 (exact for integers below 2**24).
    """
    device = params[0].device if params else torch.device("cpu")
    pieces = [p.grad.reshape(-1).float() if p.grad is not None else torch.zeros(p.numel(), device=device)
              for p in params]
    pieces.append(torch.tensor([float(p.grad is not None) for p in params], device=device))
    pieces.append(torch.tensor([float(v) for v in extra], device=device))
    flat = all_reduce(torch.cat(pieces))
    n_grad = sum(p.numel() for p in params)
    flat[:n_grad].div_(world_size)
    has = flat[n_grad:n_grad + len(params)].tolist()
    offset = 0
    for p, count in zip(params, has):
        n = p.numel()
        if count > 0:
            avg = flat[offset:offset + n].view_as(p)
            if p.grad is None:
                p.grad = avg.to(p.dtype).clone()
            else:
                p.grad.copy_(avg)
        offset += n
    return flat[n_grad + len(params):].double().tolist()


def stream_seed(seed: int, *parts) -> int:
    """A 63-bit seed for the random stream named by ``seed`` and ``parts`` (e.g. ``"batches", rank,
    step``): distinct names give unrelated streams, the same name always the same one."""
    digest = hashlib.blake2b(repr((int(seed),) + tuple(parts)).encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") >> 1


def state_checksum(module: torch.nn.Module) -> str:
    """sha256 over the module's ``state_dict`` (sorted keys; each key, then the tensor's raw bytes
    on the CPU): equal on two ranks exactly when their parameters and buffers are bitwise equal."""
    h = hashlib.sha256()
    state = module.state_dict()
    for key in sorted(state):
        h.update(key.encode() + b"\0")
        h.update(state[key].detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def report_checksum(module: Optional[torch.nn.Module], ctx: Context, step: int) -> None:
    """With ``NERF_CORE_DDP_CHECKSUM=1``: print ``ddp-checksum rank=R step=S sha256=...`` to stderr
    (a debugging aid and what the tests compare across ranks); nothing otherwise or without a module."""
    if module is not None and os.environ.get(CHECKSUM_ENV, "") not in ("", "0"):
        print(f"ddp-checksum rank={ctx.rank} step={step} sha256={state_checksum(module)}", file=sys.stderr, flush=True)


def note_resume(ckpt: dict, ctx: Context) -> None:
    """Tell the user (rank 0, on stderr) when a run continues on another number of ranks than it
    was trained with: the rays per step change with it (the learning rate does not)."""
    was = int((ckpt.get("config") or {}).get("world_size") or 1)
    if ctx.is_main and was != ctx.world_size:
        print(f"train: the run was trained on {was} rank(s) and continues on {ctx.world_size}: each step now "
              f"averages {ctx.world_size} batches instead of {was}", file=sys.stderr)
