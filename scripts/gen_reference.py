"""Write the generated reference pages: docs/reference.md, docs/recipe.md and docs/api.md.

Run: ``.venv/bin/python scripts/gen_reference.py`` (``--check`` fails when a page is stale).
Everything comes from the code, so the pages cannot drift from it (``tests/test_reference.py`` fails when one does):

* docs/reference.md: every ``drem-maniskill`` subcommand with its flags and help (the CLI's argparse parser), and
  every field of the config dataclasses with its default and the first sentence of its docstring;
* docs/recipe.md: every section and key of a recipe file (``tasks/<id>/recipe.toml``) with its default and meaning,
  from ``pipeline.recipe`` (its sections, ``valid_keys()``, ``SECTION_DEFAULTS``) and the config dataclasses;
* docs/api.md: the public Python objects, imported by module path, with their signatures and docstrings.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import re
import sys
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "reference.md"
COMMAND = ".venv/bin/python scripts/gen_reference.py"


def _cell(text) -> str:
    """Text for one markdown table cell."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _value(value) -> str:
    """A default as the page shows it."""
    if isinstance(value, tuple):
        value = list(value)
    return f"`{value!r}`" if value != "" else "`''`"


def _subcommands(parser: argparse.ArgumentParser) -> dict:
    """Name -> subparser, in the order the parser lists them."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _summaries(parser: argparse.ArgumentParser) -> dict:
    """Name -> the one-line help of each subcommand."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a.help for a in action._choices_actions}


def command_section(name: str, sub: argparse.ArgumentParser, summary: str) -> list:
    """Markdown of one subcommand: its usage, what it does and a table of its flags."""
    formatter = sub._get_formatter()
    lines = [f"### `drem-maniskill {name}`", "", summary[0].upper() + summary[1:] + ".", ""]
    if sub.description and sub.description != summary:
        lines += [" ".join(sub.description.split()), ""]
    lines += ["| flag | what it does |", "| --- | --- |"]
    for action in sub._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        flags = ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.dest}`"
        if action.required:
            flags += " (required)"
        text = formatter._expand_help(action) if action.help else ""
        lines.append(f"| {flags} | {_cell(text)} |")
    return lines + [""]


def config_section(title: str, cls, note: str = "") -> list:
    """Markdown table of a config dataclass: every field, its default and the first sentence of its docstring."""
    from drem_maniskill.utils.config_cli import config_fields, default_instance, field_docs, first_sentence

    docs, instance = field_docs(cls), default_instance(cls)
    lines = [f"### `{title}`", "", f"`{cls.__module__}.{cls.__qualname__}`. {note}".rstrip(), "",
             "| field | default | what it does |", "| --- | --- | --- |"]
    for f in config_fields(cls):
        value = getattr(instance, f.name)
        if dataclasses.is_dataclass(value):
            shown = f"a `{type(value).__name__}`"
        elif isinstance(value, dict) and value and all(dataclasses.is_dataclass(v) for v in value.values()):
            shown = "one entry per phase, below"
        else:
            shown = _value(value)
        lines.append(f"| `{f.name}` | {shown} | {_cell(first_sentence(docs.get(f.name, '')))} |")
    return lines + [""]


def _configs() -> list:
    """The config sections: the sampler and its phases, training, the model, the policy run."""
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline import SamplerConfig
    from drem_maniskill.pipeline.policy_rounds import RoundsConfig
    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.rl.config import RLConfig

    lines = config_section("SamplerConfig", SamplerConfig, "Backward sampling (`drem-maniskill sample`, recipes).")
    if "phases" in {f.name for f in dataclasses.fields(SamplerConfig)}:
        from drem_maniskill.pipeline.tree.phases import PHASES

        for name, phase in PHASES.items():
            lines += config_section(f"phases.{name}", phase.config,
                                    f"Set with `--phase {name}.FIELD=VALUE` or `--{name.replace('_', '-')}-FIELD`.")
    lines += config_section("TrainConfig", TrainConfig, "Reward-model training (`drem-maniskill train-reward`).")
    lines += config_section("ModelConfig", ModelConfig, "`TrainConfig.model`: flags `--model-FIELD`.")
    lines += config_section("RoundsConfig", RoundsConfig, "Policy rounds of hard negatives: a recipe's `[rounds]` "
                                                          "(`build-reward`).")
    lines += config_section("RLConfig", RLConfig, "Policy learning (`drem-maniskill train-policy`); the presets "
                                                  "change several defaults (see the command's flags).")
    return lines


def render() -> str:
    """The whole page."""
    from drem_maniskill.cli import build_parser

    # The state preset turns bfloat16 on where the CPU has it natively: the page shows a CPU without, on every machine.
    with mock.patch("drem_maniskill.rl.config.native_bf16", lambda: False):
        parser = build_parser()
    lines = ["# Reference", "",
             f"Generated from the code by `{COMMAND}`; do not edit by hand. Defaults marked per preset apply "
             "to that preset (`--preset`); a flag given on the command line overrides the preset's value. The "
             "state preset also turns `--bf16` on where the CPU computes bfloat16 natively (AVX512-BF16 or AMX). "
             "The keys of a recipe file are in the [recipe reference](recipe.md), the Python objects in the "
             "[API reference](api.md).", "", "## Commands", ""]
    summaries = _summaries(parser)
    for name, sub in _subcommands(parser).items():
        lines += command_section(name, sub, summaries.get(name) or "")
    lines += ["## Configs", "",
              "Every field of the config dataclasses, its default (before any preset) and what it does.", ""]
    lines += _configs()
    return "\n".join(lines).rstrip() + "\n"


# ---------------------------------------------------------------------------------------------- docs/recipe.md

RECIPE_OUT = ROOT / "docs" / "recipe.md"
RECIPE_MODULE = "drem_maniskill.pipeline.recipe"

# What each key of the sections that have no config class does (``SECTION_DEFAULTS``). A ``SECTION_DOCS`` dict of the
# same shape in the recipe module, where it has one, takes precedence; a key neither names is shown as undocumented
# (tests/test_reference.py fails on that).
KEY_DOCS = {
    "demo": {
        "expert": "The committed demo beside the recipe (`expert.h5`, its `.json` beside it); without one, or when "
                  "the file is missing, the demo is recorded with the keys below.",
        "seed": "Seed of the first recorded demo episode.",
        "episodes": "Demo episodes recorded (seeds `seed`, `seed + 1`, ...).",
        "trees": "How many of the demo's episodes are sampled into a progress tree each and trained on together, "
                 "toward the first episode's goal (1: the paper's one demo).",
        "descent_step": "Our tasks' expert: metres per step it descends inside the socket (not set: the expert's "
                        "default).",
        "descend_from": "Our tasks' expert: metres above the socket's top face where its slow descent starts (not "
                        "set: wherever it aligned).",
        "env_kwargs": "Extra `gym.make` keyword arguments of the recorded demo's env.",
    },
    "image_twin": {
        "enabled": "Also train the image-only twin `drem_image.pt` on the same tree.",
        "modalities": "The twin's inputs.",
    },
    "scene_swap": {
        "negatives": "Add the scene-swap negatives of every demo episode sampled into a tree to the training set "
                     "(beyond the paper).",
        "lag": "Least depth gap between the robot's depth and the objects' (the triplet loss's `eps`: closer scenes "
               "are neighbours anyway).",
        "max_pairs": "At most this many scenes per demo episode, spread evenly over the depth pairs.",
    },
    "examine": {
        "first_seed": "First held-out seed of the examination (keep clear of the demo's seeds).",
        "episodes": "Held-out seeds per scripted policy, from `first_seed` on.",
    },
    "calibrate": {
        "enabled": "Write `support.json`, the thresholds of the support guard (`drem-guarded`).",
        "quantile": "Quantile of the tree's reconstruction errors taken as the threshold (not set: "
                    "`drem_maniskill.drem.guard.GUARD_QUANTILE`).",
    },
}
UNDOCUMENTED = "(undocumented)"


def _md(text: str) -> str:
    """reStructuredText literals (double backticks) as markdown code spans."""
    return re.sub(r"``(.+?)``", r"`\1`", text)


def _toml(value) -> str:
    """A default as a recipe writes it; None: the key is left out."""
    if value is None:
        return "not set"
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, (tuple, list)):
        return "`[" + ", ".join(_toml(v).strip("`") for v in value) + "]`"
    if isinstance(value, dict):
        items = ", ".join(f"{k} = {_toml(v).strip('`')}" for k, v in value.items())
        return f"`{{ {items} }}`" if value else "`{}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    return f"`{value!r}`"


def section_docs(module) -> dict:
    """Section name -> its bullet in the recipe module's docstring (``* ``[name]``: text``), as markdown."""
    out, name = {}, None
    for line in (module.__doc__ or "").splitlines():
        match = re.match(r"\* ``\[([\w.<>]+)\]``: (.*)", line.strip())
        if match:
            name = match.group(1)
            out[name] = match.group(2)
        elif name and line.startswith("  ") and line.strip():
            out[name] += " " + line.strip()
        else:
            name = None
    return {k: _md(v[:1].upper() + v[1:]) for k, v in out.items()}


def key_table(defaults: dict, docs: dict, prefix: str = "") -> list:
    """Rows ``| key | default | meaning |`` of one section (nested tables of config classes are shown apart)."""
    lines = ["| key | default | what it sets |", "| --- | --- | --- |"]
    for key, value in defaults.items():
        text = docs.get(key) or UNDOCUMENTED
        lines.append(f"| `{prefix}{key}` | {_toml(value)} | {_cell(_md(first_sentence_of(text)))} |")
    return lines + [""]


def first_sentence_of(doc: str) -> str:
    from drem_maniskill.utils.config_cli import first_sentence

    return first_sentence(doc)


def _class_note(cls) -> str:
    """``module.Class``: its docstring's first line, for the sentence above a section's table."""
    doc = (inspect.getdoc(cls) or "").split("\n\n")[0]
    return f"`{cls.__module__}.{cls.__qualname__}`: {_md(' '.join(doc.split()))}"


def recipe_sections() -> list:
    """The markdown of every section, in the order a recipe lists them."""
    from drem_maniskill.utils.config_cli import field_docs

    recipe = importlib.import_module(RECIPE_MODULE)
    valid, bullets = recipe.valid_keys(), section_docs(recipe)
    key_docs = {name: {**KEY_DOCS.get(name, {}), **getattr(recipe, "SECTION_DOCS", {}).get(name, {})}
                for name in recipe.SECTION_DEFAULTS}
    classes = _section_classes()
    lines = []
    for name in recipe.SECTIONS:
        lines += [f"## `[{name}]`", ""]
        if name in bullets:
            lines += [bullets[name], ""]
        keys = dict(valid.get(name, {}))
        if name in classes:
            cls = classes[name]
            lines += [_class_note(cls) + " Every field is a key:", ""]
            nested = {k: v for k, v in keys.items() if isinstance(v, dict) and v}
            flat = {k: v for k, v in keys.items() if k not in nested}
            lines += key_table(flat, field_docs(cls))
            for key in nested:
                lines += _nested(name, key, nested[key], cls)
        else:
            lines += key_table(keys, key_docs.get(name, {}))
    return lines


def _section_classes() -> dict:
    """The sections read into a config class: section -> the class (module paths, so a move shows at once)."""
    from drem_maniskill.pipeline.policy_rounds import RoundsConfig
    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.pipeline.tree.config import SamplerConfig

    return {"sampler": SamplerConfig, "train": TrainConfig, "rounds": RoundsConfig}


def _nested(section: str, key: str, defaults: dict, cls) -> list:
    """A nested table of a section: ``[train.model]`` (``ModelConfig``) or ``[sampler.phases.<name>]``."""
    from drem_maniskill.utils.config_cli import field_docs

    if key == "phases":
        from drem_maniskill.pipeline.tree.phases import PHASES

        lines = [f"### `[{section}.phases.<name>]`", "",
                 "The extra phases of backward sampling (beyond the paper), one table each; they run after the "
                 "paper's loop in the order below, each when its size key is above 0 (the default: all off).", ""]
        for name, phase in PHASES.items():
            lines += [f"#### `[{section}.phases.{name}]`", "",
                      f"{_class_note(phase.config)} Runs when `{phase.size}` > 0; its nodes are labelled "
                      f"{_md(phase.labels)}" + (f"; it starts from the {', '.join(phase.requires)} phase's seeds"
                                                if phase.requires else "") + ".", ""]
            lines += key_table(defaults.get(name, {}), field_docs(phase.config))
        return lines
    inner = type(_default_of(cls, key))
    lines = [f"### `[{section}.{key}]`", ""]
    if dataclasses.is_dataclass(inner):
        return lines + [_class_note(inner) + " Every field is a key:", ""] + key_table(defaults, field_docs(inner))
    return lines + key_table(defaults, {})


def _default_of(cls, key: str):
    from drem_maniskill.utils.config_cli import default_instance

    instance = default_instance(cls)
    return getattr(instance, key, None) if instance is not None else None


def general_recipe() -> list:
    """What a task without a recipe file builds with: ``GENERAL_DEFAULTS`` as a recipe file."""
    recipe = importlib.import_module(RECIPE_MODULE)
    toml = []

    def table(path: list, d: dict) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        if scalars:
            toml.append(f"[{'.'.join(path)}]")
            toml.extend(f"{k} = {_toml(v).strip('`')}" for k, v in scalars.items())
            toml.append("")
        for k, v in d.items():
            if isinstance(v, dict):
                table(path + [k], v)

    for name, value in recipe.GENERAL_DEFAULTS.items():
        table([name], value)
    return (["## The general recipe: a task without a recipe file", "",
             "`drem-maniskill build-reward --task <id>` builds a task that has no `tasks/<id>/recipe.toml` with the "
             f"recipe below (`{RECIPE_MODULE}.GENERAL_DEFAULTS`; `--recipe {recipe.GENERAL}` builds any task with "
             "it); every key it leaves out takes its default above.", "",
             "```toml"] + toml[:-1] + ["```", ""])


def render_recipe() -> str:
    """The whole recipe page."""
    recipe = importlib.import_module(RECIPE_MODULE)
    sections = ", ".join(f"`[{s}]`" for s in recipe.SECTIONS)
    lines = ["# Recipe file reference", "",
             f"Generated from the code by `{COMMAND}`; do not edit by hand. A task's recipe, "
             "`tasks/<id>/recipe.toml`, holds every setting that makes its DREM reward; `drem-maniskill build-reward "
             "--task <id>` reads it ([drem.md](drem.md#one-command-per-reward)). Its sections are "
             f"{sections} and `[scales.<name>]`. Every section and key is optional: a key left out takes the "
             "default below (the config classes' defaults, which are the paper's). An unknown section or key, or a "
             "value of the wrong kind, is refused when the recipe is read, with the valid keys named. \"not set\": "
             "the key has no default value and is left out unless wanted.", ""]
    lines += recipe_sections()
    bullets = section_docs(recipe)
    scales = next((v for k, v in bullets.items() if k.startswith("scales")), "")
    lines += ["## `[scales.<name>]`", "", scales, "",
              "```toml", "[scales.tiny.train]", "iterations = 50", "", "[scales.tiny.examine]", "episodes = 1", "```",
              "", "`build-reward --scale tiny` merges `[scales.tiny]` over the recipe, key by key.", ""]
    lines += general_recipe()
    return "\n".join(lines).rstrip() + "\n"


# ------------------------------------------------------------------------------------------------- docs/api.md

API_OUT = ROOT / "docs" / "api.md"
# The public objects, by module path and name, in the order the page shows them.
API = [
    ("drem_maniskill.drem.reward", "DREMReward"),
    ("drem_maniskill.drem.wrapper", "DREMRewardWrapper"),
    ("drem_maniskill.envs.aliases", "register_drem_env"),
    ("drem_maniskill.experts.policies", "get_policy"),
    ("drem_maniskill.rl.config", "RLConfig"),
]


def _annotation(annotation) -> str:
    """An annotation as written in the source (a quoted forward reference without its quotes)."""
    if isinstance(annotation, str):
        return annotation.strip("'\"")
    return inspect.formatannotation(annotation)


def _default(value) -> str:
    """A default's repr, without this checkout's path or memory addresses."""
    text = repr(value).replace(str(ROOT) + "/", "").replace(str(ROOT), ".")
    return re.sub(r" at 0x[0-9a-f]+", "", text)


def signature(obj, bound: bool = False) -> str:
    """``(a: int, b=1, *, c: str = 'x') -> R`` with annotations as written in the source; ``bound``: a method's, without
    its ``self``."""
    sig = inspect.signature(obj)
    params = list(sig.parameters.values())[1 if bound else 0:]
    parts, star_done = [], False
    for i, p in enumerate(params):
        if p.kind == p.KEYWORD_ONLY and not star_done:
            parts.append("*")
            star_done = True
        name = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "") + p.name
        star_done = star_done or p.kind == p.VAR_POSITIONAL
        if p.annotation is not p.empty:
            name += f": {_annotation(p.annotation)}"
        if p.default is not p.empty:
            name += (" = " if p.annotation is not p.empty else "=") + _default(p.default)
        parts.append(name)
        if p.kind == p.POSITIONAL_ONLY and (i + 1 == len(params) or params[i + 1].kind != p.POSITIONAL_ONLY):
            parts.append("/")
    out = "(" + ", ".join(parts) + ")"
    if sig.return_annotation is not sig.empty:
        out += f" -> {_annotation(sig.return_annotation)}"
    return out


def _members(cls) -> list:
    """``(name, kind, object)`` of the public methods and properties ``cls`` defines, in source order."""
    out = []
    for name, member in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(member, property):
            out.append((name, "property", member.fget))
        elif isinstance(member, (classmethod, staticmethod)):
            out.append((name, type(member).__name__, getattr(cls, name)))
        elif inspect.isfunction(member):
            out.append((name, "method", member))
    return out


def _doc(obj) -> list:
    doc = inspect.getdoc(obj)
    return [_md(doc), ""] if doc else []


def _exported(module: str, name: str, obj) -> str:
    """How to import it, and the package-level name where the package exports it too."""
    import drem_maniskill

    line = f"`from {module} import {name}`"
    if getattr(drem_maniskill, name, None) is obj:
        line += f" (also `from drem_maniskill import {name}`)"
    return line


def api_entry(module: str, name: str) -> list:
    """The markdown of one public object: import line, signature, docstring, and a class's methods."""
    obj = getattr(importlib.import_module(module), name)
    lines = [f"## `{name}`", "", _exported(module, name, obj), ""]
    if inspect.isclass(obj):
        if dataclasses.is_dataclass(obj):
            lines += ["```python", f"class {name}(**fields)", "```", ""] + _doc(obj)
            lines += [f"A dataclass: every field, its default and what it does is in the "
                      f"[reference](reference.md#{name.lower()}).", ""]
        else:
            lines += ["```python", f"class {name}{signature(obj)}", "```", ""] + _doc(obj)
        for member, kind, fn in _members(obj):
            if kind == "property":
                lines += [f"### `{name}.{member}` (property)", ""] + _doc(fn)
                continue
            tag = "" if kind == "method" else f" ({kind})"
            shown = f"{name}.{member}{signature(fn, bound=kind == 'method')}"
            lines += [f"### `{name}.{member}`{tag}", "", "```python", shown, "```", ""] + _doc(fn)
    else:
        lines += ["```python", f"{name}{signature(obj)}", "```", ""] + _doc(obj)
    return lines


def render_api() -> str:
    """The whole API page."""
    lines = ["# Python API", "",
             f"Generated from the code by `{COMMAND}`; do not edit by hand. The objects a user's code calls: the "
             "reward, the wrapper that puts it on any ManiSkill env, the DREM-by-default env ids, the scripted "
             "policies and the configuration of a policy-learning run. `import drem_maniskill` registers the tasks.",
             ""]
    lines += [f"- [`{name}`](#{name.lower()}): `{module}`" for module, name in API] + [""]
    for module, name in API:
        lines += api_entry(module, name)
    return "\n".join(lines).rstrip() + "\n"


# ------------------------------------------------------------------------------------------------------- main

PAGES = {OUT: render, RECIPE_OUT: render_recipe, API_OUT: render_api}


def stale_pages() -> list:
    """The generated pages whose file differs from what the code renders now."""
    return [path for path, page in PAGES.items() if (path.read_text() if path.exists() else "") != page()]


def main(argv=None) -> int:
    """Write the generated pages, or with ``--check`` report whether they are current."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="exit 1 when a generated page differs")
    args = parser.parse_args(argv)
    if args.check:
        stale = stale_pages()
        for path in stale:
            print(f"{path.relative_to(ROOT)} is stale; regenerate it with `{COMMAND}`", file=sys.stderr)
        return 1 if stale else 0
    for path, page in PAGES.items():
        path.write_text(page())
        print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
