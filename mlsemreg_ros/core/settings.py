# Copyright 2026 The mlsemreg_ros Authors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
The settings engine: declared parameters, their checks, files and ``--set`` overrides.

A settings class is a dataclass of sections (dataclasses of :func:`param` fields) and
top-level fields. Every field carries its description, unit, range and choices, so the
ROS layer declares parameters with descriptors from them, and ``config/params.yaml``
and docs/parameters.md are generated from the same metadata. The core's sections are
assembled in :mod:`mlsemreg_ros.core.config`; a new component declares its own section
beside its code with :func:`param` and adds one field there (docs/extending.md).
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from dataclasses import field
import math
from pathlib import Path
import re
from typing import Any, ClassVar, overload, Self, TypeVar

import yaml

#: Top-level key of the node's parameter file (``config/params.yaml``).
NODE_NAME = 'mlsemreg_node'


class ConfigError(ValueError):
    """A configuration value is unknown, of the wrong type or out of range."""


class _Loader(yaml.SafeLoader):
    """YAML with YAML 1.2 booleans: only true/false, so ``fine.method: off`` is a string."""


_Loader.yaml_implicit_resolvers = {
    key: [(tag, regexp) for tag, regexp in resolvers if tag != 'tag:yaml.org,2002:bool']
    for key, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    'tag:yaml.org,2002:bool', re.compile(r'^(?:true|True|TRUE|false|False|FALSE)$'), list('tTfF')
)


def load_yaml(text: str) -> Any:
    """Parse YAML text with YAML 1.2 booleans (``on``/``off``/``yes``/``no`` stay strings)."""
    return yaml.load(text, Loader=_Loader)  # a SafeLoader subclass


def param(
    default: Any,
    description: str,
    *,
    unit: str = '',
    low: float | None = None,
    high: float | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """Declare a config field with the metadata the ROS layer turns into a descriptor."""
    meta = {'description': description, 'unit': unit, 'low': low, 'high': high, 'choices': choices}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


class Settings:
    """
    A dataclass of parameters: top-level fields and sections (dataclass-typed fields).

    The one engine behind the core's :class:`RegistrationConfig` and the node's settings:
    flat names are ``field`` or ``section.field``; every field is declared with
    :func:`param` (description, unit, range, choices), so the ROS layer, the parameter
    file and docs/parameters.md are generated from the same metadata. Unknown and removed
    names are rejected with the reason; values are type-checked, range-checked and
    cross-checked (:meth:`check`) as a whole.
    """

    #: Removed flat names and what replaced them.
    REMOVED: ClassVar[dict[str, str]] = {}

    # -- structure -----------------------------------------------------------------
    @classmethod
    def sections(cls) -> dict[str, type]:
        """Section name -> dataclass, in declaration order."""
        return {
            f.name: f.default_factory
            for f in dataclasses.fields(cls)
            if dataclasses.is_dataclass(f.default_factory)
        }

    @classmethod
    def top_level_names(cls) -> set[str]:
        """Names of the top-level fields and sections (the keys of a parameter file)."""
        return {f.name for f in dataclasses.fields(cls)}

    @classmethod
    def parameter_fields(cls) -> list[tuple[str, dataclasses.Field, Any]]:
        """``(flat_name, field, default)`` of every parameter, in declaration order."""
        defaults = cls().to_flat_dict()
        return [(key, cls.field_of(key), value) for key, value in defaults.items()]

    @classmethod
    def field_of(cls, key: str) -> dataclasses.Field:
        """Return the field behind a flat name; ConfigError (with the reason) otherwise."""
        section, dot, name = key.partition('.')
        owner = cls.sections().get(section) if dot else cls
        if owner is not None:
            for f in dataclasses.fields(owner):
                if f.name == (name if dot else key) and (dot or f.name not in cls.sections()):
                    return f
        if key in cls.REMOVED:
            raise ConfigError(f'parameter {key!r} was removed: {cls.REMOVED[key]}')
        raise ConfigError(f'unknown parameter {key!r}')

    # -- construction --------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Self:
        """Build from a nested mapping (``{'semantic': {...}, 'threads': 2}``)."""
        flat: dict[str, Any] = {}
        sections = cls.sections()
        for key, value in data.items():
            if key in sections:
                if not isinstance(value, dict):
                    raise ConfigError(f'section {key!r} must be a mapping')
                flat.update({f'{key}.{name}': v for name, v in value.items()})
            elif isinstance(value, dict):
                raise ConfigError(f'unknown config section {key!r}; known: {sorted(sections)}')
            else:
                flat[key] = value
        return cls().replace(flat)

    @classmethod
    def from_file(cls, path: str | Path) -> Self:
        """
        Build from a parameter YAML: the node layout (``config/params.yaml``) or a plain mapping.

        Only this class's keys are read; the keys of the other settings in the same file
        (node-level keys for the core, ``use_sim_time``, ...) are left to their readers.
        """
        data = read_parameter_file(path)
        return cls.from_dict({k: v for k, v in data.items() if k in cls.top_level_names()})

    def replace(self, flat: dict[str, Any]) -> Self:
        """Copy with ``{'flat.name': value}`` applied, type-checked and validated."""
        values = self.to_flat_dict()
        for key, value in flat.items():
            values[key] = coerce(key, value, self.field_of(key))
        sections = self.sections()
        top = {k: v for k, v in values.items() if '.' not in k}
        parts = {
            s: kind(
                **{k.partition('.')[2]: v for k, v in values.items() if k.partition('.')[0] == s}
            )
            for s, kind in sections.items()
        }
        new = type(self)(**top, **parts)
        errors = new.errors()
        if errors:
            raise ConfigError('; '.join(errors))
        return new

    # -- export --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict (YAML/JSON friendly)."""
        return {
            f.name: (
                dataclasses.asdict(getattr(self, f.name))
                if f.name in self.sections()
                else getattr(self, f.name)
            )
            for f in dataclasses.fields(self)
        }

    def to_flat_dict(self) -> dict[str, Any]:
        """``{'field' or 'section.field': value}`` for every parameter."""
        out: dict[str, Any] = {}
        for key, value in self.to_dict().items():
            if isinstance(value, dict):
                out.update({f'{key}.{k}': v for k, v in value.items()})
            else:
                out[key] = value
        return out

    # -- validation ----------------------------------------------------------------
    def errors(self) -> list[str]:
        """Every range, choice and cross-field violation, as readable sentences."""
        return [
            e
            for key, value in self.to_flat_dict().items()
            for e in metadata_errors(key, value, self.field_of(key).metadata)
        ] + self.check()

    def check(self) -> list[str]:
        """Cross-field rules (none by default)."""
        return []


#: Any settings class of this engine (the argument and result of :func:`apply_overrides`).
SettingsT = TypeVar('SettingsT', bound=Settings)


def metadata_errors(key: str, value: Any, meta: Any) -> list[str]:
    """Check one value against its field metadata (choices, low, high)."""
    errors = []
    if meta['choices'] is not None and value not in meta['choices']:
        errors.append(f'{key}={value!r} is not one of {list(meta["choices"])}')
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if meta['low'] is not None and value < meta['low']:
            errors.append(f'{key}={value} is below its minimum {meta["low"]}')
        if meta['high'] is not None and value > meta['high']:
            errors.append(f'{key}={value} is above its maximum {meta["high"]}')
    return errors


def coerce(key: str, value: Any, f: dataclasses.Field) -> Any:
    """Check and convert one value to the field's type (ints accepted for floats)."""
    kind = f.type if isinstance(f.type, str) else getattr(f.type, '__name__', str(f.type))
    if kind == 'bool':
        if isinstance(value, bool):
            return value
    elif kind == 'int':
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif kind == 'float':
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(float(value)):
                raise ConfigError(f'{key} must be finite, got {value!r}')
            return float(value)
    elif kind == 'str':
        if isinstance(value, str):
            return value
    elif kind == 'list[str]':
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return list(value)
    raise ConfigError(f'{key} expects {kind}, got {type(value).__name__} {value!r}')


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """
    ``['section.key=value', ...]`` -> ``{'section.key': value}``, values parsed as YAML.

    The one parser of every tool's ``--set``: ``--set semantic.enabled=false
    --set keypoints.count=5000 --set semantic.landmark_classes=[pole,trunk]``.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition('=')
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f'--set expects KEY=VALUE, got {item!r}')
        try:
            out[key] = load_yaml(value) if value.strip() else ''
        except yaml.YAMLError as error:
            raise ConfigError(f'--set {key}: cannot parse {value!r}: {error}') from None
    return out


def _owner(parts: Sequence[Settings], key: str) -> int:
    """Index of the settings that declare ``key``; ConfigError (with the reason) if none."""
    for i, part in enumerate(parts):
        try:
            part.field_of(key)
        except ConfigError:
            continue
        return i
    for part in parts:
        if key in part.REMOVED:
            raise ConfigError(f'parameter {key!r} was removed: {part.REMOVED[key]}')
    raise ConfigError(f'unknown parameter {key!r}')


@overload
def apply_overrides(config: SettingsT, items: Sequence[str]) -> SettingsT: ...


@overload
def apply_overrides(
    config: tuple[Settings, ...], items: Sequence[str]
) -> tuple[Settings, ...]: ...


def apply_overrides(
    config: Settings | tuple[Settings, ...], items: Sequence[str]
) -> Settings | tuple[Settings, ...]:
    """
    Apply ``['section.key=value', ...]`` (every tool's ``--set``) to settings; return a copy.

    ``config`` is one :class:`Settings` (e.g. :class:`RegistrationConfig`) or a tuple of
    settings with disjoint names (e.g. the core, the node's and the evaluation's): each
    key goes to the one that declares it and an unknown key is an error. Values are
    parsed as YAML (:func:`parse_overrides`), then type-, range- and cross-checked.
    """
    flat = parse_overrides(list(items))
    if isinstance(config, Settings):
        return config.replace(flat) if flat else config
    parts = tuple(config)
    changes: list[dict[str, Any]] = [{} for _ in parts]
    for key, value in flat.items():
        changes[_owner(parts, key)][key] = value
    return tuple(
        part.replace(change) if change else part
        for part, change in zip(parts, changes, strict=True)
    )


def read_parameter_file(path: str | Path) -> dict[str, Any]:
    """
    Read a parameter YAML as a nested mapping.

    Accepts the ROS layout ``{mlsemreg_node: {ros__parameters: {...}}}`` or a plain
    mapping of sections and top-level fields.
    """
    try:
        data = load_yaml(Path(path).read_text()) or {}
    except yaml.YAMLError as error:
        raise ConfigError(f'{path}: not valid YAML: {error}') from None
    if not isinstance(data, dict):
        raise ConfigError(f'{path}: expected a mapping of parameters')
    if NODE_NAME in data:
        data = (data[NODE_NAME] or {}).get('ros__parameters', {}) or {}
    return data
