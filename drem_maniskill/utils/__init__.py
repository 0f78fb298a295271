"""The bottom layer: ManiSkill shims, the file cache, camera images, state (un)flattening, episode lengths.

Nothing here imports another part of the package (``tests/test_layers.py`` checks it).
"""
