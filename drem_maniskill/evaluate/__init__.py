"""Judging a DREM reward: does it order progress, and does it pay only for progress?

* ``examine.examine``: the examination (the paper's four scripted policies and the probes) -> ``quality.json`` and
  ``examination.png``; ``measures``, ``probes`` (one table of the places the part is held at), ``scene_swap``,
  ``quality`` (the file's measures), ``plot`` (the paper's Fig. 4);
* ``targets``: what each measure should reach, as the model cards' tables;
* ``check_reward.check_reward``: ``check-reward``, a short SAC run on the reward and where its failures end.

Judging reads a checkpoint and rolls policies out; it builds nothing. Building (``drem_maniskill.pipeline``) calls it:
a build examines its reward.
"""
