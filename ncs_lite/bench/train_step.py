"""Benchmark: speed of one dSLATE training step against the machine's matmul peak.

    python -m ncs_lite bench train --out bench_train.json

For the `reduced` and `paper` widths, in fp32 and in bf16 autocast, it measures frames per
second and achieved FLOP/s of the trainer's own step (`training.train_step`: forward,
backward, gradient clipping, Adam update, as in the main phase) on synthetic videos
(without colour augmentation), and the peak FLOP/s of a large square `torch.matmul` of the
same dtype in the same run. The fraction of peak says how matmul-friendly the model's compute is. The
`paper`-width bf16 step is also measured with the forward under `torch.compile` (what
`train --compile` runs), after its compilation.

FLOPs are counted by `torch.utils.flop_counter.FlopCounterMode` (matmuls, convolutions)
plus CPU fused attention, which that counter does not know: 4*B*H*Nq*Nk*Dh per forward
and twice that per backward, halved for causal attention (only half the scores exist).
Elementwise work (softmax, layer norm, gumbel noise, Adam) is not counted: it is the
overhead that keeps a step below the matmul peak.
"""
from __future__ import annotations

import statistics
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from . import cpu_name
from ..config import get_preset
from ..models.dslate import DSlate
from ..inference import resolve_device
from ..training import build_optimizer, phases, train_step
from ..utils import package_versions, progress

__all__ = ["run", "matmul_peak", "step_flops"]

DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}


def matmul_peak(precision: str, n: int = 2048, seconds: float = 2.0, device=None) -> float:
    """Achieved FLOP/s of a loop of (n x n) @ (n x n) matmuls in `precision`."""
    device = resolve_device(device)
    a = torch.randn(n, n, device=device, dtype=DTYPES[precision])
    b = torch.randn(n, n, device=device, dtype=DTYPES[precision])
    for _ in range(3):
        a @ b
    iters, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a @ b
        iters += 1
        if device.type == "cuda":
            torch.cuda.synchronize()
    return 2.0 * n ** 3 * iters / (time.perf_counter() - t0)


def _sdpa_flops(query, key, value, dropout_p=0.0, is_causal=False, *args, out_shape=None, **kw):
    b, h, nq, d = query
    nk = key[-2]
    return 4 * b * h * nq * nk * d // (2 if is_causal else 1)


def _sdpa_bwd_flops(grad_out, query, key, value, out, lse, dropout_p=0.0, is_causal=False, *args,
                    out_shape=None, **kw):
    return 2 * _sdpa_flops(query, key, value, dropout_p, is_causal)


def _custom_flops() -> dict:
    aten = torch.ops.aten
    out = {}
    if hasattr(aten, "_scaled_dot_product_flash_attention_for_cpu"):
        out[aten._scaled_dot_product_flash_attention_for_cpu] = _sdpa_flops
        out[aten._scaled_dot_product_flash_attention_for_cpu_backward] = _sdpa_bwd_flops
    return out


def _batch(cfg, videos: int, device):
    T = cfg.train.window
    g = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (videos, T, cfg.image_size, cfg.image_size, 3), dtype=torch.uint8,
                           generator=g).to(device)
    actions = torch.randn(videos, T - 1, cfg.action_dim, generator=g).to(device)
    return frames, actions


def _step(model, opt, frames, actions, device, precision, forward=None):
    """The trainer's own step (`training.train_step`) at the first step of the config's main
    phase, where every part trains on the SLATE loss."""
    main = next(p for p in phases(model.cfg) if p.loss == "slate")
    train_step(model, opt, main, 0, frames, actions, 1.0, precision, forward=forward)
    if device.type == "cuda":
        torch.cuda.synchronize()


def step_flops(model, opt, frames, actions, device, precision) -> int:
    """FLOPs of one training step (forward + backward), counted as described above."""
    with FlopCounterMode(display=False, custom_mapping=_custom_flops()) as fc:
        _step(model, opt, frames, actions, device, precision)
    return int(fc.get_total_flops())


def run(presets=("reduced", "paper"), videos: dict | None = None, repeats: int = 5,
        device=None) -> dict:
    """Measure every (preset, precision); returns a JSON-ready dict.

    videos: videos per step for each preset (default: the preset's batch for `reduced`,
    8 videos of 5 frames for `paper` so the CPU run stays short; widths are the preset's).
    """
    device = resolve_device(device)
    videos = {"reduced": None, "paper": 8, **(videos or {})}
    peaks = {p: matmul_peak(p, device=device) for p in DTYPES}
    rows = []
    jobs = [(name, p, False) for name in presets for p in DTYPES]
    jobs += [("paper", "bf16", True)] if "paper" in presets else []
    for name, precision, compiled in progress(jobs, desc="bench train step"):
        cfg = get_preset(name)
        torch.manual_seed(0)
        model = DSlate(cfg).to(device).train()
        opt = build_optimizer(model, cfg)
        nv = videos.get(name) or cfg.train.batch_size
        frames, actions = _batch(cfg, nv, device)
        forward = torch.compile(model) if compiled else model
        for _ in range(2 if compiled else 1):                              # warm-up (+ compilation)
            _step(model, opt, frames, actions, device, precision, forward)
        flops = step_flops(model, opt, frames, actions, device, precision)  # eager: same FLOPs
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            _step(model, opt, frames, actions, device, precision, forward)
            times.append(time.perf_counter() - t0)
        t = statistics.median(times)
        n_frames = nv * cfg.train.window
        rows.append({
            "preset": name, "precision": precision, "compiled": compiled, "videos": nv, "frames_per_video": cfg.train.window,
            "step_seconds": t, "frames_per_second": n_frames / t, "step_flops": flops,
            "flops_per_second": flops / t, "matmul_peak_flops_per_second": peaks[precision],
            "fraction_of_peak": flops / t / peaks[precision],
        })
    return {"device": str(device), "cpu": cpu_name(), "cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "threads": torch.get_num_threads(), "versions": package_versions(),
            "matmul_peak_flops_per_second": peaks, "steps": rows}

