"""``NAME=VALUE`` overrides of dataclass configs (the ``--set`` option of every command): values parsed as
JSON where they are JSON, dotted names into nested dataclasses, the copy validated by its class."""

from __future__ import annotations

import dataclasses
import json
import typing
from typing import Any, Iterable, Mapping, TypeVar, Union

D = TypeVar("D")

Overrides = Union[Mapping[str, Any], Iterable[tuple[str, Any]]]


def parse_value(text: str) -> Any:
    """``text`` parsed as a JSON value, or ``text`` itself (stripped) where it is not JSON."""
    text = text.strip()
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def parse_assignment(item: str) -> tuple[str, Any]:
    """``"NAME=VALUE"`` -> ``(NAME, parse_value(VALUE))``, split at the first ``=``; ``NAME`` is a dotted
    identifier (``task.rod.mass_kg``), else ``ValueError`` quoting ``item``."""
    name, sep, value = item.partition("=")
    name = name.strip()
    if not sep or not name or not all(part.isidentifier() for part in name.split(".")):
        raise ValueError(f"--set expects NAME=VALUE with NAME a (dotted) Python identifier, got {item!r}")
    return name, parse_value(value)


def _holds_tuple(instance: Any, name: str) -> bool:
    """Whether field ``name`` of ``instance`` is a tuple field (by its current value or its annotation)."""
    if isinstance(getattr(instance, name, None), tuple):
        return True
    try:
        hint = typing.get_type_hints(type(instance)).get(name)
    except Exception:  # an annotation that cannot be resolved
        return False
    candidates = typing.get_args(hint) if typing.get_origin(hint) is Union else (hint,)
    return any(c is tuple or typing.get_origin(c) is tuple for c in candidates)


def _as_tuple(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(value)
    if isinstance(value, str) and "," in value:  # the comma form "0,1" of a tuple of JSON values
        return tuple(parse_value(part) for part in value.split(",") if part.strip())
    if isinstance(value, (bool, int, float, str)):  # one element: 5 -> (5,)
        return (value,)
    return value


def apply_overrides(instance: D, overrides: Overrides, *, prefix: str = "") -> D:
    """A validated copy of the dataclass ``instance`` with the fields named in ``overrides`` (a mapping or pairs)
    replaced: ``a.b`` (or a dict for ``a``) reaches into a nested dataclass, a list, ``"0,1"`` or a single value for
    a tuple field becomes a tuple; ``prefix`` is ``instance``'s dotted path in messages."""
    if not dataclasses.is_dataclass(instance) or isinstance(instance, type):
        raise ValueError(f"apply_overrides needs a dataclass instance, got {type(instance).__name__}")
    items = overrides.items() if isinstance(overrides, Mapping) else overrides
    fields = [f.name for f in dataclasses.fields(instance) if f.init]
    direct, nested = dict[str, Any](), dict[str, dict[str, Any]]()
    for name, value in items:
        head, _, rest = str(name).partition(".")
        if head not in fields:
            raise ValueError(f"unknown {type(instance).__name__} field {prefix + head!r}; known: {sorted(fields)}")
        if rest or (isinstance(value, dict) and dataclasses.is_dataclass(getattr(instance, head))):
            nested.setdefault(head, {}).update({rest: value} if rest else value)
        else:
            direct[head] = _as_tuple(value) if _holds_tuple(instance, head) else value
    changes = dict(direct)
    for head, sub in nested.items():
        if head in direct:
            raise ValueError(f"{prefix + head!r} is set both whole and through {prefix + head}.<field>")
        inner = getattr(instance, head)
        if not dataclasses.is_dataclass(inner) or isinstance(inner, type):
            first = next(iter(sub))
            raise ValueError(
                f"cannot set {prefix + head}.{first}: {prefix + head} holds a {type(inner).__name__}, not a dataclass"
            )
        changes[head] = apply_overrides(inner, sub, prefix=f"{prefix}{head}.")
    try:
        return dataclasses.replace(instance, **changes)
    except (TypeError, OverflowError, AttributeError) as exc:  # a value of the wrong type met the class's checks
        shown = ", ".join(f"{prefix}{name}={value!r}" for name, value in direct.items()) or "the nested fields"
        raise ValueError(f"{type(instance).__name__}: {shown}: value of the wrong type or size ({exc})") from None


def dataclass_from_data(cls: type[D], data: Any, source: Any, **convert: Any) -> D:
    """The dataclass ``cls`` from JSON data as ``dataclasses.asdict`` gives it: every field present (a one-line
    ``ValueError`` names the first unknown or missing one), lists as tuples, a mapping for a field whose default is a
    dataclass built the same way; ``convert``: field name -> function building that field from its data."""
    if not isinstance(data, Mapping):
        raise ValueError(f"{source}: expected a JSON object for a {cls.__name__}, got {type(data).__name__}")
    factories = {f.name: f.default_factory for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown, missing = [k for k in data if k not in factories], [k for k in factories if k not in data]
    if unknown:
        raise ValueError(f"{source}: {unknown[0]!r} is not a {cls.__name__} field (a config of another version)")
    if missing:
        raise ValueError(f"{source}: the {cls.__name__} field {missing[0]!r} is missing (a config of another version)")

    def build(name: str, value: Any) -> Any:  # nested dataclasses the same way, lists as tuples
        if name in convert:
            return convert[name](value)
        if dataclasses.is_dataclass(factory := factories[name]):
            return dataclass_from_data(factory, value, source)
        return tuple(value) if isinstance(value, list) else value

    return cls(**{name: build(name, data[name]) for name in factories})
