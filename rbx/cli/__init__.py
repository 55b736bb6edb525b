"""The click layer: one module per command, heavy imports inside the command bodies so ``--help`` is instant."""
