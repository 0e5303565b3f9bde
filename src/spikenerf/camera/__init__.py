"""The spike camera: integrate-and-fire model, noise, .dat I/O, reconstruction (TFP/TFI) and spike masks."""
