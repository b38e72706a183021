"""The study's experiments, their raw data and their report.

The study's questions, each answered by experiments (Hydra multiruns of ``conf/experiment/<name>.yaml``):

- the main hypothesis, a group that exchanges knowledge learns better than the same group without
  (``hypothesis``, ``hypothesis_shared``);
- claim 1, with one treasure cooperation gives no advantage over competition (``claim1``);
- claim 2, as the team grows deliberative > cooperative > competitive (``claim2``);
- claim 3, starting from a trained agent speeds up learning (``transfer``).

- :mod:`~dqn_transfer.experiments.sweeps`: profiles (quick / full), the sweeps' overrides, running a
  multirun and checking that it finished;
- :mod:`~dqn_transfer.experiments.raw_data`: every run's evaluations as compact JSON lines, and reading them back;
- :mod:`~dqn_transfer.experiments.scoring`: a run's scores, and how runs are paired and compared;
- :mod:`~dqn_transfer.experiments.settings`: what the runs were run with, from the configs stored with their data;
- :mod:`~dqn_transfer.experiments.claims`: each question's typed result (:mod:`~dqn_transfer.experiments.results`)
  computed from its raw data, with its primary comparison and verdict (the first edition's rules:
  ``results/v1/VERDICT_RULES.md``);
- :mod:`~dqn_transfer.experiments.render`: the renderer, a result to its Markdown and figures;
- :mod:`~dqn_transfer.experiments.report`: ``REPORT.md`` and its figures from the raw data alone.

All statistics come from :mod:`dqn_transfer.analysis`.
"""
