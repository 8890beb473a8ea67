"""The architecture holds: packages in layers, rclpy only in the nodes, one error base (issue 15).

The package is read bottom-up::

    physics  <  bags  <  rig  <  estimation  <  identification  <  control  <  diagnosis  <  cli  <  nodes

A module may import from its own package and from the packages below it, never from one above
(``errors``, ``config``, ``workers`` and ``files``, the error base, the declare-once settings, the
engine that runs independent tasks on worker processes and the opening of the files the suite is
handed, are below everything).
Only ``nodes/`` imports rclpy or any other ROS client code, so the
science runs, and is tested, without ROS.  Every package says in its ``__init__`` docstring what it
is for, and every error the package raises on purpose derives from :class:`PiezofinError`.
"""

from __future__ import annotations

import ast
import builtins
import re
import shutil
from pathlib import Path

import pytest

import piezofin_ros
from piezofin_ros import errors

PACKAGE = Path(piezofin_ros.__file__).parent
LAYERS = (
    "base",
    "physics",
    "bags",
    "rig",
    "estimation",
    "identification",
    "control",
    "bench",
    "diagnosis",
    "cli",
    "nodes",
)
ROS_CLIENT = (
    "rclpy",
    "launch",
    "launch_ros",
    "rosidl_runtime_py",
    "ros2cli",
    "builtin_interfaces",
    "std_msgs",
)


def _modules(root: Path = PACKAGE) -> list[Path]:
    return sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts)


def _layer_of(path: Path, root: Path = PACKAGE) -> str:
    rel = path.relative_to(root)
    return rel.parts[0] if len(rel.parts) > 1 else "base"  # errors.py, config.py, workers.py: the bottom


def _imports(path: Path, root: Path = PACKAGE) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every import in the module (of the package at ``root``),
    relative ones resolved."""
    rel = path.relative_to(root.parent).with_suffix("")
    package = list(rel.parts[:-1])  # the package a relative import starts from
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
                if node.module is None:  # from .. import x: x may be a module
                    out += [(node.lineno, f"{name}.{a.name}") for a in node.names]
                    continue
            else:
                name = node.module or ""
            out.append((node.lineno, name))
    return out


def test_the_top_level_holds_only_the_packages() -> None:
    loose = sorted(
        p.name
        for p in PACKAGE.glob("*.py")
        if p.name not in ("__init__.py", "errors.py", "config.py", "workers.py", "files.py")
    )
    assert loose == [], f"modules outside the layer packages: {loose}"
    packages = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists())
    assert sorted(set(LAYERS) - {"base"}) == packages


@pytest.mark.parametrize("layer", [x for x in LAYERS if x != "base"])
def test_every_package_says_what_it_is_for(layer: str) -> None:
    doc = ast.get_docstring(ast.parse((PACKAGE / layer / "__init__.py").read_text()))
    assert doc is not None and len(doc.split()) >= 25, f"{layer}/__init__.py needs a paragraph"


def _imports_from_above(root: Path = PACKAGE) -> list[str]:
    """Every import of a module of the package at ``root`` from a layer above its own."""
    bad = []
    for path in _modules(root):
        own = LAYERS.index(_layer_of(path, root))
        for line, name in _imports(path, root):
            parts = name.split(".")
            if parts[0] != "piezofin_ros" or len(parts) < 2:
                continue
            target = parts[1]
            if target in LAYERS and LAYERS.index(target) > own:  # errors and config are "base" modules
                bad.append(f"{path.relative_to(root)}:{line} imports {name}")
    return bad


def test_nothing_imports_from_a_layer_above_it() -> None:
    assert _imports_from_above() == []


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_two_modules_import_each_other_and_the_nodes_share_nothing_with_the_cli() -> None:
    """Issue 29's house: `cli/campaign` and `cli/campaign_report` imported each other, and
    `nodes/bringup` imported `cli/` for its tables, plots and frequency parsing.  No cycle among the
    package's modules (imports for type checking count), and the nodes import nothing from `cli/`:
    what both use lies below both."""
    names = {_module_name(p): p for p in _modules()}
    graph: dict[str, set[str]] = {}
    for name, path in names.items():
        targets = set()
        for _, imported in _imports(path):
            while imported and imported not in names:  # `from .x import y`: y may be a name in x
                imported = imported.rpartition(".")[0]
            if imported and imported != name and names[imported].name != "__init__.py":
                targets.add(imported)
        graph[name] = targets
    cycles = []
    for a, targets in graph.items():
        cycles += [f"{a} <-> {b}" for b in targets if a < b and a in graph.get(b, set())]
    assert cycles == []
    from_cli = [
        f"{p.relative_to(PACKAGE)}:{line} imports {n}"
        for p in _modules()
        if _layer_of(p) == "nodes"
        for line, n in _imports(p)
        if n.startswith("piezofin_ros.cli")
    ]
    assert from_cli == []


def test_the_controls_rooms_stay_small() -> None:
    """Issue 40: ``control/optimise.py`` had grown to 1,202 lines, one class of 43 fields holding the
    fit, the evidence, a hand-keyed cache, the map and the proposal's rules.  Split into rooms
    (correction, fit, evidence, thrustmap, proposal, tuning) with the same behaviour; kept so: no
    module of ``control/`` over 500 lines, no class there over 30 fields (a dataclass's fields, or
    the attributes its body annotates)."""
    big, wide = [], []
    for path in sorted((PACKAGE / "control").glob("*.py")):
        text = path.read_text()
        if text.count("\n") > 500:
            big.append(f"{path.name}: {text.count(chr(10))} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef):
                n = sum(isinstance(b, ast.AnnAssign) and isinstance(b.target, ast.Name) for b in node.body)
                if n > 30:
                    wide.append(f"{path.name}: {node.name} has {n} fields")
    assert big == [] and wide == []


def test_no_watt_source_or_mode_is_compared_as_a_string_outside_its_registry() -> None:
    """Issue 40: watts, sources and modes were strings compared in about ten places each; each is now
    a table declared once (``physics.amplifier.WATT``, ``estimation.estimator.SOURCE``,
    ``control.strategy.ControllerMode``), and its users ask the table."""
    pattern = re.compile(
        r"""\b(watt|source|mode)\b[\w.\[\]"']*\s*[!=]=\s*["']|["'](fin|self|vibrometer|loadcell|supply_measured|optimise)["']\s*[!=]="""
    )
    registries = {"physics/amplifier.py", "estimation/estimator.py", "control/strategy.py"}
    found = [
        f"{path.relative_to(PACKAGE)}:{k}: {line.strip()}"
        for path in sorted(PACKAGE.rglob("*.py"))
        if str(path.relative_to(PACKAGE)) not in registries
        for k, line in enumerate(path.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert found == []


def test_each_topic_is_declared_once_and_documented() -> None:
    """Issue 40: a topic's name, type and QoS were written at every publisher and subscriber, the
    recorder's list and a re-export list.  Now one table (``bags.topics.TOPICS``): every topic name
    the module declares is in it, its QoS profile exists, the recorder's lists are the table's, and
    docs/reference.md's topic table has a row for each with its type."""
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    from piezofin_ros.bags import topics
    from piezofin_ros.nodes._common import QOS, endpoint
    from piezofin_ros.nodes.recorder import GLOBAL_TOPICS, SUITE_TOPICS

    declared = {v for k, v in vars(topics).items() if k.startswith("TOPIC_")}
    assert declared == set(topics.TOPICS)
    rows, qos_cells, previous = {}, {}, ("", "")
    text = (PACKAGE.parent / "docs" / "reference.md").read_text()
    section = text[text.index("### Topics") : text.index("**Blocks**")]
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) > 4 and (name := re.match(r"`([^`]+)`", cells[0])):
            # ("same": the row above's)
            rows[name.group(1)] = previous[0] if cells[1] == "same" else cells[1]
            qos_cells[name.group(1)] = previous[1] if cells[4] == "same" else cells[4]
            previous = (rows[name.group(1)], qos_cells[name.group(1)])
    for name, t in topics.TOPICS.items():
        assert t.qos in QOS, name
        cls, topic, qos = endpoint(name)
        assert (cls.__module__.split(".")[0], cls.__name__, topic, qos) == (
            t.type.split("/")[0],
            t.type.split("/")[-1],
            name,
            QOS[t.qos],
        )
        short = t.type.replace("/msg/", "/")
        assert name in rows and short in rows[name], (name, short, rows.get(name))
        said = qos_cells[name]  # the docs' QoS: the profile's reliability, durability and depth
        best_effort = qos.reliability == ReliabilityPolicy.BEST_EFFORT
        assert said.startswith("best-effort" if best_effort else "reliable"), (name, said)
        assert f"keep last {qos.depth}" in said, (name, said)
        assert ("transient-local" in said) == (qos.durability == DurabilityPolicy.TRANSIENT_LOCAL), name
    recorded = {n: t.type for n, t in topics.TOPICS.items() if t.recorded}
    assert recorded == {**SUITE_TOPICS, **GLOBAL_TOPICS}


def _ros_outside_the_nodes(root: Path = PACKAGE) -> list[str]:
    """Every import of ROS client code by a module of the package at ``root`` outside ``nodes/``."""
    bad = []
    for path in _modules(root):
        if _layer_of(path, root) == "nodes":
            continue
        for line, name in _imports(path, root):
            if name.split(".")[0] in ROS_CLIENT:
                bad.append(f"{path.relative_to(root)}:{line} imports {name}")
    return bad


def test_only_the_nodes_import_ros_client_code() -> None:
    assert _ros_outside_the_nodes() == []


def test_the_layering_check_sees_a_violation(tmp_path: Path) -> None:
    """The checker itself: a physics module importing the controller and rclpy is reported, in a copy
    of the package (the package itself is never written: other tests read it beside this one)."""
    copy = tmp_path / "piezofin_ros"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.pyc"))
    assert _imports_from_above(copy) == [] and _ros_outside_the_nodes(copy) == []  # (as the package)
    (copy / "physics" / "_layering_probe.py").write_text("from ..control import optimise\nimport rclpy\n")
    assert _imports_from_above(copy) == ["physics/_layering_probe.py:1 imports piezofin_ros.control"]
    assert _ros_outside_the_nodes(copy) == ["physics/_layering_probe.py:2 imports rclpy"]


def test_every_error_raised_on_purpose_derives_from_the_base() -> None:
    """``raise X(...)`` names one of the package's errors, never a bare builtin one.

    Python's own protocol errors keep their meaning: ``KeyError`` from a lookup by name,
    ``TypeError`` for a programming error (a malformed effect class), ``FileNotFoundError`` and
    ``FileExistsError`` as the OS says them, ``NotImplementedError`` in abstract methods,
    ``AttributeError`` from a module's ``__getattr__`` (PEP 562: ``bags`` loads its modules lazily).
    """
    allowed = {
        "NotImplementedError",
        "KeyError",
        "TypeError",
        "FileNotFoundError",
        "FileExistsError",
        "AttributeError",
    }
    bad = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.Raise) or node.exc is None:
                continue
            call = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
            name = call.id if isinstance(call, ast.Name) else getattr(call, "attr", "")
            builtin = getattr(builtins, name, None)
            if isinstance(builtin, type) and issubclass(builtin, BaseException) and name not in allowed:
                bad.append(f"{path.relative_to(PACKAGE)}:{node.lineno} raises {name}")
    assert bad == []


def test_each_layer_has_its_error_and_every_error_class_derives_from_the_base() -> None:
    import importlib

    for path in _modules():
        mod = importlib.import_module(".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts))
        for obj in vars(mod).values():
            if isinstance(obj, type) and issubclass(obj, Exception) and obj.__module__ == mod.__name__:
                assert issubclass(obj, errors.PiezofinError), f"{mod.__name__}.{obj.__name__}"
    for name in ("PhysicsError", "BagError", "EstimationError", "RigError", "ControlError", "DiagnosisError"):
        assert issubclass(getattr(errors, name), errors.PiezofinError)


def test_every_node_parameter_is_declared_once_and_documented() -> None:
    """Each node's parameters come from one config dataclass, and docs/reference.md lists them all."""
    from piezofin_ros.config import settings_of
    from piezofin_ros.control.speedloop import SpeedLoopConfig
    from piezofin_ros.control.yawloop import YawLoopConfig
    from piezofin_ros.estimation.estimator import EstimatorConfig
    from piezofin_ros.nodes.controller import ControllerConfig
    from piezofin_ros.nodes.entry import EXECUTABLES
    from piezofin_ros.nodes.fin_sim import FinSimConfig
    from piezofin_ros.nodes.player import PlayerConfig
    from piezofin_ros.nodes.recorder import RecorderConfig
    from piezofin_ros.nodes.speed_loop import SpeedLoopNodeConfig
    from piezofin_ros.nodes.thrust_estimator import ThrustEstimatorConfig
    from piezofin_ros.nodes.waypoints import WaypointsConfig
    from piezofin_ros.rig.simulated import DriveLimits, RigConfig

    reference = (PACKAGE.parent / "docs" / "reference.md").read_text()
    rows = {line.split("|")[1].strip(" `"): line for line in reference.splitlines() if line.startswith("| `")}
    nodes = {
        "fin_sim": [FinSimConfig, RigConfig, DriveLimits],
        "thrust_estimator": [ThrustEstimatorConfig, EstimatorConfig],
        "controller": [ControllerConfig],
        "recorder": [RecorderConfig],
        "player": [PlayerConfig],
        "speed_loop": [SpeedLoopNodeConfig, SpeedLoopConfig, YawLoopConfig],
        "waypoints": [WaypointsConfig],
    }
    # every node's settings, the node list being the package's (the hosts ``fin_sims``, ``bringup``
    # run those nodes, with their settings)
    assert set(nodes) == {name for name, (module, _) in EXECUTABLES.items() if module == name} - {"bringup"}
    for node, configs in nodes.items():
        for cls in configs:
            for f, _default, s in settings_of(cls):  # every field is a setting with a description
                assert s.description, f"{cls.__name__}.{f.name}"
                if cls in (
                    FinSimConfig,
                    ThrustEstimatorConfig,
                    ControllerConfig,
                    RecorderConfig,
                    PlayerConfig,
                    SpeedLoopNodeConfig,
                    SpeedLoopConfig,
                    YawLoopConfig,
                    WaypointsConfig,
                ):
                    assert f"`{f.name}`" in rows[node], f"docs/reference.md: {node} row lacks `{f.name}`"
    for node in nodes:  # nothing the nodes do not declare
        declared = {f.name for cls in nodes[node] for f, _, _ in settings_of(cls)}
        listed = set(re.findall(r"`([a-z_]+)`", rows[node].split("|")[2]))
        stray = (
            listed
            - declared
            - {"rig", "limits", "estimator", "self", "vibrometer", "stop", "hold", "loop", "yaw"}
        )
        stray -= {"protocol", "continuous", "optimise", "thrust_estimator", "diagnose", "ros2", "launch"}
        assert not stray, f"docs/reference.md: {node} row lists {sorted(stray)}, not parameters"
