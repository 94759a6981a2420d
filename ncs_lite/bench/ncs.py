"""NCS decision latency: wall time of one `act` (perception + align + select + bind).

Measured for the oracle (ground-truth entities: the planning cost alone) and, when the
shipped dSLATE checkpoint is present, for learned NCS (slot inference with 7 iterations
included) on 4- and 7-object scenes, on mask states and on slot states (`--state slot`);
the bare `model.infer` of one image, measured in the same run, is the reference that tells
how much of a decision is perception, and the same inference with 1 to 64 restarts
(`RESTART_COUNTS`) what each restart costs.
"""
from __future__ import annotations

import time

from ..config import NCSConfig
from ..data import cached_buffer
from ..evaluation import TaskSet, agent_factory
from ..inference import SHIPPED_CHECKPOINT, load_dslate
from ..ncs.graph import graph_from_buffer
from ..ncs.perception import DSlatePerception


# slot-attention restarts whose inference time the bench also measures (ncs.perception)
RESTART_COUNTS = (1, 8, 16, 32, 64)


def _per_call(fn, n: int) -> float:
    fn()  # warm-up
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n


def run(steps: int = 50) -> dict:
    oracle_graph = graph_from_buffer(NCSConfig(clusters=30), None, cached_buffer(1000))
    ckpt = SHIPPED_CHECKPOINT
    model = load_dslate(ckpt) if ckpt.exists() else None
    learned = {}
    if model is not None:
        learned = {state: graph_from_buffer(NCSConfig(clusters=30, state=state), model, cached_buffer(200))
                   for state in ("mask", "slot")}
    out = {}
    for k in (4, 7):
        env = TaskSet(num_objects=k).make_env()
        obs, info = env.reset(seed=0)
        row = {}
        agent = agent_factory("ncs-oracle", graph=oracle_graph)(env)
        agent.reset(obs, info)
        row["oracle_ms_per_decision"] = 1e3 * _per_call(lambda: agent.act(obs, info), steps)
        for state, graph in learned.items():
            agent = agent_factory("ncs", graph=graph, model=model, ncs=NCSConfig(state=state))(env)
            agent.reset(obs, info)
            key = "ncs_ms_per_decision" if state == "mask" else "ncs_slot_ms_per_decision"
            row[key] = 1e3 * _per_call(lambda: agent.act(obs, info), steps)
        if model is not None:
            # the agent's own slot inference (7 iterations, its restarts), one image
            row["slot_inference_ms"] = 1e3 * _per_call(lambda: agent.perception.current(obs), steps)
            row["restarts"] = agent.perception.restarts
            row["perception_share"] = row["slot_inference_ms"] / row["ncs_ms_per_decision"]
            for r in RESTART_COUNTS:   # what a restart costs, for choosing how many
                read = DSlatePerception(model, num_slots=agent.perception.num_slots, restarts=r)
                row[f"slot_inference_ms_r{r}"] = 1e3 * _per_call(lambda: read.current(obs), steps)
        out[f"{k}_objects"] = {key: round(v, 3) for key, v in row.items()}
        env.close()
    if model is None:
        out["note"] = f"no checkpoint at {ckpt}: learned NCS not measured"
    return out
