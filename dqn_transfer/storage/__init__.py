"""What lands on disk: self-describing safetensors checkpoints (:mod:`.checkpoint`, never a pickle),
the run directory's layout (:mod:`.run_dir`, the one place that spells its file names) and how
JSON-lines files are read (:mod:`.jsonl`)."""
