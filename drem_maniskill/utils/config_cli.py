"""Command-line flags derived from a config dataclass, so every setting is written once: in its dataclass.

``add_dataclass_args(parser, Config)`` adds one flag per field, ``--field-name``, with the type,
the help (the field's attribute docstring: the ``\"\"\"...\"\"\"`` string under it) and the default
taken from the dataclass; every flag defaults to None, so ``overrides_from_args`` returns only
what was given, and ``apply_overrides`` puts that on top of a preset. Field shapes:

* ``int``, ``float``, ``str`` (``Optional`` of them too): ``--x VALUE``;
* ``bool``: ``--x`` / ``--no-x``;
* ``tuple``: ``--x A B ...`` (no value: the empty tuple);
* ``dict``: ``--x JSON`` (a JSON object);
* a nested dataclass field ``model``: one flag per inner field, ``--model-image-size``;
* a dict of dataclasses (e.g. the sampler's ``phases``): ``--phase NAME.FIELD=VALUE`` (the field's name
  without its plural ``s``), repeatable, and ``--NAME-FIELD VALUE`` per entry field; the entries are those of
  the field's default dict (the sampler's holds every registered phase).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import io
import json
import re
import textwrap
import tokenize
import typing
from typing import Any, Dict, Iterable, Mapping, Optional, Sequence

_SCALARS = (int, float, str)


def field_docs(cls) -> Dict[str, str]:
    """Field name -> its documentation: the string literal under the field, else the comment on its line."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    body = ast.parse(source).body[0].body
    docs = {}
    for node, after in zip(body, list(body[1:]) + [None]):
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        name = node.target.id
        if (isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)):
            docs[name] = inspect.cleandoc(after.value.value)
            continue
        line = lines[node.end_lineno - 1]
        comment = _trailing_comment(line)
        if comment:
            docs[name] = comment
    return docs


def _trailing_comment(line: str) -> str:
    """The ``# comment`` at the end of a source line, if any (a ``#`` inside a string does not count)."""
    try:
        for tok in tokenize.generate_tokens(io.StringIO(line.strip() + "\n").readline):
            if tok.type == tokenize.COMMENT:
                return tok.string.lstrip("#").strip()
    except (tokenize.TokenError, IndentationError, SyntaxError):
        pass
    return ""


def first_sentence(doc: str) -> str:
    """The first sentence of ``doc`` on one line (all of its first paragraph when it has no sentence end)."""
    text = " ".join(doc.split("\n\n")[0].split())
    end = re.search(r"(?<!e\.g)(?<!i\.e)\. ", text)  # an abbreviation's full stop ends no sentence
    return text[: end.start() + 1] if end else text


def config_fields(cls) -> list:
    """The dataclass fields of ``cls`` that a command line can set (``init=True``)."""
    return [f for f in dataclasses.fields(cls) if f.init]


@functools.lru_cache(maxsize=None)
def default_instance(cls):
    """``cls()`` (its ``__post_init__`` normalises the defaults), or None when it needs arguments; read-only."""
    try:
        return cls()
    except TypeError:
        return None


def field_default(cls, f: dataclasses.Field) -> Any:
    """The default value of field ``f`` of ``cls`` as a plain ``cls()`` holds it."""
    instance = default_instance(cls)
    if instance is not None:
        return getattr(instance, f.name)
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def field_type(cls, f: dataclasses.Field) -> Any:
    """The annotation of field ``f`` resolved to a type (Optional unwrapped), or the default's type."""
    try:
        hint = typing.get_type_hints(cls).get(f.name, Any)
    except Exception:  # an annotation that does not resolve at run time: fall back to the default
        hint = Any
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is typing.Union and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        hint = rest[0] if len(rest) == 1 else Any
    if hint is Any:
        default = field_default(cls, f)
        hint = type(default) if default is not None else str
    return hint


def _base(hint) -> Any:
    """``tuple`` for ``tuple[int, ...]``, ``dict`` for ``dict[str, X]``, else the type itself."""
    return typing.get_origin(hint) or hint


def _element_type(hint, default) -> type:
    """The type of a tuple field's elements: from ``tuple[int, ...]``, else from the default's first element."""
    args = [a for a in typing.get_args(hint) if a is not Ellipsis]
    if args and args[0] in _SCALARS:
        return args[0]
    if default:
        first = next(iter(default))
        if type(first) in _SCALARS:
            return type(first)
    return str


def _entry_types(hint, default) -> Optional[Dict[str, type]]:
    """For a dict-of-dataclasses field: entry name -> its dataclass, from the field's default dict."""
    if _base(hint) is dict and isinstance(default, dict) and default:
        if all(dataclasses.is_dataclass(v) and not isinstance(v, type) for v in default.values()):
            return {name: type(v) for name, v in default.items()}
    return None


def _flag(prefix: str, name: str) -> str:
    return "--" + prefix + name.replace("_", "-")


def _singular(name: str) -> str:
    """``phases`` -> ``phase``: the flag of a dict field sets one entry at a time."""
    return name[:-1] if name.endswith("s") and len(name) > 1 else name


def _dest(outer: str, name: str) -> str:
    return f"{outer}.{name}" if outer else name


def _format(value) -> str:
    """A default as a user would type it on the command line."""
    if isinstance(value, (tuple, list)):
        return " ".join(map(str, value)) if value else "none"
    if isinstance(value, dict):
        return json.dumps(value) if value else "{}"
    return str(value)


def _help(doc: str, defaults: Mapping[str, Any]) -> str:
    """One line of help: the field's first sentence and its default (per preset where they differ)."""
    text = first_sentence(doc) if doc else ""
    values = list(defaults.values())
    if values and all(v == values[0] for v in values):
        shown = f"default: {_format(values[0])}"
    else:
        shown = "default: " + ", ".join(f"{_format(v)} ({p})" for p, v in defaults.items())
    return (f"{text} ({shown})" if text else f"({shown})").replace("%", "%%")


def _json_object(text: str) -> dict:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise argparse.ArgumentTypeError(f"expected a JSON object, e.g. '{{\"key\": 1}}': {err}")
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


def _option_kwargs(f, hint, default) -> dict:
    """argparse keyword arguments for a scalar, bool, tuple or dict field."""
    base = _base(hint)
    if base is bool:
        return dict(action=argparse.BooleanOptionalAction)
    if base in (tuple, list):
        return dict(nargs="*", type=_element_type(hint, default), metavar=f.name.upper())
    if base is dict:
        return dict(type=_json_object, metavar="JSON")
    return dict(type=base if base in _SCALARS else str, metavar=f.name.upper())


def add_dataclass_args(parser, cls, prefix: str = "", skip: Iterable[str] = (), aliases: Optional[Mapping] = None,
                       choices: Optional[Mapping] = None, presets: Optional[Mapping[str, Any]] = None) -> None:
    """Add a ``--field-name`` flag (default None) for every field of dataclass ``cls`` not in ``skip``.

    ``prefix`` goes before every flag (``"model-"``); ``aliases`` maps a field (``"model.modalities"`` for a nested
    one, ``"phases.face.depth"`` for an entry's) to extra flags that keep working; ``choices`` a field to its allowed
    values; ``presets`` a preset name to its config instance (the help shows each preset's default where they
    differ). An entry of a dict-of-dataclasses field gets ``--<entry>-<field>`` flags for its fields too.
    """
    spec = _Spec(frozenset(skip), dict(aliases or {}), dict(choices or {}))
    _add(parser, cls, prefix, "", spec, dict(presets or {"": default_instance(cls)}))


@dataclasses.dataclass(frozen=True)
class _Spec:
    """What ``add_dataclass_args`` was told besides the class."""

    skip: frozenset
    aliases: dict
    choices: dict


def _add(parser, cls, prefix: str, outer: str, spec: _Spec, presets: dict) -> None:
    """``add_dataclass_args`` below a nested field ``outer`` (its dests are ``outer.field``)."""
    docs = field_docs(cls)
    for f in config_fields(cls):
        key = _dest(outer, f.name)
        if f.name in spec.skip or key in spec.skip:
            continue
        hint, default = field_type(cls, f), field_default(cls, f)
        values = {p: getattr(c, f.name) for p, c in presets.items() if c is not None}
        flags = [_flag(prefix, f.name), *spec.aliases.get(key, ())]
        if dataclasses.is_dataclass(hint):
            _add(parser, hint, f"{prefix}{f.name.replace('_', '-')}-", key, spec, values)
            continue
        types = _entry_types(hint, default)
        if types is not None:
            flags[0] = _flag(prefix, _singular(f.name))
            parser.add_argument(*flags, dest=key, action="append", metavar="NAME.FIELD=VALUE",
                                help=_entries_help(docs.get(f.name, ""), types, flags[0]))
            for name, entry_cls in types.items():
                _add_entry(parser, entry_cls, f"{prefix}{name.replace('_', '-')}-", f"{key}.{name}", spec)
            continue
        _add_option(parser, flags, key, _option_kwargs(f, hint, default), spec,
                    _help(docs.get(f.name, ""), values or {"": default}))


def _add_entry(parser, entry_cls, prefix: str, outer: str, spec: _Spec) -> None:
    """Flags ``--<entry>-<field>`` for one entry of a dict-of-dataclasses field (dests ``field.entry.inner``)."""
    docs = field_docs(entry_cls)
    for f in config_fields(entry_cls):
        key = _dest(outer, f.name)
        hint, default = field_type(entry_cls, f), field_default(entry_cls, f)
        flags = [_flag(prefix, f.name), *spec.aliases.get(key, ())]
        help_text = _help(docs.get(f.name, ""), {"": default})
        _add_option(parser, flags, key, _option_kwargs(f, hint, default), spec, help_text)


def _add_option(parser, flags: list, key: str, kwargs: dict, spec: _Spec, help_text: str) -> None:
    if key in spec.choices:
        kwargs["choices"] = list(spec.choices[key])
        kwargs.pop("metavar", None)
    parser.add_argument(*flags, dest=key, default=None, help=help_text, **kwargs)


def _entries_help(doc: str, types: Mapping[str, type], flag: str) -> str:
    """Help of a dict-of-dataclasses flag: what it does and the entries it takes."""
    head = f"{first_sentence(doc)} " if doc else ""
    return (f"{head}{flag} NAME.FIELD=VALUE sets one field of one entry (repeatable), as --NAME-FIELD VALUE "
            f"does. Entries: {', '.join(types)}").replace("%", "%%")


def overrides_from_args(args: argparse.Namespace, cls, prefix: str = "", skip: Iterable[str] = ()) -> dict:
    """``{field: value}`` for the flags of ``add_dataclass_args(parser, cls, ...)`` given on the command line.

    A nested dataclass field gives ``{field: {inner: value}}``, a dict of dataclasses
    ``{field: {entry: {inner: value}}}``; ``apply_overrides`` merges either into a config.
    """
    return _overrides(vars(args), cls, "", frozenset(skip))


def _overrides(values: dict, cls, outer: str, skip) -> dict:
    out = {}
    for f in config_fields(cls):
        key = _dest(outer, f.name)
        if f.name in skip or key in skip:
            continue
        hint = field_type(cls, f)
        if dataclasses.is_dataclass(hint):
            inner = _overrides(values, hint, key, skip)
            if inner:
                out[f.name] = inner
            continue
        types = _entry_types(hint, field_default(cls, f))
        if types is not None:
            given = _entry_overrides(values, key, types)
            if given:
                out[f.name] = given
            continue
        value = values.get(key)
        if value is not None:
            out[f.name] = tuple(value) if _base(hint) in (tuple, list) else value
    return out


def _entry_overrides(values: dict, key: str, types: Mapping[str, type]) -> dict:
    """``{entry: {field: value}}`` from the ``--<entry>-<field>`` flags and the repeatable ``NAME.FIELD=VALUE`` one."""
    out: Dict[str, dict] = {}
    for name, entry_cls in types.items():
        for f in config_fields(entry_cls):
            value = values.get(f"{key}.{name}.{f.name}")
            if value is not None:
                is_tuple = _base(field_type(entry_cls, f)) in (tuple, list)
                out.setdefault(name, {})[f.name] = tuple(value) if is_tuple else value
    instances = {name: default_instance(t) for name, t in types.items()}
    for name, given in parse_entries(values.get(key) or (), instances, flag=_flag("", _singular(key))).items():
        out.setdefault(name, {}).update(given)
    return out


def parse_entries(items: Sequence[str], entries: Mapping[str, Any], flag: str = "--phase") -> dict:
    """``["face.depth=8", ...]`` -> ``{"face": {"depth": 8}}``, each value converted to the field's type."""
    out: Dict[str, dict] = {}
    for item in items:
        target, sep, text = item.partition("=")
        name, dot, field_name = target.partition(".")
        if not (sep and dot):
            raise ValueError(f"{flag} takes NAME.FIELD=VALUE (e.g. {flag} {_example(entries)}), got {item!r}")
        if name not in entries:
            raise ValueError(f"{flag} {item}: unknown name {name!r}; choose one of {list(entries)}")
        cls = type(entries[name])
        fields = {f.name: f for f in config_fields(cls)}
        if field_name not in fields:
            raise ValueError(f"{flag} {item}: {name} has no field {field_name!r}; its fields: {list(fields)}")
        hint = field_type(cls, fields[field_name])
        out.setdefault(name, {})[field_name] = convert(text, hint, getattr(entries[name], field_name), item)
    return out


def _example(entries: Mapping[str, Any]) -> str:
    name, value = next(iter(entries.items()))
    f = config_fields(type(value))[0]
    return f"{name}.{f.name}={_format(getattr(value, f.name)).replace(' ', ',')}"


def convert(text: str, hint, default=None, context: str = "") -> Any:
    """``text`` as a value of type ``hint``: bools from true/false/on/off/1/0, tuples comma-separated."""
    base = _base(hint)
    try:
        if base is bool:
            lowered = text.strip().lower()
            if lowered not in ("true", "false", "on", "off", "yes", "no", "1", "0"):
                raise ValueError("expected true or false")
            return lowered in ("true", "on", "yes", "1")
        if base in (tuple, list):
            element = _element_type(hint, default)
            return tuple(element(t) for t in text.split(",") if t.strip())
        if base is dict:
            return json.loads(text)
        return (base if base in _SCALARS else str)(text)
    except (ValueError, json.JSONDecodeError) as err:
        raise ValueError(f"{context or text}: cannot read {text!r} as {getattr(base, '__name__', base)} ({err})")


def apply_overrides(config, overrides: Mapping[str, Any]):
    """A copy of dataclass ``config`` with ``overrides`` (as ``overrides_from_args`` returns them) merged in."""
    changes = {}
    fields = {f.name: f for f in config_fields(type(config))}
    for name, value in overrides.items():
        if name not in fields:
            raise ValueError(f"{type(config).__name__} has no field {name!r}; its fields: {sorted(fields)}")
        current = getattr(config, name)
        if dataclasses.is_dataclass(current) and isinstance(value, Mapping):
            value = apply_overrides(current, value)
        else:
            if _entry_types(dict, current) is not None and isinstance(value, Mapping):
                value = {**current, **{k: _entry(current, k, v) for k, v in value.items()}}
        changes[name] = value
    return dataclasses.replace(config, **changes)


def _entry(current: Mapping, name: str, values: Mapping):
    """Entry ``name`` of a dict-of-dataclasses field with ``values`` set."""
    if name not in current:
        raise ValueError(f"unknown entry {name!r}; choose one of {list(current)}")
    return apply_overrides(current[name], values)
