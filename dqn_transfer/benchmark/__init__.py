"""The benchmark: our code against the references it replaces, side by side in one run on one machine.

Seven sections, each a module (env throughput, training against SB3, team scaling, update cost, whole
processes ``lone`` and ``replicas``, the study's ``tabular`` jobs), driven by
:mod:`~dqn_transfer.benchmark.suite` and run by ``dqn-transfer-bench``; the matched hyperparameters and
maps are in :mod:`~dqn_transfer.benchmark.config`, the table of the suite's JSON document in ``tables``.
"""
