"""Imitation training: demonstrations (``dataset``), the Optax loop (``loop``),
Orbax checkpoints (``checkpoint``) and the checkpoint-trend study (``trend``)."""
