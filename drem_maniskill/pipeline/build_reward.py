"""One command per reward: a task's recipe (``tasks/<id>/recipe.toml``) run from the demo to a reward folder.

``build_reward`` runs the stages of ``STAGES`` in order, each writing one output under the work folder and skipping
when that output exists (the sampler and the training also resume their own partial files), so an interrupted build
is finished by running the same command again:

1. demo: the committed demo the recipe names, else ``record-expert`` -> ``expert/expert.h5``;
2. sample: backward sampling -> ``tree.h5`` (and ``tree_<k>.h5`` from the demo's episode ``k`` where ``[demo] trees``
   asks for more than one);
3. scene-swap negatives, where the recipe asks for them -> ``scene_swap/negatives_<k>.h5`` (one per tree);
   train: the reward -> ``reward/drem.pt``; where the recipe asks for policy rounds, they fine-tune it on hard
   negatives -> ``rounds/drem.pt`` (``rounds/round_<k>/``); examine the last -> ``examination/``;
4. the image-only twin, where the recipe asks for it -> ``reward_image/``, ``examination_image/``;
5. calibrate: the support guard's thresholds -> ``support.json``;
6. the products copied to the work folder's top under the names ``rewards/<id>/`` uses (``drem.pt``,
   ``quality.json``, ...); with ``publish``, into the shipped ``rewards/<id>/`` too, naming each file replaced.
"""

from __future__ import annotations

import filecmp
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union

from drem_maniskill.drem.checkpoint import REWARDS_DIRS
from drem_maniskill.pipeline.recipe import FULL, SECTION_DEFAULTS, Recipe, RecipeError, load_recipe
from drem_maniskill.utils.atomic import atomic_path, copy_file, write_json
from drem_maniskill.utils.lock import folder_lock

DEFAULT_OUT = Path("outputs") / "build_reward"


@dataclass(frozen=True)
class Stage:
    """One stage of a build: the file it writes, the recipe sections it reads, and the stages whose outputs it reads."""

    name: str
    output: str
    """Its file under the work folder; ``<k>``: one per demo episode."""
    sections: tuple
    reads: tuple = ()

    def path(self, work: Path, k: int = 0) -> Path:
        """Its output in the work folder ``work`` (for demo episode ``k``)."""
        return work / self.output.replace("<k>", str(k))

    def made(self) -> tuple:
        """What a rebuild deletes: its output's entry at the work folder's top, with a sampled tree's resume file."""
        top = self.output.split("/")[0]
        return (top, f"{top}.partial") if top.endswith(".h5") else (top,)


STAGES = {s.name: s for s in (
    Stage("demo", "expert/expert.h5", ("demo",)),
    Stage("sample", "tree.h5", ("demo", "sampler"), ("demo",)),
    Stage("sample_episodes", "tree_<k>.h5", ("demo", "sampler"), ("demo",)),
    Stage("scene_swap", "scene_swap/negatives_<k>.h5", ("demo", "scene_swap"), ("demo",)),
    Stage("train", "reward/drem.pt", ("train",), ("sample", "sample_episodes", "scene_swap")),
    Stage("rounds", "rounds/drem.pt", ("train", "rounds"), ("sample", "sample_episodes", "scene_swap", "train")),
    Stage("examine", "examination/quality.json", ("examine",), ("train", "rounds")),
    Stage("train_image", "reward_image/drem.pt", ("train", "image_twin"), ("sample", "sample_episodes", "scene_swap")),
    Stage("rounds_image", "rounds_image/drem.pt", ("train", "rounds"),
          ("sample", "sample_episodes", "scene_swap", "train_image")),
    Stage("examine_image", "examination_image/quality.json", ("examine",), ("train_image", "rounds_image")),
    Stage("calibrate", "support.json", ("calibrate",), ("sample", "train", "rounds")),
)}
# Work-folder file -> its name in a reward folder (as in rewards/<id>/); a stage's output, or a file beside it.
PUBLISHED = {
    "reward/drem.pt": "drem.pt",
    "examination/quality.json": "quality.json",
    "examination/examination.png": "examination.png",
    "reward_image/drem.pt": "drem_image.pt",
    "examination_image/quality.json": "quality_image.json",
    "examination_image/examination.png": "examination_image.png",
    "support.json": "support.json",
}
# The policy rounds' checkpoints, published in place of the paper's where a recipe runs them.
ROUNDS_PUBLISHED = {"reward/drem.pt": "rounds/drem.pt", "reward_image/drem.pt": "rounds_image/drem.pt"}
# Settings of the machine, not of the reward: a build may resume with other values.
MACHINE_FIELDS = {"sampler": ("workers",), "train": ("threads", "device")}


def stale_outputs(section: str) -> list:
    """The work-folder entries a change to recipe ``section`` makes stale: the outputs of the stages that read it, and
    of every stage reading theirs (a key no stage declares, such as the scale: every output)."""
    stale = {name for name, s in STAGES.items() if section in s.sections} or set(STAGES)
    grew = True
    while grew:
        more = {name for name, s in STAGES.items() if stale & set(s.reads)} - stale
        stale |= more
        grew = bool(more)
    return sorted(entry for name in stale for entry in STAGES[name].made())


def build_reward(task: str, scale: str = FULL, out: Optional[Union[str, Path]] = None,
                 recipe: Union[str, Path, dict, None] = None, publish: bool = False) -> Path:
    """Make ``task``'s reward from its recipe at ``scale`` in the work folder ``out``; returns its ``drem.pt``.

    ``out`` defaults to ``outputs/build_reward/<task>/<scale>``; the products are copied to its top under their
    published names. ``publish`` (the full scale only) copies them into the shipped ``rewards/<task>/`` too, and
    returns the shipped ``drem.pt``. ``recipe``: a recipe file, ``"default"`` (the general defaults) or None
    (``tasks/<task>/recipe.toml``).
    """
    if publish and scale != FULL:
        raise RecipeError(f"only a full-scale build publishes into rewards/{task}/ (the shipped reward is the recipe "
                          f"as written); this build is at scale {scale!r}: drop publish, or build at {FULL!r}")
    r = load_recipe(task, scale, recipe)
    work = Path(out) if out is not None else DEFAULT_OUT / task / scale
    # Two builds in one folder would both append to its partial tree and training state.
    with folder_lock(work, 0.0, "built", "the build resumes from its last finished stage", "build-reward"):
        return _build(r, work, publish)


def _build(r: Recipe, work: Path, publish: bool) -> Path:
    """``build_reward``'s stages in ``work``, run while its lock is held."""
    task = r.task
    check_same_recipe(work / "recipe.json", r)
    _log(task, f"recipe {r.source}, scale {r.scale}; working in {work}")
    expert = demo_stage(r, work)
    tree = stage(task, "sample", STAGES["sample"].path(work), lambda p: _sample(str(expert), str(p), r))
    trees = [stage(task, f"sample episode {k}", STAGES["sample_episodes"].path(work, k),
                   lambda p, k=k: _sample(str(expert), str(p), r, episode=k)) for k in range(1, r.demo["trees"])]
    negatives = []
    if r.scene_swap["negatives"]:
        negatives = [stage(task, f"scene-swap negatives {k}", STAGES["scene_swap"].path(work, k),
                           lambda p, k=k: _swap_negatives(str(expert), p, r, k)) for k in range(r.demo["trees"])]
    checkpoint = model_stages(r, tree, work, "", r.train["model"].get("modalities"), trees, negatives)
    if r.image_twin["enabled"]:
        model_stages(r, tree, work, "_image", r.image_twin["modalities"], trees, negatives)
    if r.calibrate["enabled"]:
        stage(task, "calibrate", STAGES["calibrate"].path(work), lambda p: _calibrate(checkpoint, tree, p, r))
    copy_products(task, work, work)
    if publish:
        copy_products(task, work, REWARDS_DIRS[0] / task)
        return REWARDS_DIRS[0] / task / "drem.pt"
    return work / "drem.pt"


def _sample(expert: str, out: str, r: Recipe, episode: int = 0) -> str:
    from drem_maniskill.pipeline import backward_sample

    return backward_sample(expert, out, r.sampler_config(episode=episode))


def _swap_negatives(expert: str, out: Path, r: Recipe, episode: int) -> None:
    from drem_maniskill.pipeline.scene_swap import swap_negatives

    swap_negatives(expert, str(out), episode=episode, lag=r.scene_swap["lag"], max_pairs=r.scene_swap["max_pairs"])


def _calibrate(checkpoint: Path, tree: Path, out: Path, r: Recipe) -> None:
    from drem_maniskill.pipeline.support import calibrate_support

    quantile = r.calibrate.get("quantile")
    calibrate_support(str(checkpoint), str(tree), str(out), **({"quantile": quantile} if quantile is not None else {}))


def _train(tree: Path, out: Path, config, trees=(), negatives=()) -> None:
    from drem_maniskill.pipeline.train_reward import train_reward

    train_reward(str(tree), str(out.parent), config, trees=[str(t) for t in trees],
                 negatives=[str(n) for n in negatives])


def _examine(task: str, checkpoint: Path, out: Path, r: Recipe) -> None:
    from drem_maniskill.evaluate.examine import examine

    examine(task, str(checkpoint), seeds=r.exam_seeds(), out_dir=str(out.parent))


def demo_stage(r: Recipe, work: Path) -> Path:
    """The expert demo: the committed one the recipe names, else one recorded with its settings (once)."""
    committed = r.expert_file()
    if committed is not None and committed.is_file():
        check_demo_task(committed, r.task)
        _log(r.task, f"demo: the committed {committed}")
        return committed
    if committed is not None:
        _log(r.task, f"demo: {committed} is missing; recording one with the recipe's [demo] settings")

    def record(path: Path) -> None:
        """Record the demo's episodes into ``path``'s folder."""
        from drem_maniskill.experts import record_expert

        d = r.demo
        # RecordEpisode writes its files in place: the folder appears whole, so a stopped recording is redone.
        with atomic_path(path.parent, directory=True) as folder:
            record_expert(r.task, str(folder), seeds=range(d["seed"], d["seed"] + d["episodes"]), name=path.stem,
                          env_kwargs=dict(d["env_kwargs"]), descent_step=d["descent_step"],
                          descend_from=d["descend_from"])

    return stage(r.task, "demo", STAGES["demo"].path(work), record)


def check_demo_task(h5: Path, task: str) -> None:
    """Refuse a demo recorded on another task (a recipe copied from another task's folder)."""
    meta = h5.with_suffix(".json")
    if not meta.is_file():
        raise RecipeError(f"{meta} (the metadata beside the demo {h5.name}) not found")
    env_id = json.loads(meta.read_text()).get("env_info", {}).get("env_id")
    if env_id != task:
        raise RecipeError(f"the demo {h5} was recorded on {env_id}, not {task}; "
                          f"point [demo] expert at a {task} demo, or drop it to record one")


def model_stages(r: Recipe, tree: Path, work: Path, suffix: str, modalities, trees=(), negatives=()) -> Path:
    """Train a reward on ``tree``, ``trees`` and the negatives files ``negatives`` (``modalities``; None: all the tree
    holds) and examine it; returns its checkpoint."""
    from drem_maniskill.pipeline.dataset import dataset_modalities

    config = r.train_config(modalities=modalities or dataset_modalities(str(tree)))
    checkpoint = stage(r.task, f"train{suffix}", STAGES[f"train{suffix}"].path(work),
                       lambda p: _train(tree, p, config, trees, negatives))
    rounds = r.rounds_config()
    if rounds.rounds > 0:
        checkpoint = stage(r.task, f"rounds{suffix}", STAGES[f"rounds{suffix}"].path(work),
                           lambda p: _rounds(r.task, tree, checkpoint, config, rounds, p, trees, negatives))
    stage(r.task, f"examine{suffix}", STAGES[f"examine{suffix}"].path(work),
          lambda p: _examine(r.task, checkpoint, p, r))
    return checkpoint


def _rounds(task: str, tree: Path, checkpoint: Path, config, rounds, out: Path, trees=(), negatives=()) -> None:
    """The policy rounds from ``checkpoint``; their last checkpoint copied to ``out``."""
    from drem_maniskill.pipeline.policy_rounds import run_rounds

    last = run_rounds(task, str(tree), checkpoint, config, rounds, out.parent, [str(t) for t in trees],
                      [str(n) for n in negatives])
    copy_file(last, out)


def stage(task: str, name: str, output: Path, run: Callable[[Path], object]) -> Path:
    """Run ``run(output)`` unless ``output`` exists; either way return ``output``."""
    if output.exists():
        _log(task, f"{name}: skipped, {output} exists")
        return output
    _log(task, f"{name}: running -> {output}")
    start = time.time()
    output.parent.mkdir(parents=True, exist_ok=True)
    run(output)
    if not output.exists():
        raise RuntimeError(f"stage {name} of {task} finished without writing {output}")
    _log(task, f"{name}: done in {time.time() - start:.0f} s")
    return output


def copy_products(task: str, work: Path, dest: Path) -> None:
    """Copy the products to ``dest`` under their published names, saying of each file there whether it changed."""
    dest.mkdir(parents=True, exist_ok=True)
    for src_name, dest_name in PUBLISHED.items():
        src, target = work / src_name, dest / dest_name
        if src_name in ROUNDS_PUBLISHED and (work / ROUNDS_PUBLISHED[src_name]).is_file():
            src = work / ROUNDS_PUBLISHED[src_name]
        if not src.is_file() or src.resolve() == target.resolve():
            continue
        if not target.is_file():
            copy_file(src, target)
            _log(task, f"publish: {target} (new)")
        elif filecmp.cmp(src, target, shallow=False):
            _log(task, f"publish: {target} unchanged")
        else:
            copy_file(src, target)
            _log(task, f"publish: {target} replaced (changed)")


def check_same_recipe(path: Path, r: Recipe) -> None:
    """Record the recipe beside the outputs; refuse to resume outputs made by another recipe."""
    current = json.loads(json.dumps(r.to_dict()))
    if path.is_file():
        before = json.loads(path.read_text())
        changed = sorted(k for k in set(before) | set(current) if _outcome(before, k) != _outcome(current, k))
        if changed:
            stale = sorted({entry for section in changed for entry in stale_outputs(section)})
            raise RecipeError(
                f"{path.parent} holds outputs of another recipe (it differs in {', '.join(changed)}); delete what "
                f"those settings made ({', '.join(stale)}, and recipe.json) to rebuild them, or build elsewhere (out=)")
        return
    write_json(path, current)


def _outcome(recipe: dict, section: str):
    """A recipe section without the settings that change how fast a stage runs, not what it makes."""
    value = recipe.get(section)
    if value is None:  # a section the recorded recipe predates took its defaults
        value = SECTION_DEFAULTS.get(section, {})
    if section in MACHINE_FIELDS and isinstance(value, dict):
        return {k: v for k, v in value.items() if k not in MACHINE_FIELDS[section]}
    return value


def _log(task: str, message: str) -> None:
    print(f"build-reward {task}: {message}", file=sys.stderr, flush=True)
