"""The package is a correct ament_python package: `colcon build` gives the `ros2 run` layout."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from piezofin_ros.nodes.entry import EXECUTABLES

from .rosutil import clean_env

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_colcon_build_installs_executables_and_ament_index(tmp_path: Path) -> None:
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent))
    if colcon is None:
        pytest.skip("colcon is not installed in this environment")
    src = tmp_path / "ws" / "src" / "piezofin_ros"
    src.mkdir(parents=True)
    for item in (
        "setup.py",
        "setup.cfg",
        "package.xml",
        "resource",
        "config",
        "launch",
        "piezofin_ros",
        "interfaces",
    ):
        source = ROOT / item
        if source.is_dir():
            shutil.copytree(source, src / item, ignore=shutil.ignore_patterns("__pycache__"))
        elif source.exists():
            shutil.copy2(source, src / item)
    (src / "bags").mkdir()
    shutil.copy2(ROOT / "bags" / "sample_M8528-P1.mcap", src / "bags")  # a clone has only this bag
    ws = tmp_path / "ws"
    proc = subprocess.run(  # as docs/ros.md says: the messages' package sits inside this one's folder
        [
            colcon,
            "build",
            "--base-paths",
            "src",
            "src/piezofin_ros/interfaces",
            "--packages-up-to",
            "piezofin_ros",
        ],
        cwd=ws,
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
        # (the ROS install's prefix, as a sourced setup.bash sets it: here the venv of the Jazzy wheels)
        env=clean_env(AMENT_PREFIX_PATH=os.environ.get("AMENT_PREFIX_PATH") or sys.prefix),
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Summary: 2 packages finished" in proc.stdout, proc.stdout  # piezofin_msgs, then piezofin_ros
    msgs = ws / "install" / "piezofin_msgs"
    assert (msgs / "share" / "piezofin_msgs" / "msg" / "Estimate.msg").exists()
    assert (
        msgs / "share" / "ament_index" / "resource_index" / "rosidl_interfaces" / "piezofin_msgs"
    ).exists()
    prefix = ws / "install" / "piezofin_ros"
    # `ros2 run piezofin_ros <exe>` looks in <prefix>/lib/<package>/ ...
    for exe in ("piezofin", "sweep", "diagnose", "identify", *EXECUTABLES):
        script = prefix / "lib" / "piezofin_ros" / exe
        assert os.access(script, os.X_OK), exe
        # ... each imports its function, as pip writes it: easy_install's template scanned every
        # distribution's metadata first (80 ms; seconds under load, where ros2 launch's SIGINT landed)
        text = script.read_text()
        assert "importlib.metadata" not in text and "pkg_resources" not in text, text
    # ... for a package registered in the ament index, with its share/ files.
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "piezofin_ros").exists()
    assert (prefix / "share" / "piezofin_ros" / "package.xml").exists()
    assert sorted(p.name for p in (prefix / "share" / "piezofin_ros" / "config" / "fins").iterdir()) == [
        "M8507-P1.yaml",
        "M8514-P1.yaml",
        "M8528-P1.yaml",
    ]
    share = prefix / "share" / "piezofin_ros"
    assert (share / "config" / "bringup.yaml").exists()
    for folder in sorted(p for p in (ROOT / "config").iterdir() if p.is_dir()):  # every preset installed
        installed = sorted(p.name for p in (share / "config" / folder.name).glob("*.yaml"))
        assert installed == sorted(p.name for p in folder.glob("*.yaml")), folder.name
    assert (share / "bags" / "sample_M8528-P1.mcap").exists()  # `player -p bag:=bags/sample_...` anywhere
    launch = share / "launch" / "piezofin.launch.py"
    compile(launch.read_text(), str(launch), "exec")  # launch itself is not on PyPI: syntax only
    # The installed executable runs from the install tree and finds the installed presets.
    site = next(prefix.glob("lib/python3*/site-packages"))
    assert (site / "piezofin_ros" / "msg" / "Estimate.msg").exists()  # the bag tools read it without ROS
    env = {**os.environ, "PYTHONPATH": str(site)}
    env.pop("PIEZOFIN_CONFIG", None)
    run = subprocess.run(
        [str(prefix / "lib" / "piezofin_ros" / "sweep"), "--freq", "9.9", "--vpp", "800"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert "M8528-P1" in run.stdout


#: The rosdep key (or ROS package) that provides each third-party module the package imports.
#: Keys checked against ros/rosdistro's rosdep/python.yaml (mcap: only `mcap-ros2-support`, a pip
#: key whose package depends on mcap, which depends on zstandard and lz4).
ROSDEP = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "numba": "python3-numba",
    "mcap": "mcap-ros2-support",
    "zstandard": "mcap-ros2-support",
    "lz4": "mcap-ros2-support",
    "rosbags": "python3-rosbags-pip",
}
#: Optional imports (inside ``try: ... except ImportError``), with no rosdep key: declared as a pip
#: extra in setup.py and named in a package.xml comment, never as a dependency rosdep must install.
OPTIONAL = {"ray": "ray"}


def test_every_import_is_declared_in_package_xml() -> None:
    """After `rosdep install --from-paths src`, every module the package imports is there."""
    import ast
    import xml.etree.ElementTree as ET

    root = ET.parse(ROOT / "package.xml").getroot()
    declared = {e.text for e in root if e.tag.endswith("depend") and e.tag != "doc_depend"}
    # the site's builders: keys of rosdistro's python.yaml (checked there), pip's names in requirements-dev
    assert {e.text for e in root if e.tag == "doc_depend"} == {"python3-sphinx", "python3-myst-parser-pip"}
    dev = (ROOT / "requirements-dev.txt").read_text()
    assert re.search(r"^sphinx\b", dev, re.M) and re.search(r"^myst-parser\b", dev, re.M)
    stdlib = set(sys.stdlib_module_names)
    files = [*(ROOT / "piezofin_ros").rglob("*.py"), *(ROOT / "launch").glob("*.py")]
    needed: dict[str, str] = {}
    optional: dict[str, str] = {}
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                if top in OPTIONAL:
                    optional[top] = str(path.relative_to(ROOT))
                    continue
                if top not in stdlib and top != "piezofin_ros":
                    needed[ROSDEP.get(top, top)] = str(path.relative_to(ROOT))
    missing = {key: where for key, where in needed.items() if key not in declared}
    assert not missing, f"imported but not declared in package.xml: {missing}"
    commands = {"ros2launch"}  # (the `ros2 launch` command: run, not imported)
    # the message packages of the topic table, imported by name (nodes._common.message_class)
    from piezofin_ros.bags.topics import TOPICS

    messages = {t.type.split("/")[0] for t in TOPICS.values()}
    assert not messages - declared, f"a topic's message package is not in package.xml: {messages - declared}"
    unused = declared - set(needed) - {"python3-pytest", "python3-hypothesis"} - commands - messages
    assert not unused, f"declared in package.xml but never imported: {unused}"
    # an optional import is guarded, a pip extra, and said in package.xml (not a dependency)
    extras = (ROOT / "setup.py").read_text()
    xml = (ROOT / "package.xml").read_text()
    for top, where in optional.items():
        source = (ROOT / where).read_text()
        assert re.search(rf"try:\n\s+import {top}\b.*\n\s+except ImportError", source), where
        assert f'"{top}": ["{OPTIONAL[top]}' in extras, f"{top}: no extra in setup.py"
        assert re.search(rf"<!--[^>]*\b{top.capitalize()}\b[^>]*piezofin_ros\[{top}\][^>]*-->", xml), top


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_link_to_a_heading_finds_it() -> None:
    """A link `file.md#anchor` in the README or docs/ lands on a heading of that file (two links
    in the README pointed at a heading that had since been renamed)."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    anchors = {
        page.resolve(): {_slug(m) for m in re.findall(r"^#+ (.+)$", page.read_text(), re.M)} for page in pages
    }
    broken = []
    for page in pages:
        for target, anchor in re.findall(r"\]\(([\w./-]*\.md|)#([\w-]+)\)", page.read_text()):
            where = (page.parent / target).resolve() if target else page.resolve()
            if where in anchors and anchor not in anchors[where]:
                broken.append(f"{page.relative_to(ROOT)}: {target or page.name}#{anchor}")
    assert not broken, broken
