"""Typed, validated configs.

Every component has one frozen dataclass config deriving from :class:`Config`. ``from_dict``
rejects unknown keys and wrong types; each subclass checks its value ranges in ``validate``
and raises :class:`ConfigError` naming the field. ``to_dict`` gives the resolved config that is
written beside every result.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import types
import typing
from typing import Any, TypeVar

C = TypeVar("C", bound="Config")


class ConfigError(ValueError):
    """A config value is missing, unknown, of the wrong type or out of range."""


def _check_type(name: str, value: Any, tp: Any) -> Any:
    origin = typing.get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        errors: list[ConfigError] = []
        for arg in typing.get_args(tp):
            if arg is type(None):
                if value is None:
                    return None
                continue  # a non-None value must match one of the other types
            try:
                return _check_type(name, value, arg)
            except ConfigError as e:
                errors.append(e)
        if len(errors) == 1:  # ``X | None``: X's own message names the bad value
            raise errors[0]
        raise ConfigError(f"config field '{name}': {value!r} is not of type {tp}")
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(
                f"config field '{name}': {value!r} is not one of {typing.get_args(tp)}"
            )
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config field '{name}': expected a sequence, got {value!r}")
        args = typing.get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ConfigError(f"config field '{name}': expected {len(args)} items")
            return tuple(_check_type(name, v, a) for v, a in zip(value, args, strict=True))
        inner = args[0] if args else Any
        return origin(_check_type(name, v, inner) for v in value)
    if isinstance(tp, type) and issubclass(tp, Config):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"config field '{name}': expected a mapping for {tp.__name__}")
        return tp.from_dict(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config field '{name}': expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config field '{name}': expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config field '{name}': expected true/false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"config field '{name}': expected a string, got {value!r}")
        return value
    return value


@dataclasses.dataclass(frozen=True)
class Config:
    """Base class of all component configs."""

    def __post_init__(self) -> None:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            object.__setattr__(self, f.name, _check_type(f.name, v, hints[f.name]))
        self.validate()

    def validate(self) -> None:  # overridden by components
        """Raise :class:`ConfigError` for an out-of-range value."""

    @classmethod
    def from_dict(cls: type[C], data: dict[str, Any] | None) -> C:
        data = dict(data or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(
                f"{cls.__name__}: unknown config key(s) {unknown}; valid keys are {sorted(names)}"
            )
        for f in dataclasses.fields(cls):
            # a mapping for a nested config overrides the field's default, not the nested
            # class's: {"transient": {"grow_share": 0.3}} keeps ObstacleConfig's keep_views 30
            if isinstance(data.get(f.name), dict) and isinstance(f.default, Config):
                data[f.name] = _merged(f.default.to_dict(), data[f.name])
        return cls(**data)

    def replace(self: C, **changes: Any) -> C:
        return type(self).from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = (
                v.to_dict() if isinstance(v, Config) else (list(v) if isinstance(v, tuple) else v)
            )
        return out

    def hash(self) -> str:
        """Short stable hash of the resolved config."""
        blob = json.dumps(self.to_dict(), sort_keys=True).encode()
        return hashlib.sha1(blob).hexdigest()[:12]


def _merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over``'s keys replacing its own, nested mappings merged key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def require(cond: bool, cls_name: str, field: str, msg: str) -> None:
    """Raise a :class:`ConfigError` naming ``cls_name.field`` unless ``cond``."""
    if not cond:
        raise ConfigError(f"{cls_name}.{field}: {msg}")


def json_object(text: str, what: str) -> dict[str, Any]:
    """``text`` parsed as a JSON object (a config given on a command line); a
    :class:`ConfigError` naming ``what`` when it is not JSON or not an object."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(f"{what}: not valid JSON ({e})") from None
    if not isinstance(value, dict):
        raise ConfigError(f"{what}: expected a JSON object, got {text!r}")
    return value
