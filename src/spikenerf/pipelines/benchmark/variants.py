"""The benchmark's method variants, defined once: a variant is a training method (``--method``, one class of
:mod:`spikenerf.train.methods`) plus ``TrainConfig`` overrides (``--set KEY=VALUE``), with its label in the
tables. The tables' rows (:data:`TABLE1_VARIANTS`, :data:`ABLATION_VARIANTS`) and the paired differences the
paper claims (:data:`COMPARISONS`) are listed here too; benchmark, cells, tables, results, report and the CLI
read them from here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # a light module: the CLI builds its help from it
    from spikenerf.data.choices import Method
    from spikenerf.train.config import TrainConfig


@dataclass(frozen=True)
class Variant:
    """A benchmark row: ``method`` with the ``overrides`` (dotted ``TrainConfig`` keys → values)."""

    method: Method
    label: str
    overrides: tuple[tuple[str, Any], ...] = ()

    def assignments(self) -> list[str]:
        """The overrides as ``KEY=VALUE`` texts (values as YAML reads them back: ``false``, ``learned``)."""
        return [f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in self.overrides]

    def train_args(self) -> list[str]:
        """The ``spikenerf train`` flags that select it: ``--method M`` and one ``--set KEY=VALUE`` each."""
        return ["--method", self.method, *(a for item in self.assignments() for a in ("--set", item))]

    def config(self, **fields: Any) -> TrainConfig:
        """The ``TrainConfig`` it trains with (``fields``: other options, e.g. ``dataset``), validated."""
        from spikenerf.train.config import TrainConfig
        from spikenerf.train.config_file import apply_overrides

        data = TrainConfig(method=self.method, **fields).to_dict()
        return TrainConfig.from_dict(apply_overrides(data, self.assignments())).validate()


#: poses per TFP target of the window-aware rows (``targets.window_poses``; docs/method.md, Targets)
WINDOW_POSES = 4
#: the paper's rows compare each TFP target with one render at its own step, whatever ``train``'s default
PAPER_TARGETS: tuple[tuple[str, Any], ...] = (("targets.window_poses", 1),)

#: variant -> what it trains (in the order ``--methods all`` runs them)
VARIANTS: dict[str, Variant] = {
    "nerf-gt": Variant("nerf-gt", "NeRF on sharp GT (oracle)"),
    "nerf-blur": Variant("nerf-blur", "NeRF on 400 fps blur"),
    "nerf-blur-aware": Variant("nerf-blur-aware", "Deblur NeRF given the true trajectory"),
    "nerf-bad": Variant(
        "nerf-bad", "BAD-NeRF-like: deblur NeRF that learns each exposure's start and end pose"
    ),
    "nerf-recon": Variant("nerf-recon", "NeRF + TFP reconstruction", PAPER_TARGETS),
    "spike-nerf": Variant("spike-nerf", "Spike-NeRF (paper)", PAPER_TARGETS),
    "nerf-recon-learned": Variant(
        "nerf-recon",
        "NeRF + learned reconstruction (Spk2ImgNet+NeRF stand-in)",
        (("targets.recon", "learned"),),
    ),
    "spike-nerf-learned": Variant(
        "spike-nerf", "Spike-NeRF on learned targets", (("targets.recon", "learned"),)
    ),
    "nerf-recon-window": Variant(
        "nerf-recon", "NeRF + TFP, window-aware targets", (("targets.window_poses", WINDOW_POSES),)
    ),
    "spike-nerf-window": Variant(  # with the masks it was measured with (train's default drops them there)
        "spike-nerf",
        "Spike-NeRF, window-aware targets",
        (("targets.window_poses", WINDOW_POSES), ("targets.mask", True)),
    ),
    "spike-integral": Variant("spike-integral", "Spike-integral (ours, train's default)"),
    "spike-nerf-no-mask": Variant("spike-nerf", "W/O spike masks", (*PAPER_TARGETS, ("targets.mask", False))),
    "spike-nerf-no-spike-loss": Variant(
        "spike-nerf", "W/O spike loss", (*PAPER_TARGETS, ("spike.enabled", False))
    ),
}
#: the rows of Table I (comparison) and Table II (ablation), in the paper's order
TABLE1_VARIANTS = (
    "nerf-gt",
    "nerf-blur",
    "nerf-blur-aware",
    "nerf-bad",
    "nerf-recon",
    "nerf-recon-learned",
    "spike-nerf",
    "spike-nerf-learned",
    "nerf-recon-window",
    "spike-nerf-window",
    "spike-integral",
)
ABLATION_VARIANTS = ("spike-nerf-no-mask", "spike-nerf-no-spike-loss", "spike-nerf")
#: the paired differences the paper claims: (ours, baseline); ours should be better on every metric
COMPARISONS: tuple[tuple[str, str], ...] = (
    ("spike-nerf", "nerf-recon"),
    ("spike-nerf", "nerf-blur"),
    ("spike-nerf", "spike-nerf-no-mask"),
    ("spike-nerf", "spike-nerf-no-spike-loss"),
)
#: pairs beyond the paper's claims (``results.extra_differences_markdown``): the learned reconstructor's…
LEARNED_COMPARISONS: tuple[tuple[str, str], ...] = (
    ("nerf-recon-learned", "nerf-recon"),
    ("spike-nerf-learned", "spike-nerf"),
    ("spike-nerf-learned", "nerf-recon-learned"),
)
#: … and the window-aware targets' effect
WINDOW_COMPARISONS: tuple[tuple[str, str], ...] = (
    ("nerf-recon-window", "nerf-recon"),
    ("spike-nerf-window", "spike-nerf"),
    ("spike-nerf-window", "nerf-recon-window"),
)


def label(variant: str) -> str:
    """The variant's label in tables and figures (the name itself for an unknown one)."""
    return VARIANTS[variant].label if variant in VARIANTS else variant
