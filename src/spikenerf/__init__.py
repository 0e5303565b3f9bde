"""spikenerf: 3D reconstruction and novel-view synthesis from spike cameras."""

__version__ = "0.1.0"
