"""The evaluation's typed choices and defaults, defined once, without importing torch (the CLI's ``eval``
and ``export`` choices, and the defaults their ``--help`` shows)."""

from __future__ import annotations

from typing import Literal, get_args

#: the views a run is scored on: held-out novel views, or the sharp GT along the training path
Split = Literal["test", "train"]
SPLITS: tuple[str, ...] = get_args(Split)
#: when the no-reference checks run (auto: for imported datasets)
NorefMode = Literal["auto", "on", "off"]
NOREF_MODES: tuple[str, ...] = get_args(NorefMode)
#: what ``export`` writes: coloured points of the rendered views, or a marching-cubes mesh of the density
ExportKind = Literal["pointcloud", "mesh"]
EXPORT_KINDS: tuple[str, ...] = get_args(ExportKind)
#: ``export``: a point cloud keeps the pixels whose accumulated opacity exceeds this
DEFAULT_MIN_OPACITY = 0.5
#: ``export``: a mesh's lattice, points a side over the scene box
DEFAULT_RESOLUTION = 128
#: ``export``: a mesh's surface, the density (per world unit) of its level set (see ``eval/export.py``)
DEFAULT_DENSITY_LEVEL = 25.0
#: the LPIPS networks whose weights ``eval/lpips.py`` reads (``none`` on the CLI skips LPIPS)
LpipsBackbone = Literal["alex", "vgg"]
LPIPS_BACKBONES: tuple[str, ...] = get_args(LpipsBackbone)
