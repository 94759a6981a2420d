"""ncs-lite: a teaching and reproduction kit for Neural Constraint Satisfaction.

Chang, Dayan, Meier, Griffiths, Levine, Zhang, "Neural Constraint Satisfaction:
Hierarchical Abstraction for Combinatorial Generalization in Object Rearrangement",
ICLR 2023 (arXiv 2303.11373). The stages live in one subpackage each:

    envs/        the environments of Appendix C (gymnasium)
    data/        the experience buffer of random video demonstrations
    models/      dSLATE: dVAE, slot attention, transformer decoder, dynamics
    training.py  training dSLATE, `obtain_dslate`; inference.py: `load_dslate`
    ncs/         k-means, the transition graph (isolate, cluster, bind), the agent
    baselines/   the methods NCS is compared with (Appendix B)
    evaluation.py  the seeded task sets and success statistics every method shares
    figures.py   save_fig and plotting helpers for the notebooks
    bench/       `python -m ncs_lite bench ...` benchmarks

A module imports only modules of its own layer or lower ones, never in a cycle: utils, cache
and the like; config; envs, data, models; inference; ncs, baselines, training; evaluation,
metrics; comparison, tables, docs; stress, hyperparameters; reproduce and the other entry
points; the command line (tests/test_imports.py holds the layers and checks them).
"""
__version__ = "0.1.0"

from .envs.headless import choose_gl as _choose_gl

_choose_gl()   # MuJoCo's headless backend, before anything imports MuJoCo


def __getattr__(name):
    if name in ("load_dslate", "SHIPPED_CHECKPOINT"):
        from . import inference  # local: `import ncs_lite` loads no torch for users of the environments alone

        return getattr(inference, name)
    raise AttributeError(f"module 'ncs_lite' has no attribute {name!r}")
