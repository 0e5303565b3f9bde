"""Renderers: volume rendering and the spiking volume renderer."""
