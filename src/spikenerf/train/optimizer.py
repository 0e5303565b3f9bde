"""The optimiser of a run and its learning-rate schedule: Adam over the model's parameter groups (fused,
row-major on a CPU, or plain for ``--compile-optimizer``), decayed exponentially from each group's base rate.
"""

from __future__ import annotations

import torch

from spikenerf.render.base import RadianceModel
from spikenerf.train.compiled_optim import set_lr, use_tensor_lr
from spikenerf.train.config import TrainConfig
from spikenerf.train.dense_adam import DenseAdam


def make_optimizer(model: RadianceModel, config: TrainConfig) -> torch.optim.Adam:
    """Adam over the model's parameter groups; each group remembers its undecayed rate as ``base_lr``."""
    groups = model.param_groups(config.lr)
    for g in groups:
        g["base_lr"] = g["lr"]
    # the fused kernel updates each tensor in one pass (7× faster than the per-op loop on a CPU); on a CPU
    # it copies a channels-last tensor (the grid's factors) unless stepped through row-major views
    if config.compile_optimizer:  # plain Adam with tensor rates, stepped by CompiledAdamStep
        optimizer = torch.optim.Adam(groups, betas=(0.9, 0.99))
        use_tensor_lr(optimizer)
        return optimizer
    adam = DenseAdam if model.device.type == "cpu" else torch.optim.Adam
    return adam(groups, betas=(0.9, 0.99), fused=model.device.type in ("cpu", "cuda"))


def set_learning_rate(
    optimizer: torch.optim.Optimizer, iteration: int, iters: int, final_ratio: float
) -> None:
    """Exponential decay ``lr = base_lr · final_ratio^(iteration / iters)``."""
    factor = final_ratio ** (iteration / max(iters, 1))
    for g in optimizer.param_groups:
        set_lr(g, g["base_lr"] * factor)


def lr_final_ratio(config: TrainConfig, model: RadianceModel) -> float:
    """The ratio of the last learning rate to the first: ``config.lr_final_ratio``, else the field's."""
    return config.lr_final_ratio if config.lr_final_ratio is not None else float(model.config.lr_final_ratio)
