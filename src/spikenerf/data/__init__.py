"""Dataset folder I/O, the simulate pipeline, rays, training targets and samplers."""
