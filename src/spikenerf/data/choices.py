"""The training inputs' typed choices, defined once, without importing torch (the CLI's choices and the
train config's types): the methods' names, the training colours, the order of spike windows. The image
reconstructions (``TargetRecon``) are in :mod:`spikenerf.data.reconstruction`, which needs only numpy."""

from __future__ import annotations

from typing import Literal, get_args

#: the names of the training methods, and only their names: each is one class, with its facts and rules, in
#: ``spikenerf.train.methods.METHOD_CLASSES`` (which builds its targets from ``spikenerf.data.targets``)
Method = Literal[
    "spike-integral", "spike-nerf", "nerf-recon", "nerf-blur", "nerf-blur-aware", "nerf-bad", "nerf-gt"
]
METHODS: tuple[str, ...] = get_args(Method)
#: colours a radiance field is trained in
TrainColor = Literal["gray", "rgb"]
COLORS: tuple[str, ...] = get_args(TrainColor)
#: the order in which a window sampler visits the spike windows
WindowOrder = Literal["sequential", "random"]
WINDOW_ORDERS: tuple[str, ...] = get_args(WindowOrder)
