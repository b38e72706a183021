"""The study's experiments, their raw data and their report, for any edition.

An edition is data (``conf/edition/<name>.yaml``, :mod:`~dqn_transfer.experiments.edition`): its experiments
(Hydra multiruns of ``conf/experiment/``), profiles, stages, budget rule and comparison groups, analysis and
report text. The questions: a group that exchanges knowledge learns better than the same group without;
claim 1, with one treasure cooperation gives no advantage over competition; claim 2, as the team grows
deliberative > cooperative > competitive; claim 3, starting from a trained agent speeds up learning.

- :mod:`~dqn_transfer.experiments.pipeline`: the one pipeline, tune -> pilot -> budgets -> runs -> report;
- :mod:`~dqn_transfer.experiments.sweeps`: running a Hydra multirun and checking that it finished;
- :mod:`~dqn_transfer.experiments.tuning`: the tuning protocol's searches run and collected;
- :mod:`~dqn_transfer.experiments.raw_data`: every run's evaluations as compact JSON lines, and reading them back;
- :mod:`~dqn_transfer.experiments.scoring`: a run's scores, and how runs are paired and compared;
- :mod:`~dqn_transfer.experiments.settings`: what the runs were run with, from the configs stored with their data;
- the paired analysis (the first edition's): :mod:`~dqn_transfer.experiments.claims` computes each question's
  typed result (:mod:`~dqn_transfer.experiments.results`), :mod:`~dqn_transfer.experiments.render` renders it,
  :mod:`~dqn_transfer.experiments.paired_report` writes ``REPORT.md``;
- the registered hierarchical analysis (the second edition's): :mod:`~dqn_transfer.experiments.hierarchical_claims`
  and :mod:`~dqn_transfer.experiments.hierarchical_report`.

All statistics come from :mod:`dqn_transfer.analysis`.
"""
