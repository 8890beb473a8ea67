"""Whatever a user or an attacker hands the command line: one line, an exit status a script can
test, nothing the user owns replaced, and nothing waited on for ever (issue 38).

Each class of input is handed to every reader of it, as a user types the command (its own process,
no standard input): a FIFO as any configuration file or bag (it hung for ever, and then SIGINT and
SIGTERM were ignored); an amplifier whose ``kind`` is a list (a traceback in all six readers); a
battery the loader took but ``swim`` then divided by zero on; plots written over a user's file or
to a name matplotlib changes; ``--twin`` over the user's ``twin.md`` after 292 s of work.
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from pathlib import Path

import pytest

from ..rosutil import BIN, clean_env

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_M8528-P1.mcap"
BATTERY = Path(__file__).resolve().parents[2] / "config" / "batteries" / "li-ion-2s-500mah.yaml"


def run(*argv: str, timeout: float = 60.0) -> tuple[subprocess.CompletedProcess[str], float]:
    t0 = time.monotonic()
    proc = subprocess.run(
        [str(BIN / argv[0]), *argv[1:]],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=clean_env(MPLBACKEND="Agg"),
        stdin=subprocess.DEVNULL,
    )
    return proc, time.monotonic() - t0


def one_error_line(proc: subprocess.CompletedProcess[str], *words: str) -> str:
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    errors = [x for x in proc.stderr.splitlines() if "error" in x.lower()]
    assert len(errors) == 1, proc.stderr[-3000:]
    for w in words:
        assert w in errors[0], (w, errors[0])
    return errors[0]


#: every reader of a file, the file's place in its command line as {f}
FILE_READERS = {
    "sweep --fin": ["piezofin", "sweep", "--fin", "{f}", "--vpp", "400", "--freq", "5"],
    "sweep --model": ["piezofin", "sweep", "--model", "{f}", "--vpp", "400", "--freq", "5"],
    "identify --geometry": ["piezofin", "identify", "--air", str(SAMPLE), "--geometry", "{f}"],
    "identify --air": ["piezofin", "identify", "--air", "{f}", "--geometry", "M8528-P1"],
    "estimate": ["piezofin", "estimate", "{f}"],
    "estimate --fin": ["piezofin", "estimate", str(SAMPLE), "--fin", "{f}"],
    "diagnose": ["piezofin", "diagnose", "{f}"],
    "diagnose --amplifier": ["piezofin", "diagnose", str(SAMPLE), "--amplifier", "{f}"],
    "watts --amplifiers": ["piezofin", "watts", "--amplifiers", "{f}", "--fins", "M8528-P1"],
    "watts --fins": ["piezofin", "watts", "--fins", "{f}"],
    "swim --body": ["piezofin", "swim", "--body", "{f}", "--fins", "M8528-P1"],
    "swim --battery": ["piezofin", "swim", "--battery", "{f}", "--fins", "M8528-P1"],
    "swim --amplifier": ["piezofin", "swim", "--amplifier", "{f}", "--fins", "M8528-P1"],
    "bringup --config": ["bringup", "--config", "{f}", "--bag", "{out}"],
}


@pytest.mark.fast_cases("sweep --fin", "estimate", "swim --body", "bringup --config")
@pytest.mark.parametrize("reader", list(FILE_READERS))
def test_a_fifo_as_any_file_is_refused_at_once(tmp_path: Path, reader: str) -> None:
    fifo = tmp_path / (
        "fifo.mcap" if reader == "estimate" or "--air" in reader or reader == "diagnose" else "fifo.yaml"
    )
    os.mkfifo(fifo)
    argv = [a.format(f=fifo, out=tmp_path / "b.mcap") for a in FILE_READERS[reader]]
    proc, wall = run(*argv, timeout=60.0)
    assert wall < 15.0, wall
    assert proc.returncode == 2, proc.stdout[-1000:] + proc.stderr[-2000:]
    one_error_line(proc, str(fifo))
    assert not (tmp_path / "b.mcap").exists()


@pytest.mark.slow
@pytest.mark.parametrize("node", ["fin_sim", "thrust_estimator", "speed_loop"])
def test_a_fifo_as_a_nodes_file_parameter_is_refused_at_once(tmp_path: Path, node: str) -> None:
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    param = "body" if node == "speed_loop" else "amplifier"
    proc, wall = run(node, "--ros-args", "-p", f"{param}:={fifo}", timeout=60.0)
    assert wall < 20.0, wall
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and str(fifo) in proc.stderr, proc.stderr[-2000:]


#: an amplifier's ``kind`` that is no kind: each must be one line, in every reader of an amplifier
KINDS = ["[linear]", "{linear: 1}", "null", "3", "true", "'LINEAR'"]
AMPLIFIER_READERS = {
    "watts --amplifiers": ["piezofin", "watts", "--amplifiers", "{f}", "--fins", "M8528-P1"],
    "swim --amplifier": ["piezofin", "swim", "--amplifier", "{f}", "--fins", "M8528-P1"],
    "diagnose --amplifier": ["piezofin", "diagnose", str(SAMPLE), "--amplifier", "{f}"],
}


@pytest.mark.fast_cases(
    "[linear]-watts --amplifiers", "{linear: 1}-swim --amplifier", "null-diagnose --amplifier"
)
@pytest.mark.parametrize("reader", list(AMPLIFIER_READERS))
@pytest.mark.parametrize("kind", KINDS)
def test_an_amplifier_kind_that_is_no_kind_is_one_line(tmp_path: Path, kind: str, reader: str) -> None:
    f = tmp_path / "amp.yaml"
    f.write_text(f"kind: {kind}\nrail_v: 400.0\n")
    proc, _ = run(*[a.format(f=f) for a in AMPLIFIER_READERS[reader]])
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_error_line(proc, "kind")


def test_every_amplifier_kind_that_is_no_kind_is_an_amplifier_error() -> None:
    """The class in the core: any YAML value as ``kind`` (the six readers all call this)."""
    from piezofin_ros.physics.amplifier import AmplifierError, amplifier_from_mapping

    for kind in (["linear"], {"linear": 1}, None, 3, True, 1.5, "LINEAR", "", ("linear",)):
        with pytest.raises(AmplifierError, match="kind"):
            amplifier_from_mapping({"kind": kind, "rail_v": 400.0})


#: batteries the loader took and ``swim`` then crashed on, and the word their refusal says
BATTERIES = {
    "cut-off 4.19 V per cell": ("cutoff_v_per_cell: 4.19\n", None),
    "a NaN in ocv_soc": ("ocv_soc: [0, .nan, 1]\nocv_v_per_cell: [3.0, 3.5, 4.2]\n", "finite"),
    "an OCV of 1e300 V": ("ocv_soc: [0, 1]\nocv_v_per_cell: [3.0, 1.0e+300]\n", "ocv_v_per_cell"),
    "a capacity of 1e-300 A h": ("capacity_ah: 1.0e-300\n", "capacity_ah"),
    "a hotel of 1e4 W": ("hotel_w: 1.0e+4\n", "hotel_w"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(BATTERIES))
def test_swim_on_any_battery_is_a_table_or_one_line(tmp_path: Path, case: str) -> None:
    extra, refused = BATTERIES[case]
    keys = {line.split(":")[0] for line in extra.splitlines()}
    base = [line for line in BATTERY.read_text().splitlines() if line.split(":")[0] not in keys]
    f = tmp_path / "battery.yaml"
    f.write_text("\n".join(base) + "\n" + extra)
    proc, _ = run("piezofin", "swim", "--battery", str(f), "--fins", "M8528-P1", timeout=300.0)
    if refused is None:  # a battery that can be: it swims (what it can), no crash
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert not re.search(r"\bnan\b", proc.stdout.lower()), proc.stdout
    else:
        assert proc.returncode == 2, proc.stdout[-500:] + proc.stderr[-3000:]
        one_error_line(proc, refused)


@pytest.mark.parametrize(
    ("extra", "word"),
    [
        (["--body", "{body}"], "mass_kg"),
        (["--hotel", "1e4"], "hotel_w"),
        (["--voltage-max", "0"], "--voltage-max"),
    ],
)
def test_swim_refuses_what_no_fish_can_be(tmp_path: Path, extra: list[str], word: str) -> None:
    body = tmp_path / "body.yaml"
    body.write_text("mass_kg: 1.0e-300\n")
    proc, _ = run("piezofin", "swim", "--fins", "M8528-P1", *[a.format(body=body) for a in extra])
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_error_line(proc, word)


@pytest.mark.slow
@pytest.mark.parametrize("vmax", ["1", "30", "49"])
def test_swim_takes_every_voltage_limit_it_documents(vmax: str) -> None:
    proc, _ = run("piezofin", "swim", "--fins", "M8528-P1", "--voltage-max", vmax, "--json", timeout=300.0)
    assert proc.returncode == 0, proc.stderr[-3000:]
    import json

    fins = json.loads(proc.stdout)["fins"]
    for strategy in fins["M8528-P1"].values():
        assert strategy["voltage_pp"] <= float(vmax) + 1e-9, strategy


@pytest.mark.parametrize("min_thrust", ["nan", "-1", "inf"])
def test_watts_refuses_a_floor_that_is_no_thrust(min_thrust: str) -> None:
    proc, _ = run("piezofin", "watts", "--fins", "M8528-P1", "--min-thrust", min_thrust)
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_error_line(proc, "--min-thrust")


# ------------------------------------------------------------------------------------ outputs
PLOTTERS = {
    "swim": ["piezofin", "swim", "--fins", "M8528-P1", "--plot", "{p}"],
    "watts": ["piezofin", "watts", "--fins", "M8528-P1", "--plot", "{p}"],
    "sweep": ["piezofin", "sweep", "--freq", "5", "--plot", "{p}"],
}


@pytest.mark.parametrize("command", list(PLOTTERS))
@pytest.mark.parametrize("kind", ["the user's file", "a folder's name", "/proc", "no suffix"])
def test_a_plot_never_replaces_a_file_or_changes_its_name(tmp_path: Path, command: str, kind: str) -> None:
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"my own figure")
    target = {
        "the user's file": mine,
        "a folder's name": tmp_path,
        "/proc": Path("/proc/x.png"),
        "no suffix": tmp_path / "figure",
    }[kind]
    proc, wall = run(*[a.format(p=target) for a in PLOTTERS[command]])
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_error_line(proc, "--plot")
    assert wall < 15.0  # refused before the work
    assert mine.read_bytes() == b"my own figure"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.png"]


@pytest.mark.parametrize("kind", ["holds my twin.md", "a file", "/proc/x"])
def test_diagnose_twin_refuses_before_the_work(tmp_path: Path, kind: str) -> None:
    target = tmp_path / "twin"
    if kind == "holds my twin.md":
        target.mkdir()
        (target / "twin.md").write_text("my notes")
    elif kind == "a file":
        target.write_text("a file")
    else:
        target = Path("/proc/x")
    proc, wall = run("piezofin", "diagnose", "--paper", "--twin", str(target))
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_error_line(proc, "--twin")
    assert wall < 15.0  # (it was refused, if at all, after 292 s of work)
    if kind == "holds my twin.md":
        assert (target / "twin.md").read_text() == "my notes"


@pytest.mark.fast_cases(".png")
@pytest.mark.parametrize("suffix", [".png", ".pdf", ".svg"])
def test_a_plot_replaces_the_figure_it_wrote_itself(tmp_path: Path, suffix: str) -> None:
    """A README line run twice (``piezofin sweep ... --plot out/x.png``) replaces its own figure
    (marked as the suite's), and the user's file of the same kind stays refused."""
    from piezofin_ros.files import written_by_us

    out = tmp_path / f"sweep{suffix}"
    for _ in range(2):
        proc, _ = run("piezofin", "sweep", "--freq", "5", "--plot", str(out))
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert written_by_us(out)
    mine = tmp_path / f"mine{suffix}"
    mine.write_bytes(b"my own " + suffix.encode())
    proc, _ = run("piezofin", "sweep", "--freq", "5", "--plot", str(mine))
    assert proc.returncode == 2
    one_error_line(proc, "not a figure this suite wrote")
    assert mine.read_bytes() == b"my own " + suffix.encode()
