"""The bottom layer: ManiSkill shims, the file cache, camera images, state (un)flattening, episode lengths,
progress bars.

Nothing here imports another part of the package (``tests/test_layers.py`` checks it).
"""
