"""The training loop (:mod:`.trainer`: act, step, learn, evaluate, checkpoint, resume, for one run or
a batch of replicas) and its TensorBoard writer (:mod:`.tensorboard`)."""
