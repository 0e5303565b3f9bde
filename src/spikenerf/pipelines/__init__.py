"""Pipelines composed of all layers: demo, benchmark tables, HTML report."""
