"""Making a dataset from a real recording (``spikenerf import``): a raw ``.dat`` plus poses from a file, an
orbit or COLMAP, interpolated to every step and normalised into a dataset folder (docs/real-data.md)."""
