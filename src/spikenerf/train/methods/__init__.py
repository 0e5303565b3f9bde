"""Training methods: one :class:`TrainMethod` per ``--method``; each builds its targets and returns its named
loss terms, and the trainer sums them (compare nerfstudio's ``Model.get_loss_dict``).

Every method renders ``batch`` random rays against its image targets (``recon``, linear MSE; images posed
at S > 1 poses are rendered at each and averaged first) and adds the field's prior (``reg``). Spike-NeRF adds,
once its λ(it) > 0, one window of L consecutive steps for P pixels (``spike``, weighted by λ). The terms keep
these names in ``curves.csv`` and TensorBoard (``loss/recon``, ``loss/spike``, ``loss/reg``).

=================  ==============================================  ==================================
method             targets (``spikenerf.data.targets``)             loss terms
=================  ==============================================  ==================================
nerf-gt            sharp GT renders (``gt_targets``)               recon, reg
nerf-blur          blur views at mid-exposure (``blur_targets``)   recon, reg
nerf-blur-aware    blur views at ``blur_samples`` exposure poses   recon (exposure-averaged), reg
nerf-bad           blur views at learned exposure start/end poses  recon (exposure-averaged), reg
nerf-recon         Î_k at every step (``stream_targets``)          recon, reg
spike-nerf         M_k ⊙ Î_k at every step + the recorded stream   recon, reg, λ(it) · spike
spike-integral     spike counts of L-step windows (``integral``)   recon (S steps per window), reg
=================  ==============================================  ==================================

With ``targets.window_poses`` S > 1 (the default for TFP targets: 4), nerf-recon and spike-nerf render each
TFP target at S poses spread over its window and average them (window-aware targets; S = 1 is the paper's).

**One registry.** A method is its class: its ``name`` (the ``--method`` value, one of the
``spikenerf.data.targets.Method`` Literal), its facts (``views``, ``uses_stream``, ``has_spike_loss``,
``default_batch``, ``learns_poses``) and its own config rules (:meth:`TrainMethod.check`, which
``TrainConfig.validate`` calls), listed once in :data:`METHOD_CLASSES`; ``TrainConfig``, the CLI's
``--method`` choices, :func:`make_method` and the benchmark read that table. Adding a method is a class
(a module of this package), its entry in :data:`METHOD_CLASSES` and its name in the ``Method`` Literal
(docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Iterable

from spikenerf.core.errors import check_choice
from spikenerf.train.methods.base import (
    METHOD_KEYS,
    SHARED_KEYS,
    WINDOW_KEYS,
    Config,
    StepLosses,
    Term,
    TrainMethod,
    TrainState,
)
from spikenerf.train.methods.blur import NerfBAD, NerfBlur, NerfBlurAware, NerfGT
from spikenerf.train.methods.integral import SpikeIntegral, default_track, default_window
from spikenerf.train.methods.recon import NerfRecon, SpikeNeRF

__all__ = [
    "METHOD_CLASSES",
    "METHOD_KEYS",
    "SHARED_KEYS",
    "WINDOW_KEYS",
    "Config",
    "NerfBAD",
    "NerfBlur",
    "NerfBlurAware",
    "NerfGT",
    "NerfRecon",
    "SpikeIntegral",
    "SpikeNeRF",
    "StepLosses",
    "Term",
    "TrainMethod",
    "TrainState",
    "check_only_keys",
    "default_track",
    "default_window",
    "make_method",
    "method_class",
    "unused_keys",
]

#: ``--method`` -> its class: the one table of training methods, in the order of the ``Method`` Literal of
#: ``spikenerf.data.targets`` (its names; tests/test_methods.py checks that each has exactly one entry)
METHOD_CLASSES: dict[str, type[TrainMethod]] = {
    cls.name: cls for cls in (SpikeIntegral, SpikeNeRF, NerfRecon, NerfBlur, NerfBlurAware, NerfBAD, NerfGT)
}


def method_class(name: str) -> type[TrainMethod]:
    """The :class:`TrainMethod` class of ``name`` (InputError naming ``method`` for an unknown one)."""
    check_choice(name, METHOD_CLASSES, "method")
    return METHOD_CLASSES[name]


def unused_keys(method: str, keys: Iterable[str]) -> list[str]:
    """The config ``keys`` (dotted, e.g. ``spike.lam``) that ``method`` does not read: those of
    :data:`METHOD_KEYS` outside its :attr:`TrainMethod.reads`, in the given order."""

    def among(key: str, patterns: Iterable[str]) -> bool:
        return any(key == p or (p.endswith(".") and key.startswith(p)) for p in patterns)

    reads = method_class(method).reads
    return [k for k in keys if among(k, METHOD_KEYS) and not among(k, (*reads, *SHARED_KEYS))]


def check_only_keys(method: str, keys: Iterable[str]) -> list[str]:
    """The keys among ``keys`` that do not change how ``method`` trains, in the given order: the
    :data:`WINDOW_KEYS` it does not train with (they still set eval's no-reference checks and the hold-out
    guard band), ``targets.recon`` where it does not read it (it still sets the reconstruction that
    eval's no-reference checks compare renders with), and its :attr:`TrainMethod.scores_with` (they set only
    how eval scores its renders)."""
    cls = method_class(method)
    return [
        k
        for k in keys
        if (k in WINDOW_KEYS and k not in cls.trains_with)
        or (k == "targets.recon" and k not in cls.reads)
        or k in cls.scores_with
    ]


def make_method(config: Config) -> TrainMethod:
    """The :class:`TrainMethod` of ``config.method`` (InputError for an unknown one)."""
    return method_class(config.method)(config)
