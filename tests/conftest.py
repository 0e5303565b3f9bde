"""Test-session set-up. Without CUDA, Triton kernels (``fields/vm_triton.py``) run in Triton's CPU
interpreter: ``TRITON_INTERPRET`` must be set before anything imports ``triton`` (``torch.compile`` may), so
it is set here, first. Where a CUDA device is present nothing changes and the tests run the compiled
kernels."""

import os

import torch

if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")
