"""Reading a case: the line-recording YAML loader (with its guards against duplicate keys, deep nesting
and alias bombs), the key paths and lines of messages, and the ``--set`` changes of a loaded mapping."""

from __future__ import annotations

import math
import numbers
import os
import re
import sys
import typing
from collections.abc import Mapping

import yaml

from ..errors import CaseError, type_name, wrong_type

# --- YAML -------------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 core-schema booleans, integers and floats (``70e9`` is a number)."""


_TAG = "tag:yaml.org,2002:"
# Copy the resolver table without the YAML 1.1 bool/int/float/timestamp rules so the global
# SafeLoader is untouched and `010` is ten, `on` a string and `1e-3` a float.
_Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers
            if tag not in (_TAG + "bool", _TAG + "int", _TAG + "float", _TAG + "timestamp")]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(_TAG + "bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                              list("tTfF"))
_Loader.add_implicit_resolver(_TAG + "int", re.compile(r"^[-+]?[0-9]+$"), list("-+0123456789"))
_Loader.add_implicit_resolver(
    _TAG + "float",
    re.compile(r"""^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.?(?:inf|Inf|INF)|\.?(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789.iInN"))


def _construct_int(loader, node):
    text = loader.construct_scalar(node)
    try:
        return int(text)
    except ValueError:   # (Python reads integers of at most sys.get_int_max_str_digits() digits)
        raise yaml.constructor.ConstructorError(
            None, None, f"an integer of {len(text.lstrip('+-'))} digits, more than Python reads "
                        f"({sys.get_int_max_str_digits()})", node.start_mark) from None


_Loader.add_constructor(_TAG + "int", _construct_int)


def yaml_value(text: str):
    """One value typed as in a case file (YAML 1.2: ``2.5e3`` is a number); raises yaml.YAMLError.

    The same guards as a case file: no duplicate keys, no deep nesting, no alias bombs.
    """
    try:
        return _parse_yaml(text, "--set")[0]
    except CaseError as exc:
        raise yaml.YAMLError(f"{exc.key}: {exc.message}" if exc.key else exc.message) from None


# A case file is a few hundred values a few levels deep: far beyond these, it is a mistake or an attack.
MAX_DEPTH = 64
MAX_VALUES = 100_000


def _expanded_size(node, memo) -> int:
    """Values a node stands for once its aliases are expanded (an alias counts as often as it is used)."""
    key = id(node)
    if key not in memo:
        memo[key] = 0   # (a recursive alias counts nothing the second time)
        if isinstance(node, yaml.MappingNode):
            memo[key] = 1 + sum(_expanded_size(k, memo) + _expanded_size(v, memo) for k, v in node.value)
        elif isinstance(node, yaml.SequenceNode):
            memo[key] = 1 + sum(_expanded_size(item, memo) for item in node.value)
        else:
            memo[key] = 1
    return memo[key]


def _parse_yaml(text, file):
    """Return (node tree, data) of a YAML document; syntax errors become CaseError with the line."""
    loader = None
    try:
        loader = _Loader(text)
        node = loader.get_single_node()
        lines = {}
        if node is not None:
            _record_lines(node, (), lines, set(), file)  # before construction flattens merge keys
            size = _expanded_size(node, {})
            if size > MAX_VALUES:
                raise CaseError(file, None, None, f"the document stands for {size:.3g} values once its aliases "
                                                  f"(*name) are expanded, more than {MAX_VALUES}")
        return loader.construct_document(node) if node is not None else None, lines
    except RecursionError:
        raise CaseError(file, None, None, f"the YAML is nested too deeply (at most {MAX_DEPTH} levels)") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = " ".join(str(exc.problem or exc.context).split())
        raise CaseError(file, None, mark.line + 1 if mark else None,
                        f"invalid YAML: {problem}") from None
    except yaml.YAMLError as exc:
        raise CaseError(file, None, None, f"invalid YAML: {' '.join(str(exc).split())}") from None
    finally:
        if loader is not None:
            loader.dispose()


def _record_lines(node, path, lines, seen, file, ancestors=frozenset()):
    """Record the line of every mapping key and sequence item under `path`; reject duplicate keys and
    an alias inside its own anchor (a value that would contain itself)."""
    if id(node) in ancestors:
        raise CaseError(file, _dotted(path) or None, node.start_mark.line + 1 if file != "--set" else None,
                        "an alias (*name) inside its own anchor (&name): the value would contain itself")
    if id(node) in seen:  # an alias: its lines were recorded where the anchor is
        return
    seen.add(id(node))
    ancestors = ancestors | {id(node)}
    if len(path) > MAX_DEPTH:
        raise CaseError(file, _dotted(path[:3]) + ".(...)", node.start_mark.line + 1,
                        f"nested more than {MAX_DEPTH} levels deep")
    if isinstance(node, yaml.ScalarNode) and _not_text(node.value):
        raise CaseError(file, _dotted(path) or None, node.start_mark.line + 1 if file != "--set" else None,
                        f"holds a character that is not text ({_not_text(node.value)}: half of a UTF-16 pair, "
                        "from an escape such as \\uD800)")
    if isinstance(node, yaml.MappingNode):
        keys = set()
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else id(key_node)
            line = key_node.start_mark.line + 1
            if isinstance(key, str) and _not_text(key):
                raise CaseError(file, _dotted(path) or None, line if file != "--set" else None,
                                f"a key holds a character that is not text ({_not_text(key)}: half of a UTF-16 "
                                "pair, from an escape such as \\uD800)")
            if key in keys:
                raise CaseError(file, _dotted(path + (key,)), line, "duplicate key")
            keys.add(key)
            lines[path + (key,)] = line
            _record_lines(value_node, path + (key,), lines, seen, file, ancestors)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            lines[path + (index,)] = item.start_mark.line + 1
            _record_lines(item, path + (index,), lines, seen, file, ancestors)


def _not_text(text: str) -> str:
    """The first lone surrogate in ``text`` as an escape (``\\ud800``), or "" (a YAML escape may make one;
    no file, message or output can hold it)."""
    for char in text:
        if "\ud800" <= char <= "\udfff":
            return f"\\u{ord(char):04x}"
    return ""


# --- errors -----------------------------------------------------------------------------


class _Invalid(ValueError):
    """A validation failure at a key path, turned into a CaseError once file and lines are known.

    Raised inside a schema's validator, its path is relative to the key being validated.
    """

    def __init__(self, path, message):
        super().__init__(message)
        self.path, self.message = tuple(path), message


def _dotted(path):
    """Key path as text: ``("contacts", 0, "normal")`` -> ``"contacts[0].normal"``."""
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else f".{part}" if text else str(part)
    return text


def _display(path):
    """The case file as shown in messages: relative to the current folder when inside it."""
    relative = os.path.relpath(path)
    return str(path) if relative.startswith("..") else relative


def _error(file, lines, overrides, path, message):
    """CaseError for `path`: its line (or the nearest ancestor's), or the --set option that gave it."""
    for prefix, origin in overrides.items():
        if path[:len(prefix)] == prefix:
            shown = origin if origin.isprintable() else repr(origin)   # (one line: no raw newline)
            shown = shown if len(shown) <= 100 else f"{shown[:80]}... ({len(shown)} characters)"
            return CaseError(file, _dotted(path) or None, None, f"{message} (from {shown})")
    line = next((lines[path[:n]] for n in range(len(path), 0, -1) if path[:n] in lines), None)
    return CaseError(file, _dotted(path) or None, line, message)


# --- overrides --------------------------------------------------------------------------


def _apply_override(data, option):
    """Apply one ``KEY.PATH=VALUE`` option to `data` in place and return the key path."""
    key, equals, text = option.partition("=")
    segments = key.strip().split(".")
    if not equals or not all(segments):
        raise CaseError("--set", None, None, f"expected KEY.PATH=VALUE, got {option!r}")
    try:
        value = yaml_value(text)
    except yaml.YAMLError as exc:
        raise CaseError("--set", key, None, f"cannot read the value {_brief(text)}: "
                        f"{' '.join(str(getattr(exc, 'problem', exc)).split())}") from None
    return _set_key(data, key.strip(), value, "--set")


def _set_key(data, key: str, value, origin: str):
    """Set the dotted ``key`` of `data` (in place) to `value`; returns the key path.

    Missing mappings on the way are created; a list item is named by its index. `origin`
    names the change in errors (``"--set"``, or the change of ``Case.with_changes``).
    """
    segments = key.split(".")
    if not all(segments):
        raise CaseError(origin, None, None, f"expected a dotted key path, got {key!r}")
    target, path = data, ()
    for depth, segment in enumerate(segments, 1):
        if isinstance(target, list):
            if not segment.isdigit() or int(segment) >= len(target):
                raise CaseError(origin, _dotted(path + (segment,)), None,
                                f"no item {segment}: {_dotted(path)} has {len(target)} items")
            segment = int(segment)
        elif not isinstance(target, dict):
            raise CaseError(origin, _dotted(path), None, f"is not a mapping or a list; cannot set {key}")
        path += (segment,)
        if depth == len(segments):
            try:
                target[segment] = _plain(value, path)
            except _Invalid as exc:
                raise CaseError(origin, _dotted(exc.path), None, exc.message) from None
        else:
            if isinstance(target, dict) and target.get(segment) is None:
                target[segment] = {}
            target = target[segment]
    return path


def _show(value):
    """A value as quoted in a message."""
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return "null" if value is None else _brief(value)


def _brief(value) -> str:
    """A value's repr for a message, shortened; an integer too long to print (or to read) by its magnitude."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**30:
        return f"an integer of about {'-' if value < 0 else ''}1e+{round(math.log10(abs(value)))}"
    try:
        text = repr(value)
    except Exception:   # (an object of a script whose repr fails)
        text = f"<{type_name(value)}>"
    return text if len(text) <= 80 else f"{text[:60]}...{text[-10:]} ({len(text)} characters)"


def _plain(value, path):
    """A script's value as the YAML of a case file gives it (a copy): numpy numbers and arrays, tuples, paths
    and other mappings become Python numbers, lists, strings and dicts; anything else is left for the
    validation to refuse. Nested deeper than a case file may be: _Invalid."""
    if len(path) > MAX_DEPTH:
        raise _Invalid(path[:3] + ("(...)",), f"nested more than {MAX_DEPTH} levels deep")
    if type(value) is str and _not_text(value):
        raise _Invalid(path, f"holds a character that is not text ({_not_text(value)}: half of a UTF-16 pair)")
    if value is None or type(value) in (str, bool, int, float):
        return value
    if isinstance(value, Mapping):
        return {str(key) if isinstance(key, str) else key: _plain(item, path + (key,)) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item, path + (index,)) for index, item in enumerate(value)]
    if isinstance(value, (str, os.PathLike)):
        return os.fspath(str(value) if isinstance(value, str) else value)
    if hasattr(value, "dtype") and hasattr(value, "tolist"):   # numpy scalars and arrays
        return _plain(value.tolist(), path)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    return value


def _path_argument(call: str, takes: str, value) -> str:
    """A path argument of the API as text; TypeError naming what `call` takes otherwise."""
    try:
        text = os.fspath(value)
    except TypeError:
        text = None
    if not isinstance(text, str):
        raise wrong_type(call, takes, value)
    return text


def _strings(call: str, takes: str, values) -> list[str]:
    """An iterable of strings (not a string itself) as a list; TypeError naming what `call` takes otherwise."""
    if isinstance(values, (str, bytes, Mapping)) or not isinstance(values, typing.Iterable):
        raise wrong_type(call, takes, values)
    values = list(values)
    wrong = next((value for value in values if not isinstance(value, str)), None)
    if wrong is not None:
        raise TypeError(f"{call} takes {takes}, got a {type_name(values if isinstance(values, list) else values)} "
                        f"holding {type_name(wrong)}")
    return values


