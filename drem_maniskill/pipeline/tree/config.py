"""``SamplerConfig``: the paper's backward-sampling settings, and the settings of every extra phase by name.

Its dict form (``to_dict``, ``from_dict``; recipes' ``[sampler]``, tree headers) holds the core fields at the top and
``phases`` by name, ``{"num_children": 500, "phases": {"face": {"depth": 8, "step": 0.0015}}}``. ``phases`` always
holds every registered phase; one runs when its size field (``depth``, ``children`` or ``count``, ``Phase.size``) is
above 0, and the defaults have them all at 0: the paper's sampler.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

from drem_maniskill.pipeline.tree.phases import PHASES

PRESETS = {"paper": {}, "quick": dict(num_children=24), "tiny": dict(num_children=4, max_depth=40)}
# A run that gave up at max_depth resumes with a larger one; one sampled with 1 worker process goes on with 2 (a
# child's step differs between worker layouts only by the sibling before it in PhysX's contact cache, 0.03-0.11 N).
RESUMABLE_FIELDS = ("max_depth", "workers")


@dataclass
class SamplerConfig:
    """Backward-sampling hyper-parameters; defaults are the paper's (M = 500, N = 1), with no extra phase."""

    num_children: int = 500
    """M: random actions applied to each seed state."""
    num_seeds: int = 1
    """N: seeds kept per depth (the paper's expert-guided measure uses 1)."""
    delta: float = 0.5
    """Stop when at least ceil(N * delta) seeds are in the start region."""
    max_depth: int = 0
    """Fail (resumably) when the start region is not reached by this depth; 0: the larger of 80 and twice the demo's
    length (the measure walks back one demo step per depth, so a longer demo needs a deeper tree)."""
    action_scale: float = 1.0
    """Random arm actions are uniform in [-action_scale, action_scale] (normalised); gripper ones always in [-1, 1]."""
    expert_step_scale: float = 0.0
    """When > 0, the arm actions at each depth span this many times the expert's own step there, clipped to
    [min_action_scale, action_scale]: fine where the expert moves slowly, the whole range where it moves fast."""
    even_path: bool = False
    """The progress measure walks the demo's end-effector path in equal steps of about the demo's median step,
    not at the demo's own pace (beyond the paper): a stretch the demo crossed in a few long steps (a fast final push)
    gets as many depths per centimetre as the rest, so the reward keeps rising there."""
    graded_path: float = 0.0
    """With ``even_path``, when > 0: near the goal each step of the walked path is this fraction of the path still
    left to the goal, between ``graded_finest`` times the demo's median step and the median step (beyond the paper):
    the depths crowd toward the goal, so the reward pays the last centimetres (a part at a socket's mouth against one
    in it) more than an even path does."""
    graded_finest: float = 0.25
    """The finest step of ``graded_path``, as a fraction of the demo's median step."""
    min_action_scale: float = 0.05
    """The smallest arm action range (``expert_step_scale``, and the lineage phases' steps)."""
    rotation_weight: float = 0.05
    """Metres per radian when comparing end-effector poses with the expert's."""
    seed: int = 0
    """Seed of every random stream."""
    episode: int = 0
    """Which episode of the expert file to use."""
    workers: int = 1
    """Worker processes, each with its own env (children of one seed are split among them)."""
    gripper_weight: float = 1.0
    """Metres per metre of finger opening when comparing with the expert (robots with a gripper)."""
    start_radius: float = 0.03
    """Envs without a start-region predicate: within this distance of the expert's first TCP position."""
    randomize_colors: bool = True
    """Each child gets freshly drawn part and socket colours (tasks that have them), as every reset of the task does:
    the image encoder must not learn one colour pair."""
    randomize_placement: bool = True
    """Each child's scene is moved as a whole to a freshly drawn socket placement (our tasks; not in the paper, whose
    hole stays put): a tree of one placement teaches a reward that reads where the socket is."""
    seeds_from_demo: bool = False
    """Each depth's children start from the demo's own state that many steps before the goal, not from the chosen
    child (``N = 1`` only; beyond the paper): the objects stay where the demo had them. For tasks whose random
    actions cannot carry an object back (a pushed cube stays at the goal), where the paper's chain holds only the
    hand's progress."""
    images: bool = True
    """Render the cameras at every node. False: a tree for a model that reads no camera (``poses`` alone, beyond the
    paper), sampled without rendering, many times faster on the CPU; the demo's own images are kept."""
    phases: dict = field(default_factory=dict)
    """Settings of every extra phase by name (``phases.PHASES``); a phase runs when its size field is above 0."""

    def __post_init__(self):
        if self.max_depth < 0:
            raise ValueError(f"max_depth must be >= 0 (0: from the demo's length), got {self.max_depth}")
        if self.seeds_from_demo and self.num_seeds != 1:
            raise ValueError(f"seeds_from_demo keeps one seed per depth, the demo's state; got num_seeds="
                             f"{self.num_seeds}: set num_seeds to 1 or turn seeds_from_demo off")
        if self.seeds_from_demo and self.even_path:
            raise ValueError("seeds_from_demo starts each depth from the demo's own recorded state, which even_path's "
                             "interpolated poses do not have: turn one of them off")
        if self.graded_path > 0 and not self.even_path:
            raise ValueError("graded_path grades the path even_path walks: turn even_path on too")
        if not 0 < self.graded_finest <= 1:
            raise ValueError(f"graded_finest is a fraction of the demo's median step, in (0, 1]; got "
                             f"{self.graded_finest}")
        unknown = [name for name in self.phases if name not in PHASES]
        if unknown:
            raise ValueError(f"unknown sampler phase {unknown[0]!r}; valid ones: {list(PHASES)}")
        settings = {name: _phase_settings(name, self.phases.get(name, {})) for name in PHASES}
        # A phase that is off has its defaults: its other settings change nothing, so they never tell configs apart.
        self.phases = {name: s if PHASES[name].is_on(s) else PHASES[name].config() for name, s in settings.items()}

    def depth_limit(self, demo_steps: int) -> int:
        """The depth at which sampling gives up, for a demo of ``demo_steps`` steps (``max_depth``, or its rule)."""
        return self.max_depth if self.max_depth > 0 else max(80, 2 * int(demo_steps))

    def phases_on(self) -> dict:
        """The settings of the phases that run, by name, in the order they run."""
        return {name: s for name, s in self.phases.items() if PHASES[name].is_on(s)}

    @classmethod
    def from_dict(cls, d: dict) -> "SamplerConfig":
        """A config from its dict form; an unknown key is a ValueError naming it and the valid ones."""
        core = [f.name for f in fields(cls) if f.name != "phases"]
        unknown = [key for key in d if key not in core and key != "phases"]
        if unknown:
            raise ValueError(f"unknown sampler setting {unknown[0]!r}; valid ones: {core + ['phases']}, a phase's "
                             f"settings under phases.<name> (e.g. phases.face.depth; phases: {list(PHASES)})")
        phases = {name: value if isinstance(value, dict) else asdict(value)
                  for name, value in (d.get("phases") or {}).items()}
        return cls(**{k: d[k] for k in core if k in d}, phases=phases)

    def to_dict(self) -> dict:
        """The nested form, JSON-ready: every phase, in the order they run."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "phases"}
        out["phases"] = {name: _jsonable(asdict(s)) for name, s in self.phases.items()}
        return out

    @classmethod
    def preset(cls, name: str, **overrides) -> "SamplerConfig":
        """``paper`` (M = 500), ``quick`` (M = 24, for minutes-long runs) or ``tiny``, with ``overrides`` (any key
        ``from_dict`` reads; ``phases`` by name)."""
        if name not in PRESETS:
            raise ValueError(f"unknown sampler preset {name!r}; choose one of {list(PRESETS)}")
        return cls.from_dict({**PRESETS[name], **overrides})

    def can_resume(self, saved: "SamplerConfig") -> bool:
        """Whether a partial tree sampled under ``saved`` goes on under this config: the same but for
        ``RESUMABLE_FIELDS``, or a tree gaining a growable phase; a growable phase once on only as it was."""
        for name, phase in PHASES.items():
            if phase.growable and name in saved.phases_on() and saved.phases[name] != self.phases.get(name):
                return False

        def fixed(c: SamplerConfig) -> tuple:
            """What must match: the core settings but ``RESUMABLE_FIELDS``, and the phases that cannot grow."""
            core = {k: v for k, v in c.to_dict().items() if k not in RESUMABLE_FIELDS + ("phases",)}
            return core, {n: s for n, s in c.phases.items() if not PHASES[n].growable}

        return fixed(saved) == fixed(self)


def _phase_settings(name: str, value: Any):
    """The settings dataclass of phase ``name`` from a dict (or the dataclass itself)."""
    cls = PHASES[name].config
    if isinstance(value, cls):
        return value
    valid = {f.name: f for f in fields(cls)}
    unknown = [k for k in value if k not in valid]
    if unknown:
        raise ValueError(f"unknown setting {unknown[0]!r} of sampler phase {name!r}; valid ones: {list(valid)}")
    # Lists (JSON, TOML) become the tuples the settings declare.
    return cls(**{k: tuple(v) if isinstance(valid[k].default, tuple) else v for k, v in value.items()})


def _jsonable(d: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}
