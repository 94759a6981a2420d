"""The paper's experiments, each a table under `figures/tables/` written by a command:

  comparison       the main comparison (every method on the same seeded tasks, Table 1's
                   shape) and the assets it reads
  stress           Appendix D's stress tests: Fig. 10 (action noise) and Fig. 11 (horizon)
  hyperparameters  Appendix D's Fig. 9 (graph size and isolate's threshold)
  tables           writing a table (CSV + JSON with its provenance)
  reproduce        `python -m ncs_lite reproduce TABLE`: the seeds, clusters, baselines,
                   per-environment and appendix tables
"""
