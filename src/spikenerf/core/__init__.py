"""Lowest layer: errors, colour transforms, atomic file writes and device selection (no other imports)."""
