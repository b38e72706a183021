"""Where a run's starting point comes from: a given checkpoint or a pretrained source
(:mod:`.resolve`), a curriculum's stages (:mod:`.curriculum`), both kept in a cache of finished runs
(:mod:`.run_cache`). They train through :mod:`dqn_transfer.training` and hand the run paths."""
