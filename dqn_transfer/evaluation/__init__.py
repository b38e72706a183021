"""Greedy episodes: the one episode loop (:mod:`.rollout`) and episodes recorded frame by frame for a
GIF, the terminal or TensorBoard (:mod:`.watch`)."""
