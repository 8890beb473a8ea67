"""Any rig's recording (issue 17): what a bag the suite did not write does to the diagnosis.

Each test rewrites the committed sample bag (two protocol trials of M8528-P1 at 800 Vpp) the way
another rig's driver or another lab's instruments would have recorded it: split into a rosbag2
directory, sampled at 500 Hz, without command messages, with 50 Hz mains pickup on the current,
with a sensor's sign reversed.  Then it reads it as a user does (``from_bags``, ``piezofin
diagnose``) and checks what is said and what is computed.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from piezofin_ros.bags import BagError, BagWriter, block_of, read_messages
from piezofin_ros.bags.blocks import Block
from piezofin_ros.diagnosis.attribute import diagnose
from piezofin_ros.diagnosis.blind import BlindCase, named_family, simulate_blind
from piezofin_ros.diagnosis.data import from_bags, from_csv, scan_bag
from piezofin_ros.diagnosis.report import text as report_text
from piezofin_ros.estimation.estimator import EstimatorConfig, StreamEstimator, analyse_window
from piezofin_ros.physics.fin import load_fin
from test.bags.test_bagio import cdr_block

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_M8528-P1.mcap"
FIN = load_fin("M8528-P1")
EXE = Path(sys.executable).parent / "piezofin"


Edit = Callable[[str, Block], Block | None]


def rewrite(path: Path, edit: Edit | None = None, drop: tuple[str, ...] = ()) -> Path:
    """The sample bag through ``edit(topic, block)`` (None: the message as it is), without ``drop``."""
    with BagWriter(path) as bag:
        for m in read_messages(SAMPLE):
            if m.topic in drop:
                continue
            data = m.data
            if edit is not None and m.type_name.endswith("Float64MultiArray"):
                new = edit(m.topic, block_of(m.type_name, m.data))
                if new is not None:
                    data = cdr_block(new)
            bag.add_topic(m.topic, m.type_name)
            bag.write(m.topic, m.log_time_ns, data)
    return path


def _channel(block: Block, name: str, fn: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> Block:
    values = block.values.copy()
    k = block.names.index(name)
    values[k] = fn(block["t_s"], values[k])
    return Block(block.names, values)


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def clean() -> tuple:
    trials, skipped = from_bags([SAMPLE], FIN)
    assert not skipped and len(trials) == 2
    return trials, scan_bag(SAMPLE, "/fin")


@pytest.mark.slow
def test_a_rosbag2_directory_reads_like_its_file(tmp_path: Path, clean: tuple) -> None:
    """rosbag2 writes a directory (metadata.yaml and numbered .mcap splits); it is read in the order
    the metadata lists, and gives exactly what the file gives."""
    messages = list(read_messages(SAMPLE))
    cut = messages[len(messages) // 2].log_time_ns
    run = tmp_path / "run"
    run.mkdir()
    parts = {
        "run_0.mcap": [m for m in messages if m.log_time_ns < cut],
        "run_1.mcap": [m for m in messages if m.log_time_ns >= cut],
    }
    for name, msgs in parts.items():
        with BagWriter(run / name) as bag:
            for m in msgs:
                bag.add_topic(m.topic, m.type_name)
                bag.write(m.topic, m.log_time_ns, m.data)
    (run / "metadata.yaml").write_text(
        yaml.safe_dump(
            {
                "rosbag2_bagfile_information": {
                    "version": 9,
                    "storage_identifier": "mcap",
                    "relative_file_paths": list(parts),
                }
            }
        )
    )
    again = list(read_messages(run))
    assert [(m.topic, m.log_time_ns, m.data) for m in again] == [
        (m.topic, m.log_time_ns, m.data) for m in messages
    ]
    trials, _ = from_bags([run], FIN)
    assert np.allclose(trials.current_rms, clean[0].current_rms, rtol=1e-12)
    out = tmp_path / "d.json"
    r = subprocess.run(
        [EXE, "diagnose", str(run), "--fin", "M8528-P1", "--json", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(out.read_text())["trials"] == 2
    # mistakes, each one line naming the directory
    empty = tmp_path / "empty"
    empty.mkdir()
    sqlite = tmp_path / "sqlite"
    sqlite.mkdir()
    (sqlite / "metadata.yaml").write_text(
        "rosbag2_bagfile_information: {storage_identifier: sqlite3, relative_file_paths: [a.db3]}\n"
    )
    missing = tmp_path / "missing"
    missing.mkdir()
    (missing / "metadata.yaml").write_text(
        "rosbag2_bagfile_information: {storage_identifier: mcap, relative_file_paths: [gone_0.mcap]}\n"
    )
    for bad, why in ((empty, "no .mcap file"), (sqlite, "'sqlite3' storage"), (missing, "gone_0.mcap")):
        with pytest.raises(BagError, match=why):
            list(read_messages(bad))
        r = subprocess.run(
            [EXE, "diagnose", str(bad), "--fin", "M8528-P1"], capture_output=True, text=True, timeout=120
        )
        assert r.returncode != 0 and str(bad) in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_split_files_are_read_in_rosbag2_order_without_metadata(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    for k in (10, 2, 1):
        with BagWriter(run / f"run_{k}.mcap") as bag:
            bag.add_topic("/x", "std_msgs/msg/Float64MultiArray")
            bag.write("/x", k, cdr_block(Block(("a",), np.array([[float(k)]]))))
    assert [m.log_time_ns for m in read_messages(run)] == [1, 2, 10]
    (run / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")  # lists no file
    assert [m.log_time_ns for m in read_messages(run)] == [1, 2, 10]


@pytest.mark.slow
def test_mains_pickup_is_named_and_rejected_by_the_lock_in(tmp_path: Path, clean: tuple) -> None:
    """30 uA of 50 Hz on the current channel: the RMS current comes from the lock-in (unchanged), the
    noise from the drive-off stretches net of the line (unchanged), and the line is named."""

    def mains(topic: str, block: Block) -> Block | None:
        if topic != "/fin/drive":
            return None
        return _channel(block, "current_A", lambda t, i: i + 30e-6 * np.sin(2 * math.pi * 50.0 * t + 0.4))

    bag = rewrite(tmp_path / "mains.mcap", mains)
    trials, _ = from_bags([bag], FIN)
    ref, ref_scan = clean
    assert np.allclose(trials.current_rms, ref.current_rms, rtol=2e-3)
    scan = scan_bag(bag, "/fin")
    assert scan.noise.current == pytest.approx(ref_scan.noise.current, rel=0.1)  # not the line's 21 uA
    assert not ref_scan.lines  # the fin ringing down after a burst is no interference
    (line,) = [ln for ln in scan.lines if ln.channel == "current"]
    assert line.frequency_hz == pytest.approx(50.0, abs=0.05) and line.amplitude == pytest.approx(
        30e-6, rel=0.05
    )
    assert any(
        "current channel: a 50.00 Hz line of " in n and "lock-in rejects it" in n for n in trials.notes
    )
    d, d0 = diagnose(trials, FIN), diagnose(ref, FIN)
    assert d.verdict == d0.verdict
    assert any("interference on the current channel" in n for n in d.notes)


def test_the_sample_rate_comes_from_the_block_times(tmp_path: Path, clean: tuple) -> None:
    """A rig sampling at 500 Hz: the noise model uses 500 Hz (not 1 kHz) and the estimates hold."""

    def half(topic: str, block: Block) -> Block | None:
        if topic not in ("/fin/drive", "/fin/tip_velocity"):
            return None
        return Block(block.names, block.values[:, ::2])

    bag = rewrite(tmp_path / "500hz.mcap", half)
    assert scan_bag(bag, "/fin").sample_rate_hz == pytest.approx(500.0, rel=1e-4)
    trials, _ = from_bags([bag], FIN)
    ref = clean[0]
    assert np.allclose(trials.current_rms, ref.current_rms, rtol=5e-3)
    assert np.allclose(trials.tip_velocity_rms, ref.tip_velocity_rms, rtol=5e-3)
    assert any("sampled at 500 Hz" in n for n in trials.notes)


@pytest.mark.slow
def test_a_bag_without_commands_is_said_and_the_drive_is_not_judged_against_itself(
    tmp_path: Path,
) -> None:
    bag = rewrite(tmp_path / "nocmd.mcap", drop=("/fin/cmd",))
    trials, _ = from_bags([bag], FIN)
    assert not trials.commanded
    assert any("no command messages" in n for n in trials.notes)
    d = diagnose(trials, FIN)
    assert "drive" not in {s.stage for s in d.stages}
    assert any("no command messages" in n for n in d.notes)
    with_cmd, _ = from_bags([SAMPLE], FIN)
    assert with_cmd.commanded and "drive" in {s.stage for s in diagnose(with_cmd, FIN).stages}


@pytest.mark.slow  # the fast tier has the blind generator's reversed vibrometer (test_blind_instruments)
@pytest.mark.parametrize(
    ("channel", "said"),
    [
        ("tip_velocity_m_s", "the vibrometer's sign is reversed"),
        ("current_A", "the current monitor's sign is reversed"),
        ("voltage_V", "the voltage channel's sign is reversed"),
    ],
)
def test_a_reversed_sensor_is_found_and_corrected(
    tmp_path: Path, clean: tuple, channel: str, said: str
) -> None:
    """Sign conventions (docs/reference.md): a fin only absorbs power.  A flipped sensor makes it
    give power back; the diagnosis says which sensor and corrects it, and finds what the correct
    recording gives."""

    def flip(topic: str, block: Block) -> Block | None:
        if channel not in block.names:
            return None
        return _channel(block, channel, lambda t, x: -x)

    bag = rewrite(tmp_path / "flip.mcap", flip)
    trials, _ = from_bags([bag], FIN)
    d, d0 = diagnose(trials, FIN), diagnose(clean[0], FIN)
    assert any(n.startswith(said) for n in d.notes), d.notes
    assert d.headline.startswith(f"found and corrected: {said}"), d.headline  # the lead, not a note
    assert d.verdict == d0.verdict
    assert [s.chi2 for s in d.stages] == pytest.approx([s.chi2 for s in d0.stages], rel=0.05, abs=0.5)


def test_the_current_rms_is_the_lock_in_s() -> None:
    """Interference at no odd harmonic of the drive stays out of the RMS current (a sample RMS has it)."""
    fs, f = 1000.0, 7.0
    t = np.arange(int(fs * 3 / f * 7)) / fs  # whole periods
    t = t[t < math.floor(t[-1] * f) / f]
    v = 400 * np.sin(2 * math.pi * f * t)
    i = 300e-6 * np.cos(2 * math.pi * f * t)
    clean = analyse_window(FIN, t, v, i, f)["current_rms"]
    hum = analyse_window(FIN, t, v, i + 30e-6 * np.sin(2 * math.pi * 50 * t), f)["current_rms"]
    assert clean == pytest.approx(300e-6 / math.sqrt(2), rel=1e-3)
    assert hum == pytest.approx(clean, rel=2e-3)
    assert math.sqrt(np.mean((i + 30e-6 * np.sin(2 * math.pi * 50 * t)) ** 2)) > 1.004 * clean


def _burst(amplitudes: np.ndarray, f: float, fs: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
    """A drive whose amplitude per period is ``amplitudes`` (V), with 10 s off before and after."""
    per = round(fs / f)
    env = np.concatenate([np.zeros(int(10 * fs)), np.repeat(amplitudes, per), np.zeros(int(10 * fs))])
    t = np.arange(env.size) / fs
    return t, env * np.sin(2 * math.pi * f * t)


@pytest.mark.parametrize("seed", range(4))
def test_a_ramp_tail_and_a_wandering_amplitude_do_not_split_a_trial(seed: int) -> None:
    """The first period of a burst is the tail of a ramp (97.5 %), and the amplitude then wanders by
    1 % (an amplifier's sag, warming): one trial, as the rig ran one.  Compared with its first
    period only, the segment split in two (34 trials found for 33)."""
    rng = np.random.default_rng(seed)
    f = 10.0
    amps = 400 * np.concatenate(
        [[0.5, 0.8, 0.975], 1 + 0.01 * np.sin(np.arange(150) / 7 + rng.uniform(0, 6))]
    )
    t, v = _burst(amps, f)
    est = StreamEstimator(FIN, EstimatorConfig())
    out = est.add_drive(t, v, np.zeros_like(v)) + est.flush()
    finals = [e for e in out if e.final == 1.0]
    assert len(finals) == 1
    assert finals[0].voltage_pp == pytest.approx(800, rel=0.01)
    assert finals[0].t_end - finals[0].t_start > 10.0


def test_a_step_of_the_drive_still_splits() -> None:
    t, v = _burst(np.concatenate([np.full(80, 400.0), np.full(80, 300.0)]), 10.0)
    est = StreamEstimator(FIN, EstimatorConfig())
    finals = [e for e in est.add_drive(t, v, np.zeros_like(v)) + est.flush() if e.final == 1.0]
    assert [round(e.voltage_pp) for e in finals] == [800, 600]


@pytest.mark.fast_cases("vibrometer_reversed-1.0-vibrometer reversed")
@pytest.mark.parametrize(
    ("effect", "strength", "family"),
    [
        ("current_lowpass", 2.0, "current monitor"),
        ("vibrometer_reversed", 1.0, "vibrometer reversed"),
        ("mains", 30e-6, None),
        ("", 0.0, None),
    ],
)
def test_blind_instruments(effect: str, strength: float, family: str | None) -> None:
    """The blind generator's instruments, in forms the library lacks (a low-pass, not a delay):
    the right family is named, and mains pickup alone or clean data give "no gap"."""
    case = BlindCase("M8528-P1", effect, strength, seed=5)
    d = diagnose(simulate_blind(case), FIN)
    assert named_family(d) == family, (d.verdict, d.named, d.notes)
    if family is None:
        assert d.verdict == "no gap"
    # the verdict's line leads with what was found (issue 29): the sensor corrected, the family
    assert f"**Verdict: {d.headline}.**" in report_text(d)
    if family == "vibrometer reversed":
        assert d.headline.startswith("found and corrected: the vibrometer's sign is reversed"), d.headline
        assert d.headline.endswith("no gap: every stage agrees with the model within the measurement noise")
    elif family is not None and d.verdict == "unexplained":
        assert d.headline.startswith(f"the {family} family, in another form: "), d.headline
        assert f"{d.family_removed:.0%} of the gap removed" in d.headline


@pytest.mark.slow
def test_trial_times_survive_a_csv_and_a_drift_is_fitted_on_them(tmp_path: Path) -> None:
    """A capacitance warming over the run (blind form: exponential) in a CSV with ``time_s``: the
    drift is named from the CSV as from the table; without the times it cannot be."""
    trials = simulate_blind(BlindCase("M8528-P1", "warming_capacitance", 0.12, seed=2))
    trials.to_csv(tmp_path / "t.csv")
    again = from_csv(tmp_path / "t.csv")
    assert np.array_equal(again.time_s, trials.time_s)
    assert diagnose(again, FIN).named == ("capacitance_drift",)
    timeless = tmp_path / "timeless.csv"
    rows = (tmp_path / "t.csv").read_text().splitlines()
    k = rows[0].split(",").index("time_s")
    timeless.write_text(
        "\n".join(",".join(c for j, c in enumerate(r.split(",")) if j != k) for r in rows) + "\n"
    )
    assert "capacitance_drift" not in diagnose(from_csv(timeless), FIN).named


@pytest.mark.slow
def test_on_a_fish_a_negative_power_names_both_suspects(tmp_path: Path) -> None:
    """Without a vibrometer the tip phase cannot tell a reversed current monitor from a reversed
    voltage channel: both are named, and the power is corrected."""

    def flip(topic: str, block: Block) -> Block | None:
        return _channel(block, "current_A", lambda t, x: -x) if topic == "/fin/drive" else None

    bag = rewrite(tmp_path / "fish.mcap", flip, drop=("/fin/tip_velocity", "/fin/loadcell"))
    trials, _ = from_bags([bag], FIN)
    d = diagnose(trials, FIN)
    assert any("or the voltage channel's: without a vibrometer" in n for n in d.notes), d.notes
    assert np.all(d.trials.power_w > 0)


def with_supply(path: Path, amplifier) -> Path:
    """The sample bag plus the supply's meter of ``amplifier`` (a ``supply`` block beside each drive
    block, from the drive's own samples), as a rig that records its supply would have written it."""
    from piezofin_ros.bags.blocks import SUPPLY_CHANNELS

    with BagWriter(path) as bag:
        bag.add_topic("/fin/supply", "std_msgs/msg/Float64MultiArray")
        for m in read_messages(SAMPLE):
            bag.add_topic(m.topic, m.type_name)
            bag.write(m.topic, m.log_time_ns, m.data)
            if m.topic == "/fin/drive":
                b = block_of(m.type_name, m.data)
                i = amplifier.supply_current(b["voltage_V"], b["current_A"])
                supply = Block.from_columns(
                    **dict(
                        zip(SUPPLY_CHANNELS, (b["t_s"], np.full(i.size, amplifier.supply_v), i), strict=True)
                    )
                )
                bag.write("/fin/supply", m.log_time_ns, cdr_block(supply))
    return path


@pytest.mark.slow
def test_a_recorded_supply_is_checked_against_the_amplifier_and_kept_apart_from_the_fin(
    tmp_path: Path, clean: tuple
) -> None:
    """A bag with the supply's meter: told the amplifier that drove it, the supply stage is inside
    the noise; told another, the stage has the gap and says so, and the fin's verdict does not move
    (the amplifier is not the fin: no effect of the fin is fitted to it).  From the command line too."""
    from piezofin_ros.physics.amplifier import load_amplifier

    fish, bench = load_amplifier("fish-switching"), load_amplifier("paper-bench")
    bag = with_supply(tmp_path / "supply.mcap", fish)
    d0 = diagnose(clean[0], FIN)
    right, _ = from_bags([bag], FIN, amplifier=fish)
    wrong, _ = from_bags([bag], FIN, amplifier=bench)
    assert np.all(np.isfinite(right.power_supply_w)) and np.allclose(right.power_w, clean[0].power_w)
    d_right, d_wrong = diagnose(right, FIN), diagnose(wrong, FIN)
    s_right, s_wrong = (next(s for s in d.stages if s.stage == "supply") for d in (d_right, d_wrong))
    assert not s_right.significant
    assert s_wrong.significant and np.all(s_wrong.relative_gap < -0.1)  # the bench's model draws more
    assert d_right.verdict == d_wrong.verdict == d0.verdict and d_wrong.named == d0.named
    assert any("the supply draws" in n for n in d_wrong.notes)
    assert not any("the supply draws" in n for n in d_right.notes)
    run = subprocess.run(
        [str(EXE), "diagnose", str(bag), "--amplifier", "fish-switching", "--quiet",
         "--json", str(tmp_path / "d.json")],
        capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    where = {s["stage"] for s in json.loads((tmp_path / "d.json").read_text())["where"]}
    assert "supply" in where
    (tmp_path / "bad.yaml").write_text("kind: linear\nrail_v: 0\n")
    bad = subprocess.run(
        [str(EXE), "diagnose", str(bag), "--amplifier", str(tmp_path / "bad.yaml")],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "rail_v" in bad.stderr, bad.stderr
