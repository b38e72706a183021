"""The study's experiments and its reproduction report.

The study claims three things, each tested by one experiment (a Hydra multirun of
``conf/experiment/<name>.yaml``):

1. one treasure: cooperation gives no advantage over competition (``fig1``);
2. complex map, growing team: deliberative > cooperative > competitive (``fig2``);
3. transfer from a trained agent speeds up learning (``transfer``).

- :mod:`~dqn_transfer.experiments.sweeps`: profiles (how many seeds and steps), the sweeps' overrides,
  running a multirun and checking that it finished;
- :mod:`~dqn_transfer.experiments.team_maps`: Figure 2's maps, one map for every team size;
- :mod:`~dqn_transfer.experiments.claims`: one report section per claim, with its verdict rule;
- :mod:`~dqn_transfer.experiments.report`: ``OUT/REPORT.md`` from the sections.

All numbers and figures come from :mod:`dqn_transfer.analysis`.
"""
