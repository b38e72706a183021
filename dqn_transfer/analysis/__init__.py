"""Analysis of finished runs: read run directories, compute transfer metrics and bootstrap statistics, draw figures.

Everything here reads what the trainer wrote (``metrics.jsonl``, one greedy evaluation per line:
``{"step", "team_return", "success_rate", ...}``, and the run's Hydra config), never live objects, so
it works on runs from any machine or SLURM job.

- :mod:`~dqn_transfer.analysis.runs`: run directories, their evaluations and configs;
- :mod:`~dqn_transfer.analysis.transfer_metrics`: the Taylor & Stone (2009) metrics on learning curves;
- :mod:`~dqn_transfer.analysis.stats`: the percentile bootstrap over seeds, the one place it is computed;
- :mod:`~dqn_transfer.analysis.hierarchical`: the two-stage bootstrap with maps as the unit, Holm, power;
- :mod:`~dqn_transfer.analysis.budget`: the second edition's budget rule, a cell's training steps from its pilot runs;
- :mod:`~dqn_transfer.analysis.compare`: every transfer metric of transfer runs against baseline runs;
- :mod:`~dqn_transfer.analysis.plots`: learning-curve figures (matplotlib, files only).
"""
