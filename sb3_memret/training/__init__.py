"""Training the memory: rl-zoo-style hyperparameters (``config``), a run from set-up to its last checkpoint
(``run``) and the hyperparameter search (``tuning``)."""
