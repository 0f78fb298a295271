"""Write docs/reference.md: every ``drem-maniskill`` subcommand with its flags, and every field of the configs.

Run: ``.venv/bin/python scripts/gen_reference.py`` (``--check`` fails when docs/reference.md is stale).
Everything comes from the code: the flags and their help from the CLI's argparse parser, the fields, defaults and
descriptions from the config dataclasses (each field's docstring), so the page cannot drift from them;
``tests/test_reference.py`` fails when it does.
"""

from __future__ import annotations

import argparse
import dataclasses
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
             "state preset also turns `--bf16` on where the CPU computes bfloat16 natively (AVX512-BF16 or AMX).",
             "", "## Commands", ""]
    summaries = _summaries(parser)
    for name, sub in _subcommands(parser).items():
        lines += command_section(name, sub, summaries.get(name) or "")
    lines += ["## Configs", "",
              "Every field of the config dataclasses, its default (before any preset) and what it does.", ""]
    lines += _configs()
    return "\n".join(lines).rstrip() + "\n"


def main(argv=None) -> int:
    """Write docs/reference.md, or with ``--check`` report whether it is current."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/reference.md differs")
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        current = OUT.read_text() if OUT.exists() else ""
        if current != text:
            print(f"{OUT.relative_to(ROOT)} is stale; regenerate it with `{COMMAND}`", file=sys.stderr)
            return 1
        return 0
    OUT.write_text(text)
    print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
