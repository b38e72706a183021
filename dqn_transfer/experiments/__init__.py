"""The study's experiments, their raw data and their report, for any edition.

An edition is data (``conf/edition/<name>.yaml``, :mod:`~dqn_transfer.experiments.edition`) that
:mod:`~dqn_transfer.experiments.pipeline` runs: tune -> pilot -> budgets -> runs -> report. The first edition's
paired analysis is :mod:`~dqn_transfer.experiments.claims` (rendered by :mod:`~dqn_transfer.experiments.render`);
the second's registered hierarchical one is :mod:`~dqn_transfer.experiments.hierarchical_claims`. All statistics
come from :mod:`dqn_transfer.analysis`.
"""
