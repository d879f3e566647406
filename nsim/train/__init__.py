"""Training loops (the cores the ``train_*`` stages call)."""
