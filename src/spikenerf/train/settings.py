"""What training takes, without importing torch: the typed choices, the default sizes and the small config
sections that the torch modules read too. ``train/config.py`` (the typed :class:`TrainConfig`) and the CLI's
options are built from here, so that ``spikenerf train --help`` never imports torch; each
choice's meaning stays with the module that implements it (``amp``, ``logger``, ``losses``, ``methods``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal, get_args

from spikenerf.core.config import Bound, check_config

#: mixed precision of the training step (:mod:`spikenerf.train.amp`)
AmpMode = Literal["none", "bf16", "fp16"]
AMP_MODES: tuple[str, ...] = get_args(AmpMode)
#: where the training logs go besides ``curves.csv`` (:mod:`spikenerf.train.logger`)
LogKind = Literal["none", "tensorboard"]
LOG_KINDS: tuple[str, ...] = get_args(LogKind)
#: the spike loss's window pairs (:mod:`spikenerf.train.losses`)
PairMode = Literal["all", "window"]
#: the differentiable interval loss, or the paper's spike comparison (no gradient)
SpikeLossKind = Literal["interval", "paper"]
SPIKE_LOSS_KINDS: tuple[str, ...] = get_args(SpikeLossKind)
#: how the spike-integral loss weighs each ray's squared error: ``linear`` alike, ``srgb`` by the squared
#: sRGB slope at its detached render (:func:`spikenerf.train.losses.window_mean_loss`)
LossWeight = Literal["linear", "srgb"]
LOSS_WEIGHTS: tuple[str, ...] = get_args(LossWeight)

#: each method in one line (``train --help``); its class is ``spikenerf.train.methods.METHOD_CLASSES[name]``
METHOD_SUMMARIES: dict[str, str] = {
    "spike-integral": (
        "the default; ours, not in the paper: spike-count means over short windows compared with renders "
        "at steps drawn inside each window, at their own poses, and where the image moves fast the spikes "
        "along each rendered point's image track; --integral-window, --integral-samples, --integral-track"
    ),
    "spike-nerf": (
        "the paper's method with window-aware TFP/TFI targets (unmasked) + differentiable spike loss; "
        "--window-poses 1: the paper's one-pose targets with spike masks"
    ),
    "nerf-recon": "TFP/TFI targets",
    "nerf-blur": "the dataset's 400 fps blur views",
    "nerf-blur-aware": "deblur NeRF given the true trajectory: blur views, exposure-averaged renders",
    "nerf-bad": (
        "BAD-NeRF-like: learns each blur view's exposure start and end pose from the blurred frames "
        "alone; --set exposure.lr=..."
    ),
    "nerf-gt": "sharp ground truth, an oracle",
}

#: rays per step when ``batch`` is not given: 1024 targets (spike-integral: :data:`INTEGRAL_WINDOWS`)
DEFAULT_BATCH = 1024
#: on CUDA the default batch is this many times the CPU one (where it fits): a GPU step costs about the same
#: up to 16384 rays (H200: 21.8 ms at 4096, 21.9 ms at 16384 for spike-integral; docs/performance.md)
GPU_BATCH_SCALE = 4
#: spike-integral's longest default window and steps rendered per window (docs/spike-integral.md, Choosing)
INTEGRAL_WINDOW, INTEGRAL_SAMPLES = 5, 1
#: the default window is shortened so that the image moves at most this many pixels in it, to no fewer steps
#: than INTEGRAL_SHORTEST (:func:`default_window`)
INTEGRAL_SPAN_PX, INTEGRAL_SHORTEST = 1.5, 2
#: spike-integral's default windows a step (docs/spike-integral.md, Cost): 4096 rays at one render each
INTEGRAL_WINDOWS = 4096
#: ``integral.track``'s default where the image motion shortens the default window (:func:`default_track`):
#: tracks of 2 · TRACK_HALF + 1 steps (docs/spike-integral.md, Track windows)
TRACK_HALF = 5


@dataclass
class ExposurePoseConfig:
    """The learned exposure poses of ``nerf-bad`` (``--set exposure.X=...``).

    Attributes:
        lr: Adam rate of the corrections (radians and scene units per step); BAD-NeRF uses 1e-3.
        lr_final_ratio: exponential decay to this fraction of ``lr`` at the end of the run (BAD-NeRF: 1e-5,
            i.e. 0.01).
        warmup_iters: linear warm-up of the rate from 0 (BAD-NeRF: none).
        init_noise: standard deviation of the initial half-motion δ (> 0 breaks the start/end symmetry).
        learn_centre: learn the centre correction μ too (BAD-NeRF learns both poses); false keeps every
            exposure centred on its given pose (only δ is learned: no common drift of poses and scene).
    """

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "lr": Bound(above=0), "lr_final_ratio": Bound(above=0, most=1), "warmup_iters": Bound(least=0),
        "init_noise": Bound(above=0),
    }  # fmt: skip

    lr: float = 1e-3
    lr_final_ratio: float = 0.01
    warmup_iters: int = 0
    init_noise: float = 1e-3
    learn_centre: bool = True

    def check(self) -> None:
        """InputError on a wrong type or an out-of-range value (names the config key, ``exposure.KEY``)."""
        check_config(self, "exposure.")


@dataclass
class PoseRefineConfig:
    """Pose refinement (``--refine-poses``; ``--set poses.X=...``).

    Attributes:
        refine: learn the corrections (None, the default: on for datasets written by ``spikenerf import``,
            off for simulated ones with their exact poses; docs/real-data.md measures the gain).
        lr: Adam rate of the corrections (radians and scene units per step) after the warm-up.
        lr_final_ratio: exponential decay to this fraction of ``lr`` at the end of the run.
        warmup_iters: linear warm-up of the rate from 0 (None: the grid's first upsampling step, the end of
            its coarsest stage; a tenth of the run for the MLP field).
        keyframe_every: steps between keyframes on a dataset that was not imported.
    """

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "lr": Bound(above=0), "lr_final_ratio": Bound(above=0, most=1), "warmup_iters": Bound(least=0),
        "keyframe_every": Bound(least=1),
    }  # fmt: skip

    refine: bool | None = None
    lr: float = 1e-3
    lr_final_ratio: float = 0.05
    warmup_iters: int | None = None
    keyframe_every: int = 20

    def check(self) -> None:
        """InputError on a wrong type or an out-of-range value (names the config key, ``poses.KEY``)."""
        check_config(self, "poses.")
