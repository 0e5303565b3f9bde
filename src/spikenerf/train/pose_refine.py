"""Pose refinement during training: learnable SE(3) corrections per keyframe (docs/real-data.md).

Each keyframe ``k`` carries a correction ``ξ_k = (ω_k, ρ_k)`` in so(3) × R³ log coordinates, zero at the
start. The correction of any spike step is the linear blend of the two neighbouring keyframes' ``ξ`` (held
beyond the first and last keyframe; the brackets are the ones the importer slerps the poses with,
:func:`spikenerf.importing.interpolation.key_brackets`) and it acts in the camera frame:
``c2w' = c2w · [exp(ω) | ρ]`` (a rotation about the camera centre, a shift along the camera's own axes).
A zero correction is the identity exactly. The corrections get their own Adam with a small learning rate and
a coarse-to-fine schedule fitted to the grid field (see :func:`pose_lr`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.data.holdout import is_imported
from spikenerf.importing.interpolation import key_brackets
from spikenerf.importing.keyframes import keyframe_steps
from spikenerf.train.settings import PoseRefineConfig

REFINED_POSES = "refined_poses.json"


def so3_exp(omega: Tensor) -> Tensor:
    """Rodrigues: axis-angle vectors (..., 3) → rotation matrices (..., 3, 3); exact identity at 0 and a
    Taylor expansion near it (smooth gradients there).

    Raises:
        InputError: ``omega`` not (..., 3).
    """
    if omega.dim() == 0 or omega.shape[-1] != 3:
        raise InputError(
            f"omega must be (..., 3) axis-angle vectors, found {tuple(omega.shape)}", param="omega"
        )
    theta2 = (omega * omega).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-8
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / torch.where(small, 1, theta2))
    zero = torch.zeros_like(omega[..., 0])
    x, y, z = omega.unbind(-1)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*omega.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand_as(k)
    return eye + a * k + b * (k @ k)


def se3_exp(xi: Tensor) -> Tensor:
    """so(3) × R³ log coordinates (..., 6) = (ω, ρ) → rigid transforms (..., 4, 4) ``[exp(ω) | ρ]``.

    Raises:
        InputError: ``xi`` not (..., 6).
    """
    if xi.dim() == 0 or xi.shape[-1] != 6:
        raise InputError(f"xi must be (..., 6) = (ω, ρ) vectors, found {tuple(xi.shape)}", param="xi")
    out = torch.zeros(*xi.shape[:-1], 4, 4, dtype=xi.dtype, device=xi.device)
    out[..., :3, :3] = so3_exp(xi[..., :3])
    out[..., :3, 3] = xi[..., 3:]
    out[..., 3, 3] = 1.0
    return out


def keyframes_of(dataset: Any, every: int) -> np.ndarray:
    """Keyframe steps (N,) int64 of a dataset: the ones an import registered (its held-out test keyframes
    left out), else every ``every`` steps of the trajectory plus its last step."""
    steps = np.asarray(dataset.trajectory.steps, np.int64)
    info = (dataset.config or {}).get("imported")
    if (
        info
    ):  # the steps that had poses; older imports, or dense ones (an orbit): the importer's keyframe rule
        try:
            rule = keyframe_steps(len(steps), int(info["keyframe_every"]), int(info["window"]))
            keys = info.get("pose_steps")
            keys = rule if keys is None or len(keys) > len(rule) else keys
            keys = np.setdiff1d(np.asarray(keys, np.int64), info.get("test_keyframes") or []) + steps[0]
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(
                f"config.yaml: the imported section is incomplete or malformed "
                f"({type(err).__name__}: {err}); re-run `spikenerf import`",
                path=dataset.root,
            ) from None
    else:
        keys = np.unique(np.append(np.arange(steps[0], steps[-1] + 1, every), steps[-1]))
    keys = keys[np.isin(keys, steps)]
    if len(keys) < 2:
        raise InputError(
            f"poses.refine needs at least 2 keyframes on the trajectory, the dataset gives {len(keys)} "
            f"({len(steps)} steps)",
            path=getattr(dataset, "root", None),
            param="poses.refine",
        )
    return keys


def pose_lr(config: Any, iteration: int, iters: int, warmup: int) -> float:
    """The corrections' rate at ``iteration``: a linear warm-up from 0 over ``warmup`` iterations, times an
    exponential decay to ``lr_final_ratio`` at ``iters``."""
    ramp = min(1.0, iteration / warmup) if warmup > 0 else 1.0
    return config.lr * ramp * config.lr_final_ratio ** (iteration / max(iters, 1))


class PoseRefiner(torch.nn.Module):
    """Corrections ``xi`` (N, 6) of keyframes at ``key_steps`` (N,) and their per-step interpolation.

    A keyframe that no training step has read yet (``reached`` False: with the hold-out, one whose
    neighbourhood lies inside a held-out band) has no gradient and keeps its zero correction. In training
    mode (``train()``, a new module's) a call reads ``xi`` as learned, and a call that tracks gradients (a
    training step) marks the keyframes it reads with a nonzero weight. In evaluation mode (``eval()``, or
    :func:`evaluating`: eval, render, the trainer's test views, ``refined_poses.json``) a call marks nothing
    and reads :meth:`filled_xi`: an unreached keyframe's correction is the blend of the nearest reached
    keyframes either side (held beyond the first and last), so that a held-out step follows the drift of
    the path around it."""

    def __init__(self, key_steps: np.ndarray) -> None:
        super().__init__()
        self.key_steps = np.asarray(key_steps, np.int64)
        self.xi = torch.nn.Parameter(torch.zeros(len(self.key_steps), 6))
        self.reached = np.zeros(len(self.key_steps), bool)  # (N,) read by a step that tracked gradients

    def get_extra_state(self) -> Tensor:
        """``reached`` as a (N,) bool tensor (a checkpoint's pose state holds tensors only)."""
        return torch.as_tensor(self.reached.copy())

    def set_extra_state(self, state: Any) -> None:
        """``reached`` from :meth:`get_extra_state`'s (N,) bool tensor.

        Raises:
            InputError: ``state`` not a (N,) bool tensor of this refiner's N keyframes.
        """
        if not (torch.is_tensor(state) and state.dtype == torch.bool and state.dim() == 1):
            found = (
                f"a {tuple(state.shape)} {state.dtype}" if torch.is_tensor(state) else type(state).__name__
            )
            raise InputError(
                f"the checkpoint's pose keyframe marks must be a (N,) bool tensor, found {found}",
                param="poses",
            )
        if len(state) != len(self.key_steps):
            raise InputError(
                f"the checkpoint's pose corrections mark {len(state)} keyframes, the dataset has "
                f"{len(self.key_steps)}",
                param="poses",
            )
        self.reached = state.cpu().numpy().copy()

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        """As ``torch.nn.Module``'s; a checkpoint written before ``reached`` was kept counts a keyframe as
        reached where its correction moved from zero (Adam leaves an unread one at exactly 0).

        Raises:
            InputError: ``xi`` missing or not (N, 6) for this refiner's N keyframes, or the marks not
                (N,) bool (the checkpoint of another dataset's keyframes, or a damaged one).
        """
        xi = state_dict.get("xi")
        if not (torch.is_tensor(xi) and tuple(xi.shape) == tuple(self.xi.shape)):
            found = f"{tuple(xi.shape)}" if torch.is_tensor(xi) else "missing"
            raise InputError(
                f"the checkpoint's pose corrections are {found}, the dataset's {len(self.key_steps)} "
                f"keyframes need ({len(self.key_steps)}, 6)",
                param="poses",
            )
        if "_extra_state" not in state_dict:
            state_dict = {**state_dict, "_extra_state": xi.ne(0).any(-1).cpu()}
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def filled_xi(self) -> Tensor:
        """``xi`` (N, 6) with each unreached keyframe's row the blend of the nearest reached ones, by step;
        ``xi`` itself while every keyframe or none is reached."""
        known = np.flatnonzero(self.reached)
        if len(known) in (0, len(self.reached)):
            return self.xi
        if len(known) == 1:
            lo = hi = np.zeros(len(self.reached), np.int64)
            t = np.zeros(len(self.reached))
        else:
            lo, hi, t = key_brackets(self.key_steps[known], self.key_steps)
        blend = blended(self.xi[torch.as_tensor(known, device=self.xi.device)], lo, hi, t)
        own = torch.as_tensor(self.reached, device=self.xi.device)[:, None]
        return torch.where(own, self.xi, blend)

    def correction(self, steps: Tensor | np.ndarray) -> Tensor:
        """Rigid corrections (N, 4, 4) at spike ``steps`` (N,) (linear blend of the neighbours' ``xi``).

        In training mode: ``xi`` as learned, and a call that tracks gradients (a training step) marks the
        keyframes it reads (nonzero weight) as reached; a call without them (spike-integral's track
        projection) marks nothing. In evaluation mode: :meth:`filled_xi`, marking nothing."""
        lo, hi, t = key_brackets(self.key_steps, np.asarray(torch.as_tensor(steps).cpu(), np.int64))
        t = np.clip(t, 0.0, 1.0)
        if self.training and torch.is_grad_enabled():
            self.reached[lo[t < 1]] = True
            self.reached[hi[t > 0]] = True
        return se3_exp(blended(self.xi if self.training else self.filled_xi(), lo, hi, t))

    def forward(self, poses: Tensor, steps: Tensor | np.ndarray) -> Tensor:
        """Corrected camera-to-world poses (N, 4, 4) of ``poses`` (N, 4, 4) at ``steps`` (N,)."""
        return corrected(poses, lambda: self.correction(steps), self.xi)


def blended(rows: Tensor, lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> Tensor:
    """``(1 − w) rows[lo] + w rows[hi]`` (M, 6) of keyframe ``rows`` (K, 6) at brackets ``lo``, ``hi`` (M,)
    and fractions ``t`` (M,), ``w`` = ``t`` clipped to [0, 1] (held beyond the end keyframes)."""
    w = torch.as_tensor(np.clip(t, 0.0, 1.0), dtype=rows.dtype, device=rows.device)[:, None]
    lo_t, hi_t = (torch.as_tensor(i, device=rows.device) for i in (lo, hi))
    return (1 - w) * rows[lo_t] + w * rows[hi_t]


@contextlib.contextmanager
def evaluating(refiner: PoseRefiner) -> Iterator[PoseRefiner]:
    """``refiner`` in evaluation mode inside the block (:class:`PoseRefiner`: the filled corrections, no
    marks), its own mode again after it."""
    was = refiner.training
    refiner.eval()
    try:
        yield refiner
    finally:
        refiner.train(was)


def corrected(poses: Tensor, correction: Any, like: Tensor) -> Tensor:
    """``poses`` (..., 4, 4) times the rigid ``correction()`` (..., 4, 4), on ``like``'s device; always in
    float32, also inside a mixed-precision step (a bf16 pose would be off by ~0.01 scene units)."""
    with torch.autocast(like.device.type, enabled=False):
        return poses.to(like.device, like.dtype) @ correction()


class PoseLearner:
    """Learnable pose parameters (``refiner``, a module) with their own Adam (β = 0.9, 0.99) and rate
    schedule (:func:`pose_lr` of ``config``: ``lr``, ``lr_final_ratio``): the trainer's hooks (:meth:`begin`,
    ``optimizer``, the checkpoint state)."""

    def __init__(self, refiner: torch.nn.Module, config: Any, iters: int, warmup: int) -> None:
        self.refiner, self.config, self.iters, self.warmup = refiner, config, iters, warmup
        self.optimizer = torch.optim.Adam(self.refiner.parameters(), lr=0.0, betas=(0.9, 0.99))

    def begin(self, iteration: int) -> None:
        """Set the rate of ``iteration`` and clear the gradients (before the backward pass)."""
        for g in self.optimizer.param_groups:
            g["lr"] = pose_lr(self.config, iteration, self.iters, self.warmup)
        self.optimizer.zero_grad(set_to_none=True)

    def state_dict(self) -> dict[str, Any]:
        return {"refiner": self.refiner.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.refiner.load_state_dict(state["refiner"])
        self.optimizer.load_state_dict(state["optimizer"])

    def write(self, out: Path) -> None:
        """Write the learned poses into the run folder ``out`` (a JSON file)."""
        raise NotImplementedError


class PoseRefinement(PoseLearner):
    """The trainer's hooks: the refiner, its optimiser and schedule, checkpoint state and the JSON output."""

    def __init__(self, config: PoseRefineConfig, dataset: Any, iters: int, warmup: int, device: Any) -> None:
        self.dataset = dataset
        super().__init__(
            PoseRefiner(keyframes_of(dataset, config.keyframe_every)).to(device), config, iters, warmup
        )
        traj = dataset.trajectory
        self._traj_poses = torch.as_tensor(traj.poses, dtype=torch.float32)  # (T, 4, 4)
        self._traj_steps = np.asarray(traj.steps, np.int64)
        self._traj_step_numbers = torch.as_tensor(self._traj_steps)

    def __call__(self, poses: Tensor, steps: Tensor | np.ndarray) -> Tensor:
        return self.refiner(poses, steps)

    def images(self, targets: Any, index: Tensor, poses: Tensor) -> Tensor:
        """Corrected poses (B·S, 4, 4) of image targets ``index`` (B,) given as ``poses`` (B·S, 4, 4)."""
        steps = targets.steps[index, None] if targets.pose_steps is None else targets.pose_steps[index]
        return self.refiner(poses, steps.expand(len(index), targets.poses.shape[1]).reshape(-1))

    def window(self, poses: Tensor, index: Tensor) -> Tensor:
        """Corrected poses (L, 4, 4) of ``poses`` (L, 4, 4), the trajectory's at indices ``index`` (L,)."""
        return self.refiner(poses, self._traj_step_numbers[index.cpu()])

    def views(self, views: Any) -> Any:
        """The evaluation views with their first poses refined by :meth:`eval_poses`."""
        return dataclasses.replace(views, poses=self.eval_poses(views.poses[:, 0])[:, None])

    def eval_poses(self, poses: Tensor) -> Tensor:
        """Evaluation poses (V, 4, 4) from ``poses`` (V, 4, 4) (see :func:`on_path_poses`)."""
        return on_path_poses(self.refiner, self.dataset.trajectory, poses)

    @torch.no_grad()
    def write(self, out: Path) -> None:
        """``RUN/refined_poses.json``: each keyframe's step, correction and given and refined pose."""
        keys = self.refiner.key_steps
        idx = np.searchsorted(self._traj_steps, keys)
        given = self._traj_poses[idx]
        with evaluating(self.refiner):
            refined = self.refiner(given, keys).cpu().double().numpy()
        xi = self.refiner.filled_xi().detach().cpu().double().numpy()
        reached = self.refiner.reached
        frames = [
            {
                "step": int(s),
                "omega": xi[i, :3].tolist(),
                "rho": xi[i, 3:].tolist(),
                "rotation_deg": float(np.degrees(np.linalg.norm(xi[i, :3]))),
                "trained": bool(reached[i]),
                "given_matrix": given[i].double().tolist(),
                "transform_matrix": refined[i].tolist(),
            }
            for i, s in enumerate(keys)
        ]
        doc = {
            "convention": "c2w' = c2w · [exp(omega) | rho]; omega in radians, rho in scene units along the "
            "camera axes; steps between keyframes blend the neighbours' (omega, rho) linearly; a keyframe "
            "no training step read (trained false) takes the blend of the nearest trained ones",
            "keyframes": frames,
        }
        write_text_atomic(out / REFINED_POSES, json.dumps(doc, indent=1) + "\n")


def pose_refinement(
    config: Any, dataset: Any, model: Any, device: Any, targets: Any
) -> PoseRefinement | None:
    """The run's :class:`PoseRefinement`, or None when refinement is off (``config.poses.refine``; None: on
    for an imported dataset). Every image target (``targets``; None for spike-integral, whose windows are
    stream steps) must know its spike step; where one does not,
    asking for refinement is an InputError and the imported-dataset default simply stays off."""
    cfg: PoseRefineConfig = config.poses
    cfg.check()
    auto = is_imported(dataset) and not config.method_class().learns_poses  # nerf-bad: its exposure poses
    if not (auto if cfg.refine is None else cfg.refine):
        return None
    steps = None if targets is None else targets.steps if targets.pose_steps is None else targets.pose_steps
    unplaced = steps is not None and bool((steps < 0).any())  # None: spike-integral, stream steps only
    if unplaced and cfg.refine is None:
        return None
    if unplaced:
        raise InputError(
            f"poses.refine: the {config.method} targets have no spike steps to refine at",
            param="poses.refine",
        )
    warmup = cfg.warmup_iters
    if warmup is None:
        upsample = getattr(model.config, "upsample_steps", ())
        warmup = int(upsample[0]) if len(upsample) else config.iters // 10
    return PoseRefinement(cfg, dataset, config.iters, warmup, device)


def on_path_poses(refiner: PoseRefiner, trajectory: Any, poses: Tensor | np.ndarray) -> Tensor:
    """Evaluation poses (V, 4, 4) float32: a view whose pose is a pose of the ``trajectory`` (an imported
    held-out keyframe) gets that step's refined pose, interpolated from the neighbouring keyframes (its own
    keyframe is not refined); a novel view off the trajectory is used as given."""
    poses = torch.as_tensor(np.asarray(poses) if not isinstance(poses, Tensor) else poses).float().cpu()
    path = torch.as_tensor(trajectory.poses, dtype=torch.float32)
    dist = (poses[:, None] - path[None]).abs().flatten(2).amax(-1)  # (V, T)
    best = dist.argmin(1)
    on_path = dist.gather(1, best[:, None])[:, 0] < 1e-5
    with torch.no_grad(), evaluating(refiner):
        refined = refiner(poses, np.asarray(trajectory.steps)[best.numpy()]).cpu()
    return torch.where(on_path[:, None, None], refined, poses)


def run_refiner(state: dict[str, Any], config: Any, dataset: Any) -> PoseRefiner:
    """The refiner a run learned (its checkpoint's ``poses`` ``state``), in evaluation mode."""
    refiner = PoseRefiner(keyframes_of(dataset, config.poses.keyframe_every))
    refiner.load_state_dict(state["refiner"])
    return refiner.eval()


def refined_views(checkpoint: dict[str, Any], config: Any, dataset: Any, views: Any) -> Any:
    """``views`` (PosedImages of ``dataset``) with the poses a run refined (``spikenerf eval``): unchanged
    when the run (its ``checkpoint``) did not refine poses."""
    state = checkpoint.get("poses")
    if not state or len(views.poses) == 0:
        return views
    refiner = run_refiner(state, config, dataset)
    return dataclasses.replace(views, poses=on_path_poses(refiner, dataset.trajectory, views.poses).numpy())


def refined_dataset(checkpoint: dict[str, Any], config: Any, dataset: Any) -> Any:
    """``dataset`` with every trajectory pose (T, 4, 4) corrected as the run learned them (``spikenerf
    eval``'s no-reference checks render the path): unchanged when the run did not refine poses."""
    state = checkpoint.get("poses")
    if not state:
        return dataset
    refiner = run_refiner(state, config, dataset)
    traj = dataset.trajectory
    with torch.no_grad():
        poses = refiner(torch.as_tensor(np.asarray(traj.poses), dtype=torch.float32), np.asarray(traj.steps))
    refined = dataclasses.replace(traj, poses=poses.cpu().numpy().astype(np.asarray(traj.poses).dtype))
    return dataclasses.replace(dataset, trajectory=refined)
