"""Test-session set-up. Without CUDA, Triton kernels (``fields/vm_triton.py``) run in Triton's CPU
interpreter: ``TRITON_INTERPRET`` must be set before anything imports ``triton`` (``torch.compile`` may), so
it is set here, first. Where a CUDA device is present nothing changes and the tests run the compiled
kernels. ``fresh_dynamo``: a test module that counts compiled graphs starts each test from an empty Dynamo
cache (``pytestmark = pytest.mark.usefixtures("fresh_dynamo")``). ``ieee_subnormals``: every test."""

import os

import pytest
import torch

if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")


@pytest.fixture
def fresh_dynamo():  # type: ignore[no-untyped-def]
    """An empty Dynamo cache and graph counters before and after the test."""
    from torch._dynamo.utils import counters

    torch._dynamo.reset()
    counters.clear()
    yield
    torch._dynamo.reset()


@pytest.fixture(autouse=True)
def ieee_subnormals():  # type: ignore[no-untyped-def]
    """Subnormal floats on again after each test: before torch 2.6 the first library Inductor builds on a
    CPU (linked with -ffast-math) sets flush-to-zero for the process, which Hypothesis's floats refuse."""
    yield
    torch.set_flush_denormal(False)
