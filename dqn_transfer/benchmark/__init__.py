"""The benchmark: our code against the references it replaces, side by side in one run on one machine.

Seven measurements, driven by :mod:`dqn_transfer.benchmark.suite` (the command line is
``dqn-transfer-bench`` / ``python -m dqn_transfer.cli.bench``):

1. :mod:`~dqn_transfer.benchmark.env_throughput`: joint steps/s of random play through the PettingZoo
   ``ParallelEnv`` API and through the numpy core the trainer drives, 1, 4 and 8 agents.
2. :mod:`~dqn_transfer.benchmark.training`: DQN training steps/s on ``TreasureHunt-v0``, our ``Trainer``
   against Stable-Baselines3 ``DQN`` with matched hyperparameters.
3. :mod:`~dqn_transfer.benchmark.team_scaling`: per-step cost as the team grows, one batched learner
   for K agents against K separate single-agent learners.
4. :mod:`~dqn_transfer.benchmark.update_cost`: time per gradient update, ``DQNLearner.gradient_step``
   against bare PyTorch updates and SB3's ``DQN.train``.
5. :mod:`~dqn_transfer.benchmark.whole_process` (``lone``): whole processes, spawn to exit, of one DQN
   learner: ``python -m dqn_transfer.cli.train`` against SB3's ``DQN.learn`` and a CleanRL-style
   bare-PyTorch loop (the two reference programs are :mod:`~dqn_transfer.benchmark.processes`).
6. :mod:`~dqn_transfer.benchmark.whole_process` (``replicas``): sweep throughput, one process of R
   replicas of a 4-agent team against SB3 one learner per process, one process per core.
7. :mod:`~dqn_transfer.benchmark.tabular_batches` (``tabular``): the study's tabular jobs, R replicas
   of a SARSA team, marginal cost per step, this checkout against an earlier one (``--baseline DIR``).

The matched hyperparameters and maps are in :mod:`~dqn_transfer.benchmark.config`; the method (interleaved
repeats, paired ratios, two clocks, threads) is described in :mod:`~dqn_transfer.benchmark.suite`.
"""
