"""Training: the dataset on disk, the batches drawn from it, the task losses and their
weighting, validation and threshold calibration on held-out poses, the training loop, its log
and processes, and the jobs that run it (``fit`` from a folder, ``job`` for the UI's worker)."""
