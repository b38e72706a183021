"""What lands on disk: self-describing safetensors checkpoints (:mod:`.checkpoint`, never a pickle)
and the run directory's layout (:mod:`.run_dir`, the one place that spells its file names)."""
