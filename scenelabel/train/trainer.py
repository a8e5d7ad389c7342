"""The optimisation loop: rays of the training views -> a fitted FieldNetwork + density grid.

Orchestration only; the maths lives in rendering.py, sampling.py and losses.py.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

import torch
from torch import nn
from tqdm import tqdm

from scenelabel._cores import share_summary, update_share
from scenelabel.config import (
    AUTO,
    DEPTH_RANDOM_BACKGROUND,
    RANDOM_BACKGROUND,
    SENSOR_FREE_MARGIN,
    BuildConfig,
    resolve_by_depth,
)
from scenelabel.errors import ConfigError, TrainingError, TrainingInterrupted
from scenelabel.fields.model import FieldNetwork
from scenelabel.render.marcher import (
    CompositeOptions,
    Marching,
    RayBundleOutput,
    Skipping,
    render_rays,
    render_rays_hierarchical,
)
from scenelabel.render.sampling import DensityGrid, class_balanced_rays, rays_by_class
from scenelabel.train.distributed import DistContext, all_reduce_mean, broadcast_module_buffers
from scenelabel.train.divergence import Diverged, DivergenceGuard
from scenelabel.train.losses import (
    class_balance_weights,
    composite_target,
    depth_loss,
    free_space_loss,
    mean_colour_mse,
    photometric_mse,
    semantic_cross_entropy,
    semantic_focal_loss,
    solid_interior_loss,
    total_variation_grad,
)
from scenelabel.train.rays import RayData
from scenelabel.train.schedule import RunSchedule

__all__ = ["Trainer", "TrainState"]

TV_SLAB = 16
"""Vertex rows (first grid axis) of the random slab whose total variation is added each step
(``train.tv_weight``): a stochastic estimate of the whole grid's mean, at a fraction of the cost."""

SOLID_START = 0.25
"""The solid-interior term is on from this fraction of the run (:meth:`Trainer.progress`), and only
while the smoothed photometric error is at most SOLID_ERROR_FRACTION of the mean colour's: surfaces
first, so that the points it fills lie behind surfaces, not in early fog."""

SOLID_ERROR_FRACTION = 0.5
"""Surfaces have formed where the smoothed photometric error is at most this fraction of the mean colour's
(:class:`~scenelabel.train.divergence.DivergenceGuard`). On a slow machine, on at a quarter alone, the term
filled hall-10x6's fog until its builds rolled back (docs/suite_phone_depth_rooms.md)."""

GRID_ALL_CELLS_UPDATES = 4
"""The first this-many occupancy-grid refreshes visit every cell; later ones the occupied cells plus
a random quarter (each full refresh of a 64³ grid costs as much as several training steps)."""


def free_space_limit(target: torch.Tensor, step: float, margin: float) -> torch.Tensor:
    """[n_rays] distances before which a ray with measured depth ``target`` [n_rays] should be empty,
    ``target * (1 - margin) - step`` (``train.free_margin``: the measurement's relative error; ``step``:
    one marching step of quadrature); NaN where there is no measurement."""
    return target * (1.0 - margin) - step


def backgrounds_for_rays(
    background: torch.Tensor | None,  # [3] or [n_rays, 3]; None: black
    measured: torch.Tensor,  # [n_rays] bool: the ray carries a measured depth
    colours: torch.Tensor,  # [n_rays, 3] random colours in [0, 1]
) -> torch.Tensor:
    """[n_rays, 3] the colour behind each training ray: ``colours`` where the ray carries a measured
    depth, ``background`` elsewhere (``train.depth_background`` "random"). A measured ray ends at its
    surface, and a room has no backdrop behind it: with the white background a wall left half
    transparent in front of it can match its pixels, and the field can stay that way (a forward rig's
    walls, and rooms seen from inside: docs/models.md); a random colour never matches."""
    base = torch.zeros(3, dtype=colours.dtype, device=colours.device) if background is None else background
    return torch.where(measured[:, None], colours, base.expand_as(colours))


@contextmanager
def _interrupt_between_steps():
    """Inside: the first Ctrl-C (SIGINT) sets the yielded event, which the loop checks before each
    step, instead of raising KeyboardInterrupt wherever the main thread happens to be (inside a
    finaliser or a callback Python ignores it, and training went on); a second Ctrl-C interrupts at
    once. Off the main thread (signals cannot be handled there) the event is never set."""
    interrupted = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield interrupted
        return

    def on_sigint(signum, frame):
        if interrupted.is_set():
            raise KeyboardInterrupt
        interrupted.set()

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield interrupted
    finally:
        signal.signal(signal.SIGINT, previous)


@dataclass
class TrainState:
    step: int = 0
    elapsed: float = 0.0  # seconds of training so far (resumed runs add up)
    history: list[dict] = field(default_factory=list)  # logged {step, loss, psnr, ...}


class TrainingRender(nn.Module):
    """The training render behind one ``forward``, so that
    :class:`~torch.nn.parallel.DistributedDataParallel` can wrap it: the field and its occupancy
    grid (:func:`render_rays`), or, with a coarse field, NeRF's two networks
    (:func:`render_rays_hierarchical`, ``hierarchical = (n_coarse, n_fine)``)."""

    def __init__(
        self,
        model: FieldNetwork,
        grid: DensityGrid,
        marching: Marching,
        coarse: FieldNetwork | None = None,
        hierarchical: tuple[int, int] = (64, 128),
        min_trans: float = 0.0,
    ):
        super().__init__()
        self.model = model
        self.grid = grid
        self.marching = marching
        self.min_trans = min_trans  # Skipping's: a ray stops being evaluated below this transmittance
        self.coarse = coarse
        self.hierarchical = hierarchical

    def forward(
        self,
        origins: torch.Tensor,  # [n_rays, 3]
        directions: torch.Tensor,  # [n_rays, 3]
        t_min: torch.Tensor,  # [n_rays]
        t_max: torch.Tensor,  # [n_rays]
        jitter: torch.Tensor,  # [n_rays]
        fine_jitter: torch.Tensor | None = None,  # [n_rays, n_fine], with a coarse field
        options: CompositeOptions = CompositeOptions(),
        solid_offsets: torch.Tensor | None = None,  # [n_rays] distances past t_opaque, or None
        open_rays: torch.Tensor | None = None,  # [n_rays] bool: rays that ignore the grid, or None
    ) -> tuple[RayBundleOutput, RayBundleOutput | None, torch.Tensor | None]:
        """(the field's render, the coarse field's render or None, σ [k] at the solid-interior
        points ``t_opaque + solid_offsets`` of the rays that became opaque inside the box, or None)."""
        coarse_out = None
        if self.coarse is None:
            out = render_rays(
                self.model, self.grid, origins, directions, t_min, t_max, self.marching, jitter, options,
                Skipping(self.min_trans, open_rays),
            )
        else:
            out, coarse_out = render_rays_hierarchical(
                self.coarse, self.model, origins, directions, t_min, t_max, self.hierarchical, (jitter, fine_jitter), options
            )
        solid_sigmas = None
        if solid_offsets is not None:  # inside the DDP forward, so that its gradient is averaged too
            t = out.t_opaque + solid_offsets
            points = origins + torch.where(torch.isfinite(t), t, 0.0)[:, None] * directions
            aabb = self.model.aabb
            keep = torch.isfinite(t) & ((points >= aabb[0]) & (points <= aabb[1])).all(-1)
            solid_sigmas = self.model.density(points[keep])
        return out, coarse_out, solid_sigmas


class Trainer:
    """Fits a field to the rays of the training views.

    Data-parallel (``dist.world_size`` > 1, the process group joined, :mod:`scenelabel.train.distributed`):
    each rank draws ``ceil(batch_rays / world_size)`` rays per step from its own random stream,
    the render is wrapped in DistributedDataParallel (gradients averaged over ranks), the
    density grid is updated from the same cells on every rank and then copied from rank 0, and
    the logged losses, the loss checks and the elapsed time (which drives the learning-rate
    schedule and the time budget) are averaged over ranks, so every rank takes the same decisions.

    Args:
        model: the field (normalised frame).
        grid: its density grid.
        rays: training rays.
        config: the resolved build config.
        device: where to train.
        dist: this process's place in a data-parallel run (default: a single process).
        coarse: NeRF's coarse field (``sampling.strategy == "hierarchical"``): trained beside
            the field with the same losses, its weights choosing where the field is sampled.
    """

    def __init__(
        self,
        model: FieldNetwork,
        grid: DensityGrid,
        rays: RayData,
        config: BuildConfig,
        device: torch.device,
        dist: DistContext = DistContext(),
        coarse: FieldNetwork | None = None,
    ):
        self.model = model.to(device)
        self.coarse = None if coarse is None else coarse.to(device)
        self.grid = grid.to(device)
        self.config = config
        self.device = device
        self.dist = dist
        tc, sc = config.train, config.sampling
        self.rays = RayData(**{k: None if v is None else v.to(device) for k, v in rays.__dict__.items()})
        # Only rays that cross the box can be learnt from.
        self.ray_pool = torch.nonzero(self.rays.t_max > self.rays.t_min).squeeze(1)
        if len(self.ray_pool) == 0:
            raise TrainingError("no training ray enters the scene bounds: check the poses and bounds")
        self.marching = Marching.across_box(model.aabb, sc.n_steps)
        self.render = TrainingRender(
            self.model, self.grid, self.marching, self.coarse, (sc.n_coarse, sc.n_fine), sc.train_min_trans
        )
        self.batch_rays = -(-tc.batch_rays // dist.world_size)  # rays per rank and step
        if dist.distributed:
            self.render = nn.parallel.DistributedDataParallel(
                self.render,
                device_ids=[device] if device.type == "cuda" else None,
                forward_sync_buffers=False,  # the grid is synchronised after each of its updates instead
            )
        fused = device.type in ("cpu", "cuda")
        fields = [self.model] + ([] if self.coarse is None else [self.coarse])
        self.optimizer = torch.optim.Adam(
            [
                {"params": [p for f in fields for p in f.encoding_parameters()], "lr": tc.lr_encoding},
                {"params": [p for f in fields for p in f.mlp_parameters()], "lr": tc.lr_mlp},
            ],
            betas=(0.9, 0.99),
            eps=1e-15,  # Adam's eps: tiny, as for hash/grid encodings whose gradients are sparse
            fused=fused,
        )
        self.base_lrs = [tc.lr_encoding, tc.lr_mlp]
        self.class_weights = (
            class_balance_weights(self.rays.channels, model.num_classes) if tc.class_balance else None
        )
        self.background = None if tc.background in (None, RANDOM_BACKGROUND) else torch.tensor(tc.background, device=device)
        # the grid's random cells: the same stream on every rank; the rays: one stream per rank
        self.generator = torch.Generator(device="cpu").manual_seed(tc.seed)
        self.ray_generator = (
            torch.Generator(device="cpu").manual_seed(tc.seed + 1_000_003 * (dist.rank + 1))
            if dist.distributed
            else self.generator
        )
        if tc.tv_weight > 0 and config.field.encoding != "dense":
            raise ConfigError(f"train.tv_weight regularises a dense grid; field.encoding is {config.field.encoding!r}")
        # with sensor depth the surfaces sit where they were measured, so the interior behind them
        # is filled at least at train.depth_solid_weight (without depth: train.solid_weight alone)
        # the training rays carry sensor depth the depth terms train on
        self.with_depth = with_depth = self.rays.depth is not None and tc.depth_weight > 0
        self.solid_weight = max(tc.solid_weight, tc.depth_solid_weight) if with_depth else tc.solid_weight
        # "auto" is resolved by the build (choices.resolve_distortion); a trainer made without it: off
        self.distortion_weight = 0.0 if tc.distortion_weight == AUTO else float(tc.distortion_weight)
        # "auto" is resolved by the build (choices.resolve_free_margin); a trainer made without it: a sensor's
        self.free_margin = SENSOR_FREE_MARGIN if tc.free_margin == AUTO else float(tc.free_margin)
        self.config = resolve_by_depth(config, with_depth)  # grid_decay, steps, budget "auto": by the rays' depth
        self.rays_by_class = None  # sampling.grid_open_rays: the pool by label, where any ray has one
        if self.config.sampling.grid_open_rays > 0:  # "auto" resolved: by the build, else 0
            grouped = rays_by_class(self.rays.channels[self.ray_pool], self.ray_pool)
            self.rays_by_class = grouped if len(grouped[1]) > 0 else None
        self.state = TrainState()
        self.carve_released = False  # sampling.depth_carve_until: the carve's border handed back once
        alpha, random_bg = None if self.rays.alpha is None else self.rays.alpha[self.ray_pool], tc.background == RANDOM_BACKGROUND
        self.guard = DivergenceGuard(mean_colour_mse(self.rays.rgb[self.ray_pool], alpha, self.background, random_bg))
        self.schedule = RunSchedule()  # the run's fraction done: by steps, by the clock once the budget will end the run

    def _snapshot(self) -> dict:
        """What the divergence guard copies: :meth:`state_dict` (less the guard's record of rollbacks,
        which a rollback does not undo) and the schedules' (:meth:`RunSchedule.snapshot`)."""
        state = {k: v for k, v in self.state_dict().items() if k not in ("rollbacks", "budget_anchor")}
        return {**state, "schedule": self.schedule.snapshot(*self._run_position())}

    def _roll_back(self, diverged: Diverged) -> str:
        """Resume from the state the guard hands back, at a lower learning rate (the time
        spent stays spent); raises TrainingError when the guard gives up. Returns what happened."""
        step, state = self.guard.roll_back(diverged)
        elapsed = self.state.elapsed
        self.load_state_dict(state)
        # the schedules (learning rate, the terms that start or end at a fraction of the run) go back
        # with the state; the time thrown away counts against the budget
        self.state.elapsed = elapsed
        self.schedule.resume(state["schedule"], elapsed)
        factor = self.guard.rollbacks[-1]["lr_factor"]
        for group in self.optimizer.param_groups:  # saved with the optimizer: a resumed build keeps it
            group["lr_scale"] = factor
        return (
            f"training diverged at step {diverged.step} (photometric error {diverged.mse_ema:.4g}, the mean colour's "
            f"{self.guard.mean_colour_mse:.4g}): resumed from step {step} at {factor:g} times the learning rate"
        )

    def _semantic_loss(
        self, class_log_probs: torch.Tensor, channels: torch.Tensor, ray_weights: torch.Tensor | None = None
    ) -> torch.Tensor:
        tc = self.config.train
        if tc.semantic_loss == "focal":
            return semantic_focal_loss(class_log_probs, channels, tc.focal_gamma, self.class_weights, ray_weights)
        return semantic_cross_entropy(class_log_probs, channels, self.class_weights, ray_weights)

    def _add_grid_tv(self) -> float:
        """Adds train.tv_weight x the total variation of a random TV_SLAB-row slab of the field's
        dense grid to the grid's gradient (in place: no gradient of the whole grid is made for
        it); returns the weighted value."""
        grid = self.model.encoding.grid
        start = int(torch.randint(max(grid.shape[0] - TV_SLAB, 0) + 1, (1,), generator=self.generator))
        rows = slice(start, start + TV_SLAB + 1)
        value, grad = total_variation_grad(grid.detach()[rows])
        weight = self.config.train.tv_weight
        if grid.grad is None:
            grid.grad = torch.zeros_like(grid)
        grid.grad[rows] += weight * grad
        return weight * float(value)

    def progress(self) -> float:
        """Fraction of the run done: by steps until the time budget is going to end the run first
        (:mod:`scenelabel.train.schedule`)."""
        return self.schedule.fraction(*self._run_position())

    def _run_position(self) -> tuple[int, int, float, float | None]:
        """(step, steps, elapsed seconds, time budget): what the schedule reads."""
        return self.state.step, self.config.train.steps, self.state.elapsed, self.config.train.time_budget

    def _set_lr(self) -> None:
        factor = self.config.train.lr_final_ratio ** self.progress()
        for group, base in zip(self.optimizer.param_groups, self.base_lrs):
            group["lr"] = base * factor * group.get("lr_scale", 1.0)

    def _reopen_worst(self, out, target_rgb: torch.Tensor, idx: torch.Tensor, t_stop: torch.Tensor) -> None:
        """Re-open the grid cells along this step's worst rays (``sampling.grid_reopen`` of them), from
        each ray's start to its rendered depth (its far end where it met nothing):
        :meth:`~scenelabel.render.sampling.DensityGrid.reopen`. Worst by ``sampling.grid_reopen_by``:
        the largest colour error, or the largest cross-entropy among the rays whose rendered class
        is not their label's (fewer rays where fewer are wrong; none where none is)."""
        n_worst = max(1, round(self.config.sampling.grid_reopen * len(idx)))
        if self.config.sampling.grid_reopen_by == "labels":
            channels = self.rays.channels[idx]  # [n_rays]: -1 unlabelled
            log_probs = out.class_log_probs.detach()
            target = channels.clamp(min=0)[:, None]
            wrong = (channels >= 0) & (log_probs.argmax(-1) != target[:, 0])
            error = torch.where(wrong, -log_probs.gather(-1, target)[:, 0], torch.full_like(log_probs[:, 0], -1.0))
            n_worst = min(n_worst, int(wrong.sum()))
            if n_worst == 0:
                return
        else:
            error = ((out.rgb.detach() - target_rgb) ** 2).sum(-1)  # [n_rays]
        worst = error.topk(n_worst).indices
        r = self.rays
        t_min, t_stop = r.t_min[idx][worst], t_stop[worst]
        t_end = torch.minimum(torch.maximum(out.depth.detach()[worst], t_min), t_stop)
        self.grid.reopen(r.origins[idx][worst], r.directions[idx][worst], t_min, t_end)

    def train_step(self) -> dict:
        """One optimisation step on a random batch of rays; returns the logged scalars."""
        tc, sc = self.config.train, self.config.sampling
        step = self.state.step
        if step >= sc.grid_warmup and step % sc.grid_update_every == 0:
            n_updates = (step - sc.grid_warmup) // sc.grid_update_every
            release = self.progress() >= sc.depth_carve_until and not self.carve_released and bool(self.grid.carved.any())
            if release:  # from here the field decides at the carve's border: a cell it holds dense comes back
                self.grid.release_carve_border()
                self.carve_released = True
            all_cells = n_updates < GRID_ALL_CELLS_UPDATES or release
            self.grid.update(self.model.density, sc.grid_decay, all_cells=all_cells, generator=self.generator)
            broadcast_module_buffers(self.grid)  # identical already; rank 0's copy makes it certain
        self._set_lr()
        pick = torch.randint(len(self.ray_pool), (self.batch_rays,), generator=self.ray_generator)
        idx = self.ray_pool[pick.to(self.device)]
        open_rays = colour_weights = label_weights = None
        if self.rays_by_class is not None and self.coarse is None and self.progress() < sc.grid_open_until:
            extra, share_weights = class_balanced_rays(self.rays_by_class, sc.grid_open_rays, self.ray_generator)
            open_rays = torch.arange(len(idx) + len(extra), device=self.device) >= len(idx)
            # their colour counts at the pixels' shares: drawn class by class, they would otherwise pull
            # the colour towards the furniture's; their labels too with sampling.grid_open_labels "share"
            colour_weights = torch.cat([torch.ones(len(idx), device=self.device), share_weights])
            label_weights = colour_weights if sc.grid_open_labels == "share" else None
            idx = torch.cat([idx, extra])
        n_rays = len(idx)
        jitter = torch.rand(n_rays, generator=self.ray_generator).to(self.device)
        fine_jitter = None
        if self.coarse is not None:
            fine_jitter = torch.rand(n_rays, sc.n_fine, generator=self.ray_generator).to(self.device)
        solid_offsets = None
        solid_weight = self.solid_weight
        if solid_weight > 0 and self.progress() >= SOLID_START and self.guard.below(SOLID_ERROR_FRACTION):
            u = torch.rand(n_rays, generator=self.ray_generator).to(self.device)
            solid_offsets = u * tc.solid_depth_steps * self.marching.step
        r = self.rays
        background = self.background
        if tc.background == RANDOM_BACKGROUND:  # [n_rays, 3]: transparency never matches a pixel
            background = torch.rand(n_rays, 3, generator=self.ray_generator).to(self.device)
        target_depth = None if r.depth is None or tc.depth_weight == 0 else r.depth[idx]
        if target_depth is not None and tc.depth_background == DEPTH_RANDOM_BACKGROUND:
            colours = torch.rand(n_rays, 3, generator=self.ray_generator).to(self.device)
            background = backgrounds_for_rays(background, torch.isfinite(target_depth), colours)
        free_until = None if target_depth is None else free_space_limit(target_depth, self.marching.step, self.free_margin)
        t_stop = r.t_max[idx] if r.t_stop is None else r.t_stop[idx]
        out, coarse_out, solid_sigmas = self.render(
            r.origins[idx], r.directions[idx], r.t_min[idx], t_stop, jitter, fine_jitter,
            CompositeOptions(background, True, tc.detach_semantic_weights, free_until,
                             open_rays if sc.grid_open_labels == "geometry" else None), solid_offsets=solid_offsets,
            open_rays=open_rays,
        )
        if sc.grid_from_training and out.sample_points is not None:  # each rank its own; the refresh keeps rank 0's
            self.grid.observe(out.sample_points, out.sample_sigmas)
        target_rgb = composite_target(r.rgb[idx], None if r.alpha is None else r.alpha[idx], background)
        if sc.grid_reopen > 0 and self.coarse is None and self.progress() < sc.grid_reopen_until:
            self._reopen_worst(out, target_rgb, idx, t_stop)
        mse = photometric_mse(out.rgb, target_rgb, colour_weights)
        ce = self._semantic_loss(out.class_log_probs, r.channels[idx], label_weights)
        distortion = out.distortion.mean()
        distortion_weight = self.distortion_weight if self.progress() >= tc.distortion_start else 0.0
        loss = mse + tc.semantic_weight * ce + distortion_weight * distortion
        depth_term = mse.new_zeros(())
        if target_depth is not None:  # expected termination (the transparent rest at the ray's far end, the box's:
            # a ray whose marching stops just past its surface must still be opaque there)
            termination = out.depth * out.opacity + (1.0 - out.opacity) * r.t_max[idx].clamp(min=0.0)
            depth_term = depth_loss(termination, target_depth) + free_space_loss(out.front_weight, target_depth)
            loss = loss + tc.depth_weight * depth_term
        if solid_sigmas is not None:
            loss = loss + solid_weight * solid_interior_loss(solid_sigmas, self.marching.step)
        n_evaluated = out.n_evaluated
        if coarse_out is not None:  # NeRF: the coarse render is supervised alike (logged: the fine one)
            loss = loss + photometric_mse(coarse_out.rgb, target_rgb)
            loss = loss + tc.semantic_weight * self._semantic_loss(coarse_out.class_log_probs, r.channels[idx])
            n_evaluated += coarse_out.n_evaluated
        # the checks see the mean over ranks, so that all ranks stop together
        mse_mean, ce_mean, distortion_mean, depth_mean, loss_mean = all_reduce_mean(
            torch.stack([mse, ce, distortion.to(mse.dtype), depth_term.to(mse.dtype), loss]).detach()
        ).tolist()
        if not math.isfinite(loss_mean):
            raise TrainingError(
                f"the loss became non-finite at step {step} (mse={mse_mean}, ce={ce_mean}); "
                "the learning rate is probably too high for this scene"
            )
        self.guard.observe(self.state.step, mse_mean)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if tc.tv_weight > 0:
            loss_mean += self._add_grid_tv()
        self.optimizer.step()
        self.state.step += 1
        return {
            "step": self.state.step,
            "loss": loss_mean,
            "mse": mse_mean,
            "ce": ce_mean,
            "distortion": distortion_mean,
            "depth": depth_mean,
            "psnr": -10.0 * math.log10(max(mse_mean, 1e-10)),
            "samples_per_ray": n_evaluated / n_rays,
        }

    def state_dict(self) -> dict:
        """Everything needed to continue training exactly where it stopped."""
        data = {
            "model": self.model.state_dict(),
            "occupancy": self.grid.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "step": self.state.step,
            "elapsed": self.state.elapsed,
            "history": self.state.history,
            "generator": self.generator.get_state(),
        }
        if self.schedule.anchor is not None:  # the schedules follow the clock: a resumed build keeps them so
            data["budget_anchor"] = self.schedule.anchor
        if self.guard.rollbacks:  # and its count, so that a later rollback lowers the rate further
            data["rollbacks"] = [dict(r) for r in self.guard.rollbacks]
        if self.coarse is not None:
            data["coarse_model"] = self.coarse.state_dict()
        return data

    def load_state_dict(self, data: dict) -> None:
        """Continue from :meth:`state_dict` output (e.g. a checkpoint's
        :meth:`~scenelabel.fields.checkpoint.Checkpoint.training_state`)."""
        self.model.load_state_dict(data["model"])
        if self.coarse is not None:
            self.coarse.load_state_dict(data["coarse_model"])
        self.grid.load_state_dict(data["occupancy"])
        self.optimizer.load_state_dict(data["optimizer"])
        self.state = TrainState(step=int(data["step"]), elapsed=float(data["elapsed"]), history=list(data.get("history", [])))
        if "generator" in data:
            self.generator.set_state(data["generator"])
        self.schedule = RunSchedule(data.get("budget_anchor"))
        self.guard.rollbacks = [dict(r) for r in data.get("rollbacks", self.guard.rollbacks)]

    def drop_data_parallel(self) -> None:
        """Unwrap the DistributedDataParallel render: training with the other ranks is over, and the
        wrapper holds the process group (:func:`scenelabel.train.distributed.leave` says why that matters)."""
        if isinstance(self.render, nn.parallel.DistributedDataParallel):
            self.render = self.render.module

    def run(self, on_checkpoint: Callable[["Trainer"], None] | None = None, progress: bool = True) -> TrainState:
        """Train until ``steps`` or the time budget; calls ``on_checkpoint`` every checkpoint_every steps.

        When training ends, the density grid is rebuilt from the final field
        (:meth:`~scenelabel.render.sampling.DensityGrid.rebuild`). On Ctrl-C (taken between steps) it calls
        ``on_checkpoint`` once more and raises :class:`TrainingInterrupted`.
        Data-parallel: only rank 0 shows progress and calls ``on_checkpoint``.
        """
        with _interrupt_between_steps() as interrupted:
            return self._run(on_checkpoint, progress, interrupted)

    def _run(self, on_checkpoint, progress: bool, interrupted: threading.Event) -> TrainState:
        tc = self.config.train
        start = time.perf_counter() - self.state.elapsed
        if not self.dist.is_main:
            on_checkpoint, progress = None, False
        self.render.train()
        bar = tqdm(total=tc.steps, initial=self.state.step, disable=not progress, unit="step", dynamic_ncols=True)
        threads, told = torch.get_num_threads(), False
        try:
            while self.state.step < tc.steps:
                if interrupted.is_set():
                    raise KeyboardInterrupt
                if update_share() < threads and not told:  # other scenelabel jobs started (scenelabel._cores)
                    told = True  # once: the share then follows the jobs as they start and end
                    bar.write(f"step {self.state.step}: {share_summary()}; the share follows them as they start and end")
                self.guard.keep(self.state.step, self._snapshot)
                try:
                    logs = self.train_step()
                except Diverged as diverged:
                    bar.write(self._roll_back(diverged))
                    bar.n = self.state.step
                    continue
                elapsed = time.perf_counter() - start
                if self.dist.distributed:  # the ranks' mean: the same schedule and budget everywhere
                    elapsed = float(all_reduce_mean(torch.tensor([elapsed], dtype=torch.float64, device=self.device))[0])
                self.state.elapsed = elapsed
                if self.schedule.observe(*self._run_position()):
                    bar.write(f"step {self.state.step}: the time budget will end the run before step {tc.steps}; "
                              "the schedules follow the clock to its end")
                if self.state.step % tc.log_every == 0 or self.state.step == tc.steps:
                    logs["time"] = self.state.elapsed
                    logs["threads"] = torch.get_num_threads()
                    self.state.history.append(logs)
                    bar.set_postfix(loss=f"{logs['loss']:.4f}", psnr=f"{logs['psnr']:.1f}", spr=f"{logs['samples_per_ray']:.0f}")
                bar.update(1)
                if on_checkpoint is not None and self.state.step % tc.checkpoint_every == 0:
                    on_checkpoint(self)
                if tc.time_budget is not None and self.state.elapsed >= tc.time_budget:
                    bar.write(f"time budget of {tc.time_budget:.3g} s reached after {self.state.step} steps")
                    break
            # queries and maps skip space by the grid of the final field, not the lagging average
            self.grid.rebuild(self.model.density)
            broadcast_module_buffers(self.grid)
        except KeyboardInterrupt:
            if on_checkpoint is not None:
                on_checkpoint(self)
            raise TrainingInterrupted(f"interrupted at step {self.state.step}") from None
        finally:
            bar.close()
            self.render.eval()
        return self.state
