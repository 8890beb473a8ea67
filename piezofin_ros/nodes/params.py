"""ROS 2 parameter files (``node: {ros__parameters: {...}}``) read without ROS, for ``bringup``.

The same YAML file configures the in-process ``bringup`` and the launch file on a ROS machine
(``parameters=[file]``).  Keys select nodes as rcl does: ``/**`` (every node), ``/**/name``
(a node of that name in any namespace), ``name`` or ``/name`` (root namespace), ``/ns/name``.
Nested mappings flatten to dotted names (``rig: {voltage_noise_v: 0.2}`` is ``rig.voltage_noise_v``).
Loaded with the safe YAML loader: nothing in a file can execute code.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..physics.fin import FinConfigError, read_yaml_file


def load_parameter_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a parameter file; raises :class:`FinConfigError` naming the file and the problem."""
    path = Path(path)
    doc = read_yaml_file(path)
    if not isinstance(doc, dict):
        raise FinConfigError(f"{path}: expected a mapping of node names to ros__parameters")
    for key, entry in doc.items():
        if (
            not isinstance(entry, dict)
            or set(entry) != {"ros__parameters"}
            or not isinstance(entry["ros__parameters"], dict)
        ):
            raise FinConfigError(f"{path}: entry {key!r} must hold exactly one mapping 'ros__parameters'")
    return doc


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
        return
    if isinstance(value, list) and any(isinstance(x, float) for x in value):
        value = [float(x) if isinstance(x, int) and not isinstance(x, bool) else x for x in value]
    out[prefix] = value


def node_parameters(doc: dict[str, Any], name: str, namespace: str = "") -> dict[str, Any]:
    """Flattened parameters of node ``name`` in ``namespace`` (later, more specific keys win)."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    full = f"{ns}/{name}"
    order = ["/**", f"/**/{name}", name, f"/{name}"] if not ns else ["/**", f"/**/{name}", full]
    out: dict[str, Any] = {}
    for key in order:
        if key in doc:
            _flatten("", doc[key]["ros__parameters"], out)
    return out
