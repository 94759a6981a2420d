"""Shared test setup: tests that compare numbers run on one thread, where torch's reductions
are bit-reproducible (another thread count changes the floating-point order)."""
import torch

torch.set_num_threads(1)
