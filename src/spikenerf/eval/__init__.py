"""Evaluation: image metrics and metrics.json."""
