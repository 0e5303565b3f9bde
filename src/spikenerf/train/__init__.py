"""Training: losses, methods, trainer and checkpoints."""
