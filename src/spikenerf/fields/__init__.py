"""Radiance fields: the fast grid field and the vanilla NeRF MLP."""
