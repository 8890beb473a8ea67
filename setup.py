"""ament_python build of piezofin_ros (colcon build / pip install)."""

import ast
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "piezofin_ros"


def node_executables() -> list[str]:
    """The names of ``piezofin_ros.nodes.entry.EXECUTABLES``, read without importing the package
    (its dependencies need not be there when it is built)."""
    tree = ast.parse((Path(__file__).resolve().parent / PACKAGE / "nodes" / "entry.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", "") == "EXECUTABLES":
            return list(ast.literal_eval(node.value))
    raise SystemExit("setup.py: piezofin_ros/nodes/entry.py declares no EXECUTABLES")


CONSOLE_SCRIPTS = [
    "piezofin = piezofin_ros.cli.main:main",
    "sweep = piezofin_ros.cli.main:sweep_main",
    "diagnose = piezofin_ros.cli.main:diagnose_main",
    "identify = piezofin_ros.cli.main:identify_main",
    *(f"{name} = piezofin_ros.nodes.entry:{name}" for name in node_executables()),
]


def write_console_scripts_as_pip_does() -> None:
    """colcon builds an ament_python package with ``setup.py develop`` (or ``install``), whose console
    scripts (``lib/piezofin_ros/<node>``, what ``ros2 run`` starts) setuptools writes from
    easy_install's template: it imports ``importlib.metadata`` and scans every distribution on the
    path for the entry point before the node's first line runs (80 ms here; seconds under CI's load,
    when a SIGINT from ``ros2 launch`` landed there as a ``KeyboardInterrupt`` traceback).  Written as
    pip writes them instead: the function imported and called.  (A setuptools without easy_install
    writes its own.)"""
    try:
        from setuptools.command.easy_install import ScriptWriter
    except ImportError:
        return
    targets = {name.strip(): target.strip() for name, target in (s.split("=") for s in CONSOLE_SCRIPTS)}
    ScriptWriter.template = (
        "# %(name)s: written by piezofin_ros's setup.py (the entry point imported, as pip writes it)\n"
        "import importlib\n"
        "import sys\n\n"
        f"_TARGETS = {targets!r}\n\n"
        "if __name__ == '__main__':\n"
        "    module, _, function = _TARGETS[%(name)r].partition(':')\n"
        "    sys.exit(getattr(importlib.import_module(module), function)())\n"
    )


write_console_scripts_as_pip_does()

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    # the messages' definitions: the bag tools read them without ROS (interfaces/piezofin_msgs builds them)
    package_data={PACKAGE: ["msg/*.msg"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/fins", glob("config/fins/*.yaml")),
        (f"share/{PACKAGE}/config/amplifiers", glob("config/amplifiers/*.yaml")),
        (f"share/{PACKAGE}/config/models", glob("config/models/*.yaml")),
        (f"share/{PACKAGE}/config/bodies", glob("config/bodies/*.yaml")),
        (f"share/{PACKAGE}/config/batteries", glob("config/batteries/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/bags", ["bags/sample_M8528-P1.mcap"]),  # `player -p bag:=bags/sample_...`
    ],
    install_requires=["setuptools", "numpy", "scipy", "pyyaml", "matplotlib"],
    # ray: the benchmarks' and `diagnose --paper`'s tasks on a Ray cluster (piezofin_ros.workers);
    # optional, and without it they run on local worker processes
    extras_require={"test": ["pytest", "hypothesis"], "fast": ["numba"], "ray": ["ray>=2.9"]},
    zip_safe=False,
    maintainer="piezofin_ros developers",
    maintainer_email="dev@piezofin.local",
    description="MFC piezoelectric fin: simulated hardware, thrust estimation, control, MCAP, diagnosis",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": CONSOLE_SCRIPTS},
)
