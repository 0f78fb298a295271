"""A task's DREM recipe: every setting that makes its reward, as data (``tasks/<id>/recipe.toml``).

A task's folder (its recipe and committed demo) is ``tasks/<id>/`` in a checkout, else the copy a wheel installs
under ``<prefix>/share/drem-maniskill/tasks/<id>/`` (``TASKS_DIRS``, ``task_folder``).

Sections (each optional; what is left out takes the defaults below or the config classes' own):

* ``[demo]``: the expert demo. ``expert`` names a committed demo beside the recipe (``expert.h5``, its
  ``.json`` beside it); without one, or when that file is missing, ``record-expert`` records ``episodes``
  episodes from ``seed`` with ``descent_step`` / ``descend_from`` (our tasks' expert) and ``env_kwargs``.
  ``trees`` (1, the paper's one demo): how many of its episodes are sampled into a progress tree each and trained on
  together, toward the first episode's goal; more than one teaches a task whose reset moves its objects.
* ``[sampler]``: ``SamplerConfig`` in its nested form, the extra phases under ``[sampler.phases.<name>]``.
* ``[train]``: ``TrainConfig`` fields, the model's under ``[train.model]`` (``ModelConfig``); without
  ``modalities`` the model reads every modality the tree holds.
* ``[image_twin]``: ``enabled`` trains the image-only twin ``drem_image.pt`` on the same tree with ``modalities``.
* ``[scene_swap]``: ``negatives`` (beyond the paper) adds, for every demo episode sampled into a tree, the scenes with
  the robot at one depth of the demo and every other body at a deeper one, labelled by the objects' depth
  (``pipeline.scene_swap.swap_negatives``; ``lag``, ``max_pairs``), to the training set and the policy rounds'.
* ``[examine]``: the held-out seeds ``first_seed`` .. ``first_seed + episodes - 1``.
* ``[calibrate]``: ``enabled`` writes the support guard's thresholds ``support.json`` (``quantile``).
* ``[rounds]``: ``RoundsConfig`` (``pipeline.policy_rounds``): policy rounds of hard negatives after training;
  ``rounds = 0`` (the default) trains as the paper does.
* ``[scales.<name>]``: the same sections again, merged over the recipe for a smaller run (``tiny``: a test's
  minute; ``demo``: ``make demo``). The scale ``full`` is the recipe as written.
"""

from __future__ import annotations

import copy
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Optional, Union

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

# The tasks' folders: beside the package in a checkout; a wheel installs them as data files under
# <prefix>/share/drem-maniskill/tasks (pyproject's data-files), as it does the shipped rewards.
TASKS_DIRS = (Path(__file__).resolve().parents[2] / "tasks",
              Path(sys.prefix) / "share" / "drem-maniskill" / "tasks")
FULL = "full"
DICT = "<dict>"
GENERAL = "default"
"""The recipe of a task without a recipe file (``GENERAL_DEFAULTS``); as ``recipe``, it builds any task."""

# Section -> its keys and their defaults (None: no default, the key may be left out).
SECTION_DEFAULTS = {
    "demo": dict(expert=None, seed=1000, episodes=1, trees=1, descent_step=None, descend_from=None, env_kwargs={}),
    "image_twin": dict(enabled=False, modalities=["fixed", "wrist"]),
    "scene_swap": dict(negatives=False, lag=4, max_pairs=500),
    "examine": dict(first_seed=0, episodes=20),
    "calibrate": dict(enabled=True, quantile=None),
}
SECTIONS = ("demo", "sampler", "scene_swap", "train", "rounds", "image_twin", "examine", "calibrate")

# A task without a recipe file: one demo recorded at the expert's own speed, the paper's sampler at M = 100 with
# settings derived from the demo alone (random actions spanning four times the expert's step at each depth; the demo's
# path walked in even steps of its median step, so a fast stretch leaves no gap in progress; twelve lineages from the
# start region outward in world directions, level and downward, so a part pressed down beside its socket is a state
# the tree holds, not one the reward guesses at), 20,000 iterations at 64 px. Nothing in it reads the task's geometry.
GENERAL_DEFAULTS = {
    "sampler": {"num_children": 100, "expert_step_scale": 4.0, "even_path": True,
                "phases": {"outward": {"depth": 10, "lineages": 12, "children": 100}}},
    "train": {"iterations": 20_000, "pairs_per_batch": 16, "threads": 1, "model": {"image_size": 64}},
    "scales": {
        "tiny": {"sampler": {"num_children": 4, "max_depth": 60,
                             "phases": {"outward": {"depth": 1, "lineages": 2, "children": 2}}},
                 "train": {"iterations": 50, "pairs_per_batch": 8}, "examine": {"episodes": 1}},
        "demo": {"sampler": {"num_children": 24, "phases": {"outward": {"depth": 0}}}, "train": {"iterations": 500},
                 "examine": {"episodes": 3}},
    },
}


class RecipeError(ValueError):
    """A recipe is missing, unreadable, or holds a key or value its section does not take."""


@dataclass(frozen=True)
class Recipe:
    """One task's recipe at one scale, validated and merged; ``source`` is its file (or ``default``)."""

    task: str
    scale: str
    source: str
    demo: dict
    sampler: dict
    scene_swap: dict
    train: dict
    rounds: dict
    image_twin: dict
    examine: dict
    calibrate: dict

    def sampler_config(self, **overrides):
        """The ``SamplerConfig`` of ``[sampler]`` (``overrides``: top-level fields, e.g. ``seed``)."""
        from drem_maniskill.pipeline.tree.config import SamplerConfig

        return SamplerConfig.from_dict({**self.sampler, **overrides})

    def train_config(self, modalities: Optional[Any] = None, **overrides):
        """The ``TrainConfig`` of ``[train]``; ``modalities`` replaces the model's (the image twin's, the tree's)."""
        from drem_maniskill.drem.model import ModelConfig
        from drem_maniskill.pipeline.train_reward import TrainConfig

        fields = {k: v for k, v in self.train.items() if k != "model"}
        model = dict(self.train.get("model", {}))
        if modalities is not None:
            model["modalities"] = tuple(modalities)
        return TrainConfig(**{**fields, **overrides, "model": ModelConfig(**model)})

    def rounds_config(self):
        """The ``RoundsConfig`` of ``[rounds]``."""
        from drem_maniskill.pipeline.policy_rounds import RoundsConfig

        return RoundsConfig(**self.rounds)

    def expert_file(self) -> Optional[Path]:
        """The committed demo ``[demo] expert`` names, beside the recipe (a dict's: in the task's folder), or None."""
        name = self.demo.get("expert")
        if not name:
            return None
        folder = task_folder(self.task) if self.source in (GENERAL, DICT) else Path(self.source).parent
        return folder / name

    def exam_seeds(self) -> range:
        """The held-out seeds the examination runs on."""
        return range(self.examine["first_seed"], self.examine["first_seed"] + self.examine["episodes"])

    def to_dict(self) -> dict:
        """The recipe as plain data (what ``build_reward`` records beside its outputs)."""
        return {k: v for k, v in asdict(self).items() if k not in ("source",)}


def task_folder(task: str) -> Path:
    """The folder of ``task``'s recipe and demo: the first of ``TASKS_DIRS`` that holds one, else the checkout's."""
    for folder in TASKS_DIRS:
        if (folder / task).is_dir():
            return folder / task
    return TASKS_DIRS[0] / task


def recipe_path(task: str) -> Path:
    """Where the recipe of ``task`` lives: ``recipe.toml`` in its folder (``tasks/<task>/``)."""
    return task_folder(task) / "recipe.toml"


def load_recipe(task: str, scale: str = FULL, recipe: Union[str, Path, dict, None] = None) -> Recipe:
    """The recipe of ``task`` at ``scale``; ``recipe``: a file, ``"default"``, a dict, or None (the task's own file, or
    the general recipe where the task has none)."""
    if isinstance(recipe, dict):
        raw, source = copy.deepcopy(recipe), DICT
    elif (recipe is not None and str(recipe) == GENERAL) or (recipe is None and not recipe_path(task).is_file()):
        raw, source = copy.deepcopy(GENERAL_DEFAULTS), GENERAL
    else:
        path = Path(recipe) if recipe is not None else recipe_path(task)
        raw, source = read_toml(path, task), str(path)
    return resolve(raw, task, scale, source)


def read_toml(path: Path, task: str) -> dict:
    """Parse a recipe file, with an error that says how to write one when it is missing."""
    if not path.is_file():
        raise RecipeError(
            f"no DREM recipe at {path}: the file does not exist. Name an existing recipe file, or leave --recipe out "
            f"to build {task} with its own recipe or, where it has none, the general one ({GENERAL!r})")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as err:
        raise RecipeError(f"{path} is not valid TOML: {err}") from err


def resolve(raw: dict, task: str, scale: str, source: str) -> Recipe:
    """Validate ``raw`` (a parsed recipe), merge its ``scale`` over it and fill in the sections' defaults."""
    raw = copy.deepcopy(raw)
    scales = raw.pop("scales", {})
    check_sections(raw, source)
    if not isinstance(scales, dict):
        raise RecipeError(f"{source}: [scales] must be a table of scale names, got {scales!r}")
    for name, table in scales.items():
        check_sections(table, f"{source} [scales.{name}]")
    if scale != FULL and scale not in scales:
        raise RecipeError(f"{source} has no scale {scale!r}; its scales: {[FULL, *scales]}")
    merged = merge(raw, scales.get(scale, {}))
    sections = {name: {**SECTION_DEFAULTS.get(name, {}), **merged.get(name, {})} for name in SECTIONS}
    sections["train"].setdefault("model", {})
    recipe = Recipe(task=task, scale=scale, source=source, **sections)
    trees, episodes = sections["demo"]["trees"], sections["demo"]["episodes"]
    if trees < 1 or trees > episodes:  # a committed demo with fewer episodes is refused when its tree is sampled
        raise RecipeError(f"{source} (scale {scale}): [demo] trees = {trees} needs 1 <= trees <= episodes "
                          f"(= {episodes}): one progress tree per demo episode")
    read = [*(sections["train"]["model"].get("modalities") or []),
            *(sections["image_twin"]["modalities"] if sections["image_twin"]["enabled"] else [])]
    if not sections["sampler"].get("images", True) and set(read) & {"fixed", "wrist"}:
        raise RecipeError(f"{source} (scale {scale}): [sampler] images = false samples no camera images, but the "
                          f"models read {sorted(set(read) & {'fixed', 'wrist'})}: read poses only, or sample images")
    try:  # the config classes check the values (a modality's name, an image size), once here for every scale
        recipe.sampler_config()
        recipe.train_config()
        recipe.train_config(modalities=recipe.image_twin["modalities"])
        recipe.rounds_config()
    except (TypeError, ValueError) as err:
        raise RecipeError(f"{source} (scale {scale}): {err}") from err
    return recipe


def check_sections(table: dict, where: str) -> None:
    """Raise ``RecipeError`` naming ``where``, the bad key and the valid ones, for anything a section does not take."""
    if not isinstance(table, dict):
        raise RecipeError(f"{where}: expected a table of sections ({', '.join(SECTIONS)}), got {table!r}")
    valid = valid_keys()
    for name, value in table.items():
        if name not in valid:
            raise RecipeError(f"{where}: unknown section [{name}]; valid sections: {', '.join(SECTIONS)}, [scales]")
        check_table(value, valid[name], f"{where} [{name}]")


def check_table(table: Any, valid: dict, where: str) -> None:
    """Check ``table``'s keys against ``valid`` (key -> default) and each value against its default's type."""
    if not isinstance(table, dict):
        raise RecipeError(f"{where}: expected a table, got {table!r}")
    for key, value in table.items():
        if key not in valid:
            raise RecipeError(f"{where}: unknown key {key!r}; valid keys: {', '.join(sorted(valid))}")
        default = valid[key]
        if isinstance(default, dict) and default:
            check_table(value, default, f"{where} {key}")
        elif not _same_kind(value, default):
            raise RecipeError(f"{where}: {key} = {value!r} should be a {_kind(default)} (like {default!r})")


def _kind(default: Any) -> str:
    if isinstance(default, bool):
        return "boolean"
    if isinstance(default, (int, float)):
        return "number" if isinstance(default, float) else "integer"
    return {str: "string", tuple: "list", list: "list", dict: "table"}.get(type(default), type(default).__name__)


def _same_kind(value: Any, default: Any) -> bool:
    if default is None:  # no default to compare with: the config class checks it
        return True
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(default, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float))
    if isinstance(default, (tuple, list)):
        return isinstance(value, (tuple, list))
    return isinstance(value, type(default))


def valid_keys() -> dict:
    """Section -> its keys and their defaults, read from the config classes (the sampler's in its nested form)."""
    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.pipeline.tree.config import SamplerConfig
    from drem_maniskill.pipeline.tree.phases import PHASES

    sampler = SamplerConfig().to_dict()
    sampler["phases"] = {name: asdict(phase.config()) for name, phase in PHASES.items()}
    from drem_maniskill.pipeline.policy_rounds import RoundsConfig

    return {"sampler": sampler, "train": asdict(TrainConfig()), "rounds": asdict(RoundsConfig()), **SECTION_DEFAULTS}


def merge(base: dict, override: dict) -> dict:
    """``override`` over ``base``: tables merged key by key, any other value replaced."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out
