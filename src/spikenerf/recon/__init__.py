"""A learned spike-to-image reconstructor: training pairs, the network, training and tiled inference.

Sits between ``scenes`` (it renders its own training scenes) and ``data`` (whose targets can use it).
See docs/reconstruction.md.
"""
