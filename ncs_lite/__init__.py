"""ncs-lite: a teaching and reproduction kit for Neural Constraint Satisfaction.

Chang, Dayan, Meier, Griffiths, Levine, Zhang, "Neural Constraint Satisfaction:
Hierarchical Abstraction for Combinatorial Generalization in Object Rearrangement",
ICLR 2023 (arXiv 2303.11373). The stages live in one subpackage each:

    envs/        the environments of Appendix C (gymnasium)
    data/        the experience buffer of random video demonstrations
    figures.py   save_fig and plotting helpers for the notebooks
    bench/       `python -m ncs_lite bench ...` benchmarks
"""
__version__ = "0.1.0"
