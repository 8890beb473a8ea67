"""Every command line in a ``bash`` block of README.md and docs/*.md, run as a user types it.

Lines run in the order written, each section (a ``## `` heading) in a scratch directory of its own
holding a copy of ``bags/`` and the placeholders the text names (``mine.yaml``, ``my_fin.yaml``,
``bags/run.mcap``, ``trials.csv``), so a line may use what an earlier line of its section wrote
(``out/diag/augmented_model.yaml``).  A section's lines stay together on one test worker; sections
run in parallel (pytest-xdist, each worker on its own DDS domain).  Three kinds:

- a node or a launch (runs until Ctrl-C): still running, or exited 0, after a few seconds and once
  it is up (every process it started has logged its first line: a user presses Ctrl-C on a suite
  that runs, not on one still importing numpy); then SIGINT, and it must exit 0;
- a line talking to a running suite (``ros2 node|topic|param|lifecycle|service``): run while
  ``ros2 launch piezofin_ros piezofin.launch.py realtime_factor:=10`` runs in the background;
- anything else: exits 0 within its time limit.

No line may print a traceback.  A line marked ``(not run by the tests: why)`` is skipped, saying
why.  ``ros2`` lines need the ``ros_env`` fixture (skipped, saying why, without a ROS command line).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from markdown_it import MarkdownIt

from .rosutil import BIN, Launch, clean_env, listed, ros2

pytestmark = [pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
NOT_RUN = "(not run by the tests:"
#: A line another test runs as typed and checks more closely (run once, not twice): ``(run by FILE, ...)``
RUN_ELSEWHERE = re.compile(r"\(run by (test/[\w/]+\.py)\b[^)]*\)")
#: Options whose value is the user's own output path (a test writes to its own).
OUTPUT_OPTIONS = ("-o", "--json", "--report", "--plot", "--twin")
RUNS_UNTIL_STOPPED = re.compile(
    r"^(ros2 launch |ros2 run piezofin_ros (fin_sim|fin_sims|thrust_estimator|controller|recorder|player)\b)"
)
TALKS_TO_THE_SUITE = re.compile(r"^ros2 (node|topic|param|lifecycle|service) ")
NEEDS_ROS = re.compile(r"^(ros2|colcon|rosdep) ")
#: Sections whose lines a user types in the colcon workspace the install block left them in, not in
#: the repository: the sample bag is reached through the installed package (issue 29).
FROM_THE_WORKSPACE = {"ros.md: On a ROS 2 machine (Jazzy)"}
#: Seconds a node or launch must survive before it is stopped; the limit for everything else.
ALIVE_S = 12.0
UP_S = 120.0  # a loaded machine: the processes may take this long to import and start
LIMIT_S = 600.0


def command_lines() -> list[tuple[str, int, str, str]]:
    """(document, line number, command, section) of every command line in a ``bash`` block; the
    section is the ``## `` heading above it (a line may use only what its own section wrote)."""
    found = []
    for doc in DOCUMENTS:
        inside = False
        section = ""
        for number, line in enumerate(doc.read_text().splitlines(), start=1):
            if line.startswith("```"):
                inside = line.strip() == "```bash" if not inside else False
                continue
            if not inside and line.startswith("## "):
                section = line[3:].strip()
            if inside and line.strip() and not line.lstrip().startswith("#"):
                found.append((doc.name, number, line.strip(), section))
    return found


LINES = command_lines()


def talks_later(document: str, section: str, number: int) -> bool:
    """A later line of the section talks to the background suite (so it stays up until then)."""
    return any(
        TALKS_TO_THE_SUITE.match(c) and NOT_RUN not in c and not RUN_ELSEWHERE.search(c)
        for d, n, c, s in LINES
        if (d, s) == (document, section) and n > number
    )


def test_the_documents_have_commands_to_run() -> None:
    assert len(LINES) >= 30, LINES
    marked = [line for _, _, line, _ in LINES if NOT_RUN in line]
    assert all(re.search(r"\(not run by the tests: \S.+\)", line) for line in marked)  # a reason each


#: The commands a sentence may name in ``code``: each must begin a block line.
COMMAND = re.compile(r"^(piezofin |bringup |ros2 |bash tools/|python (-m |benchmarks/|tools/))")


def test_every_command_a_sentence_names_begins_a_line_the_tests_run() -> None:
    """A command the README writes inline (`piezofin watts --plot out/watts.png`) is one of the
    block lines, or the start of one, which the tests run (or which say why not: the test command
    itself): a reader may type it as it stands.  (The pages of docs/ name benchmarks inline as the
    source of their figures; those take minutes.)"""
    lines = [c for _, _, c, _ in LINES]
    named = []
    for doc in DOCUMENTS[:1]:
        for block in MarkdownIt().parse(doc.read_text()):
            for span in (c.content for c in block.children or () if c.type == "code_inline"):
                if COMMAND.match(span) and not re.search(r"[A-Z]{3,}|\.\.\.|<", span):
                    named.append((doc.name, span))
    assert len(named) >= 3, named
    unrun = [(doc, span) for doc, span in named if not any(c.startswith(span) for c in lines)]
    assert not unrun, unrun


@pytest.fixture(scope="session")  # a test worker may run other modules between a section's lines
def placeholders(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The files the text names, made once: each section's scratch directory starts as a copy."""
    from piezofin_ros.diagnosis.synthetic import Case, simulate_case

    here = tmp_path_factory.mktemp("readme-placeholders")
    (here / "bags").mkdir()
    sample = ROOT / "bags" / "sample_M8528-P1.mcap"
    shutil.copy2(sample, here / "bags" / sample.name)
    shutil.copy2(sample, here / "bags" / "run.mcap")
    shutil.copy2(ROOT / "config" / "fins" / "M8528-P1.yaml", here / "my_fin.yaml")
    (here / "mine.yaml").write_text("/**/controller:\n  ros__parameters:\n    frequencies: [5.0, 6.0]\n")
    simulate_case(Case("M8528-P1", {"electroelastic_softening": 0.3}, 5)).trials.to_csv(here / "trials.csv")
    return here


@pytest.fixture(scope="session")
def scratches() -> dict[str, Path]:
    """Each section's scratch directory, by ``"document: section"``."""
    return {}


def scratch_for(
    key: str, scratches: dict[str, Path], placeholders: Path, factory: pytest.TempPathFactory
) -> Path:
    """The section's own scratch directory: a copy of the placeholders, on first use."""
    if key not in scratches:
        here = factory.mktemp("readme")
        shutil.copytree(placeholders, here, dirs_exist_ok=True)
        if key in FROM_THE_WORKSPACE:  # the user stands in ~/ws: the repository's files are not there
            shutil.rmtree(here / "bags")
        for name in ("tools", "requirements.txt", "requirements-dev.txt", "setup.py", "docs", "CHANGELOG.md"):
            (here / name).symlink_to(ROOT / name)  # tools/main.sh runs here, on the project's venv
        if key not in FROM_THE_WORKSPACE:
            (here / "benchmarks").symlink_to(ROOT / "benchmarks")  # (the clone's, as its lines say)
        scratches[key] = here
    return scratches[key]


class Background:
    """The suite under ``ros2 launch`` while talking lines run (started when first needed)."""

    def __init__(self) -> None:
        self.launch: Launch | None = None

    def start(self, env: dict[str, str], cwd: Path) -> None:
        if self.launch is None:
            # a fresh CLI daemon: the one of this domain may still list the nodes of a suite an earlier
            # test ran and killed, till their lease ends (the CI run of stop 45: `topic list` showed a
            # dead /fin/estimate, then `echo` found none and `param describe` no /fin/fin_sim)
            ros2(env, "daemon", "stop")
            self.launch = Launch(env, cwd, "realtime_factor:=10", log="background-launch.log")
            self.launch.wait_for("trial 1.000 Hz", 60.0)  # estimates flow
            # ... and the command line sees them: as a user would wait for `ros2 node list` and
            # `ros2 topic list` to show them (on a loaded machine the CLI's discovery lags the graph)
            listed(
                env,
                nodes={"/fin/fin_sim", "/fin/thrust_estimator", "/fin/controller"},
                topics={"/fin/estimate", "/fin/cmd"},
            )

    def stop(self) -> None:
        if self.launch is not None:
            self.launch.interrupt()
            self.launch = None


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def background() -> Iterator[Background]:
    bg = Background()
    yield bg
    bg.stop()


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def plain_env() -> dict[str, str]:
    return clean_env(
        PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
        PIEZOFIN_VENV=str(BIN.parent),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        MPLBACKEND="Agg",
    )


def _up(out: str) -> bool:
    """Every process the line started has logged a line of its own (its imports are done)."""
    started = re.findall(r"\[INFO\] \[([\w.-]+)\]: process started", out)
    if started:  # ros2 launch: "[controller-3] [INFO] [...]" once the node runs
        return all(re.search(rf"^\[{re.escape(p)}\] ", out, re.M) for p in started)
    return bool(out.strip())  # ros2 run: the node's first log line


def _run_until_stopped(command: str, env: dict[str, str], cwd: Path) -> str:
    proc = subprocess.Popen(
        ["bash", "-c", command],
        env=env,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.stdout is not None
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    t0 = time.monotonic()
    while time.monotonic() - t0 < ALIVE_S or (not _up("".join(lines)) and time.monotonic() - t0 < UP_S):
        if proc.poll() is not None:
            reader.join(10)
            out = "".join(lines)
            assert proc.returncode == 0, f"exited {proc.returncode} before it was stopped:\n{out[-3000:]}"
            return out
        time.sleep(0.2)
    assert _up("".join(lines)), f"not up after {UP_S:.0f} s:\n{''.join(lines)[-3000:]}"
    os.killpg(proc.pid, signal.SIGINT)  # still running, as it should: Ctrl-C
    try:
        proc.wait(timeout=30)
        reader.join(10)
        out = "".join(lines)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        out = "".join(lines)
        raise AssertionError(f"did not stop on Ctrl-C within 30 s:\n{out[-3000:]}") from None
    assert proc.returncode == 0, f"exit {proc.returncode} on Ctrl-C:\n{out[-3000:]}"
    return out


@pytest.mark.parametrize(
    ("document", "number", "command", "section"),
    [
        # a section's lines stay together, in order, on one test worker; sections run in parallel
        pytest.param(*line, id=f"{line[0]}:{line[1]}", marks=pytest.mark.xdist_group(f"{line[0]}: {line[3]}"))
        for line in LINES
    ],
)
def test_command_line(
    document: str,
    number: int,
    command: str,
    section: str,
    scratches: dict[str, Path],
    placeholders: Path,
    background: Background,
    plain_env: dict[str, str],
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    if NOT_RUN in command:
        pytest.skip(command[command.index(NOT_RUN) + 1 : command.rindex(")")])
    elsewhere = RUN_ELSEWHERE.search(command)
    if elsewhere:  # that test holds the command, word for word but its output paths
        text = (ROOT / elsewhere.group(1)).read_text()
        words = shlex.split(command.split("#")[0])
        skip = {i + 1 for i, w in enumerate(words) if w in OUTPUT_OPTIONS}
        absent = [w for i, w in enumerate(words[1:], 1) if i not in skip and f'"{w}"' not in text]
        assert not absent, f"{elsewhere.group(1)} does not run {command!r}: {absent} not in it"
        pytest.skip(elsewhere.group(0)[1:-1])
    scratch = scratch_for(f"{document}: {section}", scratches, placeholders, tmp_path_factory)
    env = request.getfixturevalue("ros_env") if NEEDS_ROS.match(command) else plain_env
    if TALKS_TO_THE_SUITE.match(command):
        background.start(env, scratch)
    else:
        background.stop()  # one suite at a time under the same names, and the CPU to this line
    try:
        if RUNS_UNTIL_STOPPED.match(command):
            out = _run_until_stopped(command, env, scratch)
        else:
            run = subprocess.run(
                ["bash", "-c", command],
                env=env,
                cwd=scratch,
                stdin=subprocess.DEVNULL,
                capture_output=True,
                text=True,
                timeout=LIMIT_S,
            )
            out = run.stdout + run.stderr
            assert run.returncode == 0, f"{document}:{number}: exit {run.returncode}\n{out[-3000:]}"
    finally:
        if not talks_later(document, section, number):
            # the worker runs other modules next, in the same DDS domain: a suite left running there
            # publishes /clock and /fin/* into their graphs (CI's two-fin launch test took its clock)
            background.stop()
    assert "Traceback" not in out, f"{document}:{number}:\n{out[-3000:]}"
