"""Scenes: camera trajectories, the optional Blender backend, image-sequence import."""
