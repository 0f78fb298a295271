"""The runtime DREM reward: model, fast encoder, ``DREMReward``, checkpoints, the ``drem`` reward mode, the wrapper.

The offline chain that makes a checkpoint (backward sampling, training, examination) is
``drem_maniskill.pipeline``.
"""
