"""Knowledge moved between agents: the segment-by-name mapping of weights and Q-tables
(:mod:`.mapping`), the warm start from a source checkpoint (:mod:`.warm_start`) and a team's
exchange during training (:mod:`.exchange`). Where a source comes from is :mod:`dqn_transfer.sources`."""
