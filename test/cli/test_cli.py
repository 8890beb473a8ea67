"""The `piezofin sweep` command, through its installed console scripts (real processes)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from piezofin_ros.cli.main import UsageError, parse_frequencies
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.steady import harmonic_balance

from .run import console, run_showing_where


def run(exe: str, *args: str) -> subprocess.CompletedProcess[str]:
    return console(exe, *args, env={**os.environ, "MPLBACKEND": "Agg"})


def test_a_command_that_outlives_its_timeout_says_where_it_hung() -> None:
    """The CLI tests' runner: a command still running at its timeout fails the test with the function
    and line each of its threads was in (faulthandler's stacks, on SIGABRT) and the output it gave,
    not a bare ``TimeoutExpired`` (a campaign's analysis outlived 180 s once on a CI, unexplained)."""
    lines = ("import time", "", "def waits_for_ever():", "    time.sleep(60)", "")
    code = "\n".join((*lines, "print('begun', flush=True)", "waits_for_ever()"))
    t0 = time.monotonic()
    with pytest.raises(AssertionError, match="still ran after 1 s") as info:
        run_showing_where([sys.executable, "-c", code], timeout=1.0)
    said = str(info.value)
    assert 'File "<string>", line 4 in waits_for_ever' in said and "begun" in said, said
    assert time.monotonic() - t0 < 20


def test_sweep_json_has_parameters_and_points() -> None:
    proc = run(
        "piezofin", "sweep", "--fin", "M8528-P1", "--vpp", "400", "600", "800", "--freq", "1:11:0.1", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["fin"] == "M8528-P1"
    for key in ("L", "b", "m_s", "f_sc", "zeta", "theta", "C_eq", "psi", "c_m", "c_d", "rho_w"):
        assert isinstance(out[key], float), key
    assert out["f_sc"] == 38.1 and out["C_eq"] == pytest.approx(19.3e-9)  # SI, not nF
    points = out["points"]
    assert len(points) == 101 * 3
    assert set(points[0]) == {
        "frequency_hz",
        "voltage_pp",
        "tip_velocity_rms",
        "current_rms",
        "power_w",
        "thrust_n",
        "thrust_per_watt",
    }
    # The numbers are the core's.
    fin = load_fin("M8528-P1")
    p = next(r for r in points if r["frequency_hz"] == 5.5 and r["voltage_pp"] == 800)
    ref = harmonic_balance(fin, 5.5, 800.0)
    assert p["thrust_n"] == pytest.approx(float(ref.thrust_n), rel=1e-12)
    assert p["thrust_per_watt"] == pytest.approx(p["thrust_n"] / p["power_w"], rel=1e-12)


@pytest.mark.slow
def test_ros2_run_alias_and_plot(tmp_path: Path) -> None:
    png = tmp_path / "sweep.png"
    proc = run("sweep", "--fin", "M8507-P1", "--vpp", "800", "--freq", "5", "10", "--plot", str(png))
    assert proc.returncode == 0, proc.stderr
    assert "M8507-P1" in proc.stdout and len(proc.stdout.splitlines()) == 2 + 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_fin_file_path(tmp_path: Path) -> None:
    text = (Path(__file__).parents[2] / "config" / "fins" / "M8514-P1.yaml").read_text()
    fin_file = tmp_path / "my_fin.yaml"
    fin_file.write_text(text.replace("name: M8514-P1", "name: my-fin"))
    proc = run("piezofin", "sweep", "--fin", str(fin_file), "--freq", "10", "--json")
    assert json.loads(proc.stdout)["fin"] == "my-fin"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--fin", "nope"], "unknown fin 'nope'"),
        (["--freq", "5:1:1"], "need start <= stop"),
        (["--freq", "abc"], "cannot read 'abc'"),
        (["--vpp", "-5"], "voltages must be finite"),
        (["--plot", "/proc/nonexistent/x.png", "--freq", "5"], "cannot write"),
    ],
)
def test_errors_are_one_line_without_traceback(args: list[str], message: str) -> None:
    proc = run("piezofin", "sweep", *args)
    assert proc.returncode == 2
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr


def test_bad_fin_file_names_the_key(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nL: 0.1\n")
    proc = run("piezofin", "sweep", "--fin", str(bad))
    assert proc.returncode == 2 and "missing field 'L_active'" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_frequency_spec_includes_the_stop() -> None:
    f = parse_frequencies(["1:11:0.1"])
    assert f.size == 101 and f[0] == 1.0 and f[-1] == 11.0
    assert list(parse_frequencies(["2", "3:4:0.5"])) == [2.0, 3.0, 3.5, 4.0]
    with pytest.raises(UsageError):
        parse_frequencies(["0"])


#: modules of a second or more each: a command line that refuses its input loads none of them
HEAVY = ("scipy.stats", "scipy.optimize", "scipy.signal", "matplotlib", "piezofin_ros.diagnosis.attribute")


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["sweep", "--vpp", "-1"],
        ["diagnose", "{tmp}/bad.csv"],
        ["watts", "--help"],
        ["swim", "--help"],
    ],
    ids=["help", "sweep refused", "diagnose refused", "watts help", "swim help"],
)
def test_a_command_line_refusing_its_input_loads_nothing_heavy(tmp_path: Path, argv: list[str]) -> None:
    """``piezofin``'s parser read the paper's fin names from a module that imported scipy.stats and
    scipy.optimize, and ``diagnose`` imported its fits before reading its file: every command, and
    every refusal, took a second or more (``--help`` 1.6 s, now 0.3 s).  The heavy modules are
    imported where they are used."""
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code = (
        "import sys\nfrom piezofin_ros.cli.main import main\n"
        f"try:\n    main({args!r})\nexcept SystemExit:\n    pass\n"
        f"print('loaded:', *(m for m in {HEAVY!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.splitlines()[-1] == "loaded:", out.stdout[-500:]
