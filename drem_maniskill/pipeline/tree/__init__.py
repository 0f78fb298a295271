"""The task progress tree: backward sampling from an expert demo into one HDF5 file.

* ``expert``: the demo as DREM reads it (``load_expert``; observations and env states, never actions);
* ``child_sampler``: the env driver (``ChildSampler``) and its worker processes (``ChildPool``);
* ``tree_file``: the file's layout, its writing, resuming and reading;
* ``backward``: the paper's loop (Section III-A) and ``backward_sample``, which then runs the phases turned on;
* ``phases``: the registry of named extra phases (outward, face, side, push, goal_presses, turn);
* ``config``: ``SamplerConfig``, the core settings and the phases' settings by name.
"""
