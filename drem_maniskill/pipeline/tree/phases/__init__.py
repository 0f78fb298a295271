"""The registry of extra phases of backward sampling, which run after the paper's loop, in registry order.

Each phase lives in one module: its settings dataclass, its sampling function, and its ``Phase`` record (the label
rule, the completion counter it resumes from, the phases it starts from). ``SamplerConfig.phases`` holds the settings
of the phases turned on, by name; the backward loop and the config know phases only through ``PHASES``. To add one,
write its module and register its ``Phase`` below (or ``register_phase`` it from elsewhere).

Phase ``i`` of the registry draws its children from random stream ``FIRST_STREAM + i`` (``stream_of``).
"""

from __future__ import annotations

from drem_maniskill.pipeline.tree.phases import face, goal_presses, outward, push, slide, turn, twist, wander
from drem_maniskill.pipeline.tree.phases.base import Phase, PhaseContext

# The backward loop's random stream is 0, and its colour and placement streams take the entropy words 1 and 2
# (``child_sampler.random_streams``): the phases' streams start past them.
FIRST_STREAM = 3

PHASES: dict = {}


def register_phase(phase: Phase) -> Phase:
    """Add ``phase`` to the registry (last: it runs after the others and draws from the next random stream)."""
    if phase.name in PHASES:
        raise ValueError(f"a phase named {phase.name!r} is registered already")
    if not all(r in PHASES for r in phase.requires):
        raise ValueError(f"phase {phase.name!r} requires {list(phase.requires)}; register those first")
    PHASES[phase.name] = phase
    return phase


def stream_of(name: str) -> int:
    """The random stream the phase ``name`` draws its children from."""
    return FIRST_STREAM + list(PHASES).index(name)


for _phase in (outward.PHASE, face.FACE, face.SIDE, push.PHASE, goal_presses.PHASE, turn.PHASE, twist.PHASE,
               slide.PHASE, wander.PHASE):
    register_phase(_phase)

__all__ = ["FIRST_STREAM", "PHASES", "Phase", "PhaseContext", "register_phase", "stream_of"]
