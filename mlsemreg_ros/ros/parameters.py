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
ROS parameters <-> RegistrationConfig + NodeConfig, validated and applied live.

Every parameter is declared from the config dataclasses' fields (flat name,
default, metadata -> ``ParameterDescriptor``), so no default is copied by hand.
Changes go through the pattern of ros2/demos ``set_parameters_callback.py``:
the on-set callback validates the whole candidate configuration (ranges,
choices, cross-field rules, class names known to the label map) and rejects
with the reason; the post-set callback publishes the new configuration, which
the node's worker picks up at the start of the next frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import threading
from typing import Any

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.ros.node_config import all_parameter_fields, NodeConfig, READ_ONLY
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

_INT64 = (-(2**63), 2**63 - 1)
_TYPES = {
    'bool': Parameter.Type.BOOL,
    'int': Parameter.Type.INTEGER,
    'float': Parameter.Type.DOUBLE,
    'str': Parameter.Type.STRING,
    'list[str]': Parameter.Type.STRING_ARRAY,
}


def _kind(f: dataclasses.Field) -> str:
    return f.type if isinstance(f.type, str) else getattr(f.type, '__name__', str(f.type))


def descriptor_for(
    name: str, f: dataclasses.Field, label_map: LabelMap | None = None
) -> ParameterDescriptor:
    """Build the ParameterDescriptor of a config field (description, unit, range, choices)."""
    meta, kind = f.metadata, _kind(f)
    unit = f' [{meta["unit"]}]' if meta['unit'] else ''
    descriptor = ParameterDescriptor(
        name=name,
        type=_TYPES[kind].value,
        description=meta['description'] + unit,
        read_only=name in READ_ONLY,
    )
    constraints = []
    if meta['choices'] is not None:
        constraints.append('one of: ' + ', '.join(meta['choices']))
    if kind == 'list[str]' and name.endswith('_classes') and label_map is not None:
        constraints.append('class names: ' + ', '.join(label_map.names))
    if name in READ_ONLY:
        constraints.append('read-only: set at startup (parameter file or --ros-args -p)')
    descriptor.additional_constraints = '; '.join(constraints)
    low, high = meta['low'], meta['high']
    if kind == 'float' and (low is not None or high is not None):
        descriptor.floating_point_range = [
            FloatingPointRange(
                from_value=float(low if low is not None else -float('inf')),
                to_value=float(high if high is not None else float('inf')),
                step=0.0,
            )
        ]
    elif kind == 'int' and (low is not None or high is not None):
        descriptor.integer_range = [
            IntegerRange(
                from_value=int(low if low is not None else _INT64[0]),
                to_value=int(high if high is not None else _INT64[1]),
                step=0,
            )
        ]
    return descriptor


@dataclass(frozen=True)
class ConfigSnapshot:
    """The configuration in force; ``version`` grows with every accepted change."""

    core: RegistrationConfig
    node: NodeConfig
    core_version: int


class LiveParameters:
    """
    Declares the node's parameters and keeps the validated configuration up to date.

    Thread-safe: the executor thread sets parameters, the worker reads
    :meth:`snapshot` at the start of each frame.
    """

    def __init__(self, node: Node, label_map: LabelMap) -> None:
        """
        Declare every parameter (overrides from the parameter file win) and validate.

        Raises ConfigError when the startup values are inconsistent.
        """
        self._node, self._label_map = node, label_map
        self._lock = threading.Lock()
        values = {}
        for name, f, default in all_parameter_fields():
            kind = _kind(f)
            descriptor = descriptor_for(name, f, label_map)
            # An empty list has no ROS type of its own (rclpy would infer BYTE_ARRAY, and an
            # empty YAML list arrives as NOT_SET): declare string arrays by type.
            first = _TYPES[kind] if kind == 'list[str]' and not default else default
            value = node.declare_parameter(name, first, descriptor).value
            if value is None and kind == 'list[str]':
                value = []
                node.set_parameters([Parameter(name, Parameter.Type.STRING_ARRAY, [])])
            values[name] = value
        core, node_cfg = self._build(RegistrationConfig(), NodeConfig(), values)
        self._snapshot = ConfigSnapshot(core, node_cfg, 0)
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._apply)

    def snapshot(self) -> ConfigSnapshot:
        """Return the configuration in force now."""
        with self._lock:
            return self._snapshot

    # ------------------------------------------------------------------------------
    def _build(
        self, core: RegistrationConfig, node_cfg: NodeConfig, values: dict[str, Any]
    ) -> tuple[RegistrationConfig, NodeConfig]:
        """Apply flat values; ConfigError (with the reason) if the result is invalid."""
        node_keys = set(NodeConfig().to_flat_dict())
        node_values = {k: v for k, v in values.items() if k in node_keys}
        core_values = {k: v for k, v in values.items() if k not in node_keys}
        if core_values:
            core = core.replace(core_values)
            Registration.check(core, self._label_map)  # class names known; no side effects
        if node_values:
            node_cfg = node_cfg.replace(node_values)
        return core, node_cfg

    def _ours(self, parameters: list[Parameter]) -> dict[str, Any]:
        known = {name for name, _, _ in all_parameter_fields()}
        return {p.name: p.value for p in parameters if p.name in known}

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: accept only if the whole candidate configuration is valid."""
        values = self._ours(parameters)
        unset = sorted(k for k, v in values.items() if v is None)
        if unset:
            return SetParametersResult(
                successful=False, reason=f'parameters cannot be unset: {unset}'
            )
        current = self.snapshot()
        try:
            self._build(current.core, current.node, values)
        except ConfigError as error:
            self._node.get_logger().warning(f'rejected parameter change: {error}')
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _apply(self, parameters: list[Parameter]) -> None:
        """Post-set callback: the new configuration holds from the next frame on."""
        values = self._ours(parameters)
        if not values:
            return
        with self._lock:
            current = self._snapshot
            core, node_cfg = self._build(current.core, current.node, values)
            version = current.core_version + (core != current.core)
            self._snapshot = ConfigSnapshot(core, node_cfg, version)
        self._node.get_logger().info(
            'parameters changed (from the next frame on): '
            + ', '.join(f'{k}={v!r}' for k, v in values.items())
        )
