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
A stand-in of the part of ROS 2's ``launch`` / ``launch_ros`` API that the launch file uses.

ROS 2's launch packages have no PyPI wheel (``ros-jazzy-launch`` and ``launch-ros`` do not
exist there; the PyPI project named ``launch`` is an unrelated 2017 tool whose pins cannot
be met), so ``launch/mlsemreg.launch.py`` cannot be run in the venv. These classes take the
same constructor arguments and evaluate the substitutions the way the real ones do
(``LaunchConfiguration``, ``PythonExpression`` with ``eval``, ``IfCondition`` on
``true``/``false``/``1``/``0``, ``ParameterValue`` through YAML, the arguments' defaults),
so a test can ask which processes, with which parameters, a set of launch arguments starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
import sys
import types
from typing import Any

import yaml


@dataclass
class Context:
    """The launch arguments, the environment and the packages' share folders."""

    arguments: dict[str, str]
    environment: dict[str, str] = field(default_factory=dict)
    shares: dict[str, str] = field(default_factory=dict)


def perform(value: Any, context: Context) -> Any:
    """Evaluate a substitution, a list of them (concatenated) or a plain value."""
    if isinstance(value, (list, tuple)):
        return ''.join(str(perform(v, context)) for v in value)
    if hasattr(value, 'perform'):
        return value.perform(context)
    return value


class LaunchConfiguration:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: Context) -> str:
        if self.name not in context.arguments:
            raise KeyError(f'launch configuration {self.name!r} is not set')
        return context.arguments[self.name]


class EnvironmentVariable:
    def __init__(self, name: str, default_value: Any = '') -> None:
        self.name, self.default_value = name, default_value

    def perform(self, context: Context) -> str:
        if self.name in context.environment:
            return context.environment[self.name]
        return str(perform(self.default_value, context))


class PathJoinSubstitution:
    def __init__(self, parts: list[Any]) -> None:
        self.parts = parts

    def perform(self, context: Context) -> str:
        return os.path.join(*(str(perform(p, context)) for p in self.parts))


class PythonExpression:
    def __init__(self, expression: list[Any]) -> None:
        self.expression = expression

    def perform(self, context: Context) -> str:
        return str(eval(perform(self.expression, context), {}, {}))


class FindPackageShare:
    def __init__(self, package: str) -> None:
        self.package = package

    def perform(self, context: Context) -> str:
        return context.shares[self.package]


class ParameterValue:
    def __init__(self, value: Any, value_type: type | None = None) -> None:
        self.value, self.value_type = value, value_type

    def perform(self, context: Context) -> Any:
        value = perform(self.value, context)
        if self.value_type is None:
            return value
        parsed = yaml.safe_load(value) if isinstance(value, str) else value
        if not isinstance(parsed, self.value_type):
            raise TypeError(f'{value!r} is not a {self.value_type.__name__}')
        return parsed


class IfCondition:
    def __init__(self, predicate: Any) -> None:
        self.predicate = predicate

    def evaluate(self, context: Context) -> bool:
        text = str(perform(self.predicate, context)).strip().lower()
        if text not in ('true', 'false', '1', '0'):
            raise ValueError(f'IfCondition: {text!r} is not a boolean')
        return text in ('true', '1')


class _Action:
    condition: IfCondition | None = None

    def wanted(self, context: Context) -> bool:
        return self.condition is None or self.condition.evaluate(context)


class DeclareLaunchArgument(_Action):
    def __init__(self, name: str, default_value: Any = None, description: str = '') -> None:
        self.name, self.default_value, self.description = name, default_value, description


class SetEnvironmentVariable(_Action):
    def __init__(self, name: str, value: Any) -> None:
        self.name, self.value = name, value


class ExecuteProcess(_Action):
    def __init__(self, cmd: list[Any], output: str = 'log', condition=None) -> None:
        self.cmd, self.output, self.condition = cmd, output, condition


class Node(_Action):
    def __init__(
        self,
        package: str,
        executable: str,
        name: str | None = None,
        output: str = 'log',
        parameters: list[Any] | None = None,
        remappings: list[tuple[Any, Any]] | None = None,
        arguments: list[Any] | None = None,
        condition=None,
    ) -> None:
        self.package, self.executable, self.name, self.output = package, executable, name, output
        self.parameters = parameters or []
        self.remappings = remappings or []
        self.arguments = arguments or []
        self.condition = condition


class LaunchDescription:
    def __init__(self, entities: list[_Action]) -> None:
        self.entities = list(entities)


@dataclass
class Started:
    """What a launch would start: processes by name, the environment it sets."""

    nodes: dict[str, dict[str, Any]]
    processes: list[list[str]]
    environment: dict[str, str]


def evaluate(description: LaunchDescription, context: Context) -> Started:
    """Walk the description in order, as ``ros2 launch`` does, and return what it starts."""
    arguments = dict(context.arguments)
    context = Context(arguments, dict(context.environment), context.shares)
    declared = set()
    nodes, processes, environment = {}, [], {}
    for entity in description.entities:
        if isinstance(entity, DeclareLaunchArgument):
            declared.add(entity.name)
            if entity.name not in arguments:
                if entity.default_value is None:
                    raise KeyError(f'launch argument {entity.name!r} is required')
                arguments[entity.name] = str(perform(entity.default_value, context))
        elif not entity.wanted(context):
            continue
        elif isinstance(entity, SetEnvironmentVariable):
            value = str(perform(entity.value, context))
            context.environment[entity.name] = environment[entity.name] = value
        elif isinstance(entity, ExecuteProcess):
            processes.append([str(perform(part, context)) for part in entity.cmd])
        elif isinstance(entity, Node):
            parameters = []
            for item in entity.parameters:
                if isinstance(item, dict):
                    parameters.append({k: perform(v, context) for k, v in item.items()})
                else:
                    parameters.append(str(perform(item, context)))
            nodes[entity.name or entity.executable] = {
                'package': entity.package,
                'executable': entity.executable,
                'parameters': parameters,
                'remappings': [
                    (str(perform(a, context)), str(perform(b, context)))
                    for a, b in entity.remappings
                ],
                'arguments': [str(perform(a, context)) for a in entity.arguments],
            }
    unknown = set(context.arguments) - declared
    if unknown:
        raise KeyError(f'not declared by the launch file: {sorted(unknown)}')
    return Started(nodes, processes, environment)


def install(monkeypatch) -> None:
    """Put the stand-in modules where the launch file imports them from (``sys.modules``)."""
    here = sys.modules[__name__]
    modules = {
        'launch': [],
        'launch.actions': ['DeclareLaunchArgument', 'ExecuteProcess', 'SetEnvironmentVariable'],
        'launch.conditions': ['IfCondition'],
        'launch.launch_description': ['LaunchDescription'],
        'launch.substitutions': [
            'EnvironmentVariable',
            'LaunchConfiguration',
            'PathJoinSubstitution',
            'PythonExpression',
        ],
        'launch_ros': [],
        'launch_ros.actions': ['Node'],
        'launch_ros.parameter_descriptions': ['ParameterValue'],
        'launch_ros.substitutions': ['FindPackageShare'],
    }
    for name, members in modules.items():
        module = types.ModuleType(name)
        for member in members:
            setattr(module, member, getattr(here, member))
        monkeypatch.setitem(sys.modules, name, module)
