"""The cross-entropy method (CEM), the MPC baseline's optimiser (Appendix B).

The paper ran mbrl-lib's CEM (Pineda et al., 2021); mbrl-lib cannot be installed on the
kit's Python 3.11 (it pins hydra-core 1.0.3; notebook 07), so this is the kit's own, with
mbrl-lib's parameters and their meaning (`mbrl.planning.CEMOptimizer`):

- `iterations` rounds; each samples `population` solutions around the mean, keeps the
  `ceil(elite_ratio * population)` cheapest (the elites) and moves the mean and variance
  towards the elites' (biased) mean and variance by alpha smoothing:
  mean <- alpha mean + (1 - alpha) elite mean, and the same for the variance.
- the first variance comes from the bounds: (upper - lower)^2 / 16, i.e. a standard
  deviation of a quarter of the range.
- sampling: a normal clipped to the bounds (`clipped_normal=True`), or a normal truncated
  at two standard deviations whose variance is first shrunk so that two of them stay within
  the bounds (the default, as mbrl-lib's).
- the answer: the best solution seen in any round, or the last mean (`return_mean_elites`).

One departure: mbrl-lib replaces a NaN value by a tiny number, which can make it an elite.
Here a NaN (or infinite) cost ranks after every finite one, so it is never an elite while
any finite cost exists; if every cost of a round is non-finite, that is an error.

It minimises a cost (mbrl-lib maximises a value; same thing with the sign flipped).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass
class CEMConfig:
    iterations: int = 10         # Appendix B
    elite_ratio: float = 0.05    # Appendix B
    population: int = 250        # Appendix B
    alpha: float = 0.1           # mbrl-lib's default smoothing
    clipped_normal: bool = False   # mbrl-lib's default: truncated normal
    return_mean_elites: bool = False

    def validate(self) -> "CEMConfig":
        for name in ("iterations", "population"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"cem.{name} must be an integer >= 1, got {v!r}")
        if not (isinstance(self.elite_ratio, (int, float)) and 0 < self.elite_ratio <= 1):
            raise ValueError(f"cem.elite_ratio must be in (0, 1], got {self.elite_ratio!r}")
        if not (isinstance(self.alpha, (int, float)) and 0 <= self.alpha < 1):
            raise ValueError(f"cem.alpha must be in [0, 1), got {self.alpha!r}")
        return self

    @property
    def elites(self) -> int:
        return max(1, math.ceil(self.elite_ratio * self.population))


def truncated_normal(shape, generator: torch.Generator, limit: float = 2.0) -> torch.Tensor:
    """Standard normal samples truncated to [-limit, limit] (redrawn until inside)."""
    out = torch.randn(shape, generator=generator)
    bad = out.abs() > limit
    while bool(bad.any()):
        out[bad] = torch.randn(int(bad.sum()), generator=generator)
        bad = out.abs() > limit
    return out


def cem_minimize(cost_fn, lower: torch.Tensor, upper: torch.Tensor, cfg: CEMConfig | None = None,
                 initial: torch.Tensor | None = None, generator: torch.Generator | None = None,
                 seed: int = 0) -> tuple[torch.Tensor, float]:
    """Minimise `cost_fn(population (P, *shape)) -> costs (P,)` over the box [lower, upper]
    (tensors of one shape, e.g. (horizon, action_dim)). `initial` is the first mean
    (default: the box's middle). Returns (solution, its cost). Deterministic for a seed (or
    a given generator, whose state it advances)."""
    cfg = (cfg or CEMConfig()).validate()
    lower, upper = torch.as_tensor(lower, dtype=torch.float32), torch.as_tensor(upper, dtype=torch.float32)
    if lower.shape != upper.shape or not bool((upper > lower).all()):
        raise ValueError(f"bounds must have one shape with upper > lower everywhere, got {tuple(lower.shape)} "
                         f"and {tuple(upper.shape)}")
    mean = (lower + upper) / 2 if initial is None else torch.as_tensor(initial, dtype=torch.float32).clone()
    if mean.shape != lower.shape:
        raise ValueError(f"initial must have the bounds' shape {tuple(lower.shape)}, got {tuple(mean.shape)}")
    mean = torch.minimum(torch.maximum(mean, lower), upper)
    gen = generator if generator is not None else torch.Generator().manual_seed(int(seed))
    var = (upper - lower).square() / 16
    best, best_cost = mean.clone(), math.inf
    for _ in range(cfg.iterations):
        if cfg.clipped_normal:
            noise = torch.randn((cfg.population, *mean.shape), generator=gen)
            population = torch.minimum(torch.maximum(mean + noise * var.sqrt(), lower), upper)
        else:
            room = torch.minimum(mean - lower, upper - mean) / 2      # two std devs stay inside
            std = torch.minimum(room.square(), var).sqrt()
            population = mean + truncated_normal((cfg.population, *mean.shape), gen) * std
        costs = torch.as_tensor(cost_fn(population), dtype=torch.float32).reshape(-1)
        if costs.shape[0] != cfg.population:
            raise ValueError(f"cost_fn must return one cost per solution ({cfg.population}), got {costs.shape[0]}")
        finite = torch.isfinite(costs)
        if not bool(finite.any()):
            raise FloatingPointError(f"every cost of a CEM round is NaN or infinite ({cfg.population} solutions)")
        ranked = torch.where(finite, costs, torch.full_like(costs, math.inf))
        order = torch.argsort(ranked, stable=True)[:min(cfg.elites, int(finite.sum()))]
        elites = population[order]
        mean = cfg.alpha * mean + (1 - cfg.alpha) * elites.mean(0)
        var = cfg.alpha * var + (1 - cfg.alpha) * elites.var(0, unbiased=False)
        if float(ranked[order[0]]) < best_cost:
            best_cost, best = float(ranked[order[0]]), population[order[0]].clone()
    if cfg.return_mean_elites:
        return mean, float(torch.as_tensor(cost_fn(mean[None])).reshape(-1)[0])
    return best, best_cost


__all__ = ["CEMConfig", "cem_minimize", "truncated_normal"]
