"""The nodes on real rclpy and Fast DDS, in one process: a live run, its bag, its replay."""

from __future__ import annotations

import itertools
import json
import math
import re
from typing import Any

import numpy as np
import pytest
import yaml
from rclpy.exceptions import InvalidParameterValueException
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rosbags.highlevel import AnyReader
from std_msgs.msg import Float64MultiArray

from piezofin_ros.bags import block_of, read_messages
from piezofin_ros.bags.blocks import Block, BlockFormatError
from piezofin_ros.estimation.estimator import Estimate
from piezofin_ros.nodes._common import (
    QOS_COMMAND,
    QOS_DATA,
    MessageRefused,
    StartupError,
    block_msg,
    drive_command,
)
from piezofin_ros.nodes.controller import Controller
from piezofin_ros.nodes.fin_sim import FinSim
from piezofin_ros.nodes.player import Player
from piezofin_ros.nodes.recorder import Recorder
from piezofin_ros.nodes.speed_loop import drive_point
from piezofin_ros.nodes.thrust_estimator import ThrustEstimator
from piezofin_ros.physics.steady import harmonic_balance

from ..rosutil import data_type, graph


def rclpy_node(name: str, g: Any) -> Any:
    import rclpy

    return rclpy.create_node(name, context=g.context)


pytestmark = pytest.mark.ros

T0 = 1000.0  # simulated start time, far from the wall clock: a wall-clock stamp would show
SIM_TIME = [Parameter("use_sim_time", value=True)]


def params(**kw: Any) -> list[Parameter]:
    return [Parameter(k.replace("__", "."), value=v) for k, v in kw.items()]


#: The tests of the module fixture below: on one test worker, so that it is built once.
ON_ITS_WORKER = pytest.mark.xdist_group("the live graph")


#: The estimator live and in replay: a lagging channel (the load cell) waited for 30 s of the fin's
#: time, 0.6 s of wall time at x50 (the default 2 s, 40 ms, passed on a loaded machine: the live
#: estimate then had part of its post baseline, and replay differed by 1e-4).  (120 s was worse: a
#: live estimate the bag could not complete in replay.  The later failures at a load of 20 were
#: blocks lost in replay, not the wait: see the replay test.)
ESTIMATOR = params(estimator__baseline_s=4.0, estimator__channel_timeout_s=30.0)


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def live(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Two protocol trials (9 and 6 Hz at 800 Vpp), 50x real time, recorded."""
    bag = tmp_path_factory.mktemp("live") / "live.mcap"
    with graph() as g:
        ctx = g.context
        sim = g.add(
            FinSim(
                context=ctx,
                namespace="fin",
                parameter_overrides=params(
                    realtime_factor=50.0, publish_clock=True, start_time_s=T0, autostart=False
                ),
            )
        )
        est = g.add(ThrustEstimator(context=ctx, namespace="fin", parameter_overrides=SIM_TIME + ESTIMATOR))
        ctl = g.add(
            Controller(
                context=ctx,
                namespace="fin",
                parameter_overrides=SIM_TIME
                + params(frequencies=[9.0, 6.0], voltages=[800.0], off_s=6.0, on_s=8.0, min_thrust_n=0.0),
            )
        )
        rec = g.add(
            Recorder(context=ctx, parameter_overrides=SIM_TIME + params(path=str(bag), namespaces=["fin"]))
        )
        assert sim.trigger_configure() == TransitionCallbackReturn.SUCCESS
        g.spin_until(lambda: sim.matched() >= 2, timeout=10.0, what="estimator and recorder matched")
        sim.trigger_activate()
        g.spin_until(lambda: ctl.finished, timeout=60.0, what="two trials")
        sim.trigger_deactivate()
        est.close()
        g.spin_for(0.3)  # let the recorder take the last messages
        rec.close()
        return {
            "bag": bag,
            "fin": est.fin,
            "estimates": list(est.estimates),
            "status": ctl.status(),
            "published": dict(sim.published),
            "recorded": rec.counts,
            "rig": sim.rig,
        }


@ON_ITS_WORKER
def test_live_estimates_match_the_steady_state(live: dict[str, Any]) -> None:
    finals = [e for e in live["estimates"] if e.final]
    assert [round(e.frequency_hz, 3) for e in finals] == [9.0, 6.0]
    for e in finals:
        hb = harmonic_balance(live["fin"], e.frequency_hz, e.voltage_pp, harmonics=3)
        assert e.voltage_pp == pytest.approx(800.0, rel=2e-3)
        assert e.thrust_n == pytest.approx(float(hb.thrust_n), rel=5e-3)
        assert e.thrust_self_n == pytest.approx(e.thrust_n, rel=5e-3)
        cfg = live["rig"].config
        n_on = (e.t_end - e.t_start) * cfg.sample_rate_hz
        sigma = cfg.loadcell_stiffness * cfg.displacement_noise_m * math.sqrt(1 / n_on + 1 / (2 * 4000))
        assert e.loadcell_baselines == 2
        assert abs(e.thrust_loadcell_n - e.thrust_n) <= 5 * sigma + 3e-3 * e.thrust_n


@ON_ITS_WORKER
def test_times_come_from_the_samples_not_the_wall_clock(live: dict[str, Any]) -> None:
    for e in live["estimates"]:
        assert T0 < e.t_start < e.t_end < T0 + 60.0
    times = [m.log_time_ns * 1e-9 for m in read_messages(live["bag"])]
    assert min(times) >= T0 and max(times) < T0 + 60.0  # the recorder logs in simulated time


@ON_ITS_WORKER
def test_controller_reports_both_trials(live: dict[str, Any]) -> None:
    st = live["status"]
    assert st["state"] == "done"
    assert [r["frequency_hz"] for r in st["results"]] == [9.0, 6.0]
    # chosen by thrust per supply watt (the controller's default): what the amplifier draws rises less
    # than the thrust towards resonance, so 9 Hz; per fin watt, mean(v i), 6 Hz would win
    assert st["watt"] == "supply" and st["chosen"]["frequency_hz"] == 9.0
    by = {w: max(st["results"], key=lambda r: r[f"thrust_per_watt_self{w}"]) for w in ("_supply", "")}
    assert by["_supply"]["frequency_hz"] == 9.0 and by[""]["frequency_hz"] == 6.0
    for r in st["results"]:  # every watt of every trial recorded, measured supply within 1 % of the model
        assert r["power_supply_measured_w"] == pytest.approx(r["power_supply_w"], rel=0.01)
        assert r["power_w"] < r["power_apparent_w"] < r["power_supply_w"]


@ON_ITS_WORKER
def test_rosbags_reads_every_recorded_message(live: dict[str, Any]) -> None:
    with AnyReader([live["bag"]]) as reader:
        counts: dict[str, int] = {}
        samples = 0
        for conn, _, raw in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == "/fin/drive":  # (piezofin_msgs/Drive, from the schema the bag carries)
                msg = reader.deserialize(raw, conn.msgtype)
                assert len(msg.voltage_v) == len(msg.current_a) == len(msg.t_s)
                assert msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 == pytest.approx(msg.t_s[0])
                samples += len(msg.t_s)
    assert counts == {k: v for k, v in live["recorded"].items() if v}
    assert samples == live["published"]["drive"]  # not one sample lost between fin_sim and the bag
    assert counts["/fin/estimate"] == len(live["estimates"])
    assert counts["/clock"] > 0


@ON_ITS_WORKER
def test_replay_reproduces_the_live_estimates(live: dict[str, Any]) -> None:
    recorded = [
        Estimate.from_dict(block_of(m.type_name, m.data).as_dict())
        for m in read_messages(live["bag"], ["/fin/estimate"])
    ]
    assert recorded == live["estimates"]
    with graph() as g:
        player = g.add(
            Player(
                context=g.context,
                parameter_overrides=params(
                    bag=str(live["bag"]),
                    # (at 20 a machine at a load of 20 stalled the estimator's looks past its queue of 200
                    # blocks a topic, 0.5 s of them, and a block was lost: at 5, 2 s of stall)
                    rate=5.0,
                    # (and the controller's fitted fin: the estimator's self-sensing followed it live)
                    topics=[
                        "/fin/drive",
                        "/fin/tip_velocity",
                        "/fin/loadcell",
                        "/fin/supply",
                        "/fin/controller/model",
                    ],
                ),
            )
        )
        est = g.add(
            ThrustEstimator(
                context=g.context,
                namespace="fin",
                parameter_overrides=SIM_TIME + ESTIMATOR,
            )
        )
        g.spin_until(lambda: player.done, timeout=60.0, what="replay")
        # every block played heard before the estimator closes: a lost one is said here, not read as
        # an estimate replayed differently (the fast tier, at a load of 20: one estimate for two)
        g.spin_until(
            lambda: all(est.received[k] >= player.published.get(f"/fin/{k}", 0) for k in est.received),
            timeout=60.0,
            what="every block played heard by the estimator",
        )
        g.spin_for(0.3)
        est.close()
        replayed = list(est.estimates)
    assert len(replayed) == len(recorded)
    for a, b in zip(replayed, recorded, strict=True):
        np.testing.assert_allclose(
            np.array(list(a.as_dict().values())),
            np.array(list(b.as_dict().values())),
            rtol=1e-12,
            equal_nan=True,
        )


def test_nodes_build_twice_in_one_process() -> None:
    for _ in range(2):
        with graph() as g:
            for ns in ("left", "right"):
                g.add(FinSim(context=g.context, namespace=ns, parameter_overrides=params(autostart=False)))
                g.add(ThrustEstimator(context=g.context, namespace=ns))
                g.add(Controller(context=g.context, namespace=ns))
            g.spin_for(0.1)
            assert {n.get_fully_qualified_name() for n in g.nodes} >= {"/left/fin_sim", "/right/controller"}


def test_parameters_have_ranges_and_reasons() -> None:
    with graph() as g:
        sim = g.add(FinSim(context=g.context, parameter_overrides=params(autostart=False)))
        desc = sim.describe_parameter("rig.sample_rate_hz")
        assert desc.floating_point_range[0].from_value == 100.0
        assert desc.description
        result = sim.set_parameters([Parameter("rig.sample_rate_hz", value=5.0)])[0]
        assert not result.successful
        assert result.reason
        result = sim.set_parameters([Parameter("block_s", value=0.1)])[0]
        assert not result.successful
        assert "read-only" in result.reason  # (descriptors say it: `ros2 param describe`)
        with pytest.raises((InvalidParameterValueException, StartupError), match=r"limits\.voltage_pp_max"):
            FinSim(
                context=g.context, node_name="over", parameter_overrides=params(limits__voltage_pp_max=2000.0)
            )
        with pytest.raises(StartupError, match=r"realtime_factor.*outside"):
            FinSim(context=g.context, node_name="slow", parameter_overrides=params(realtime_factor=0))
        assert (
            FinSim(context=g.context, node_name="int", parameter_overrides=params(block_s=1))._block_s == 1.0
        )
        with pytest.raises(StartupError, match="mode"):
            Controller(context=g.context, parameter_overrides=params(mode="sometimes"))
        with pytest.raises(StartupError, match="outside"):
            Controller(context=g.context, node_name="c2", parameter_overrides=params(voltages=[900.0]))
        bad_fin = g.add(
            FinSim(context=g.context, node_name="nofin", parameter_overrides=params(fin="M0000-X"))
        )
        assert bad_fin.trigger_configure() == TransitionCallbackReturn.FAILURE
        with pytest.raises(StartupError, match="objective"):
            Controller(context=g.context, node_name="c3", parameter_overrides=params(objective="speed"))
        fish = g.add(
            Controller(
                context=g.context,
                node_name="c4",
                parameter_overrides=params(mode="optimise", objective="range", fixed_draw_w=0.3),
            )
        )
        assert (
            fish.loop is not None
            and fish.loop.optimiser.objective.name == "speed per watt with 0.3 W of fixed draw (range)"
        )
        assert fish.describe_parameter("objective").additional_constraints == "one of: thrust_per_watt, range"
        assert fish.describe_parameter("objective").read_only
        model = fish._diagnose_model()  # (on /diagnostics as "c4: fin model": WARN once a prior is dropped)
        assert model.level == 0 and model.message == "M8528-P1, corrected by 0 trials", model


def test_fin_sim_and_controller_load_a_diagnosed_model(tmp_path: Any) -> None:
    """`-p model:=augmented_model.yaml`: fin_sim streams the diagnosed model, the optimiser starts
    from it; a bad model fails at start naming the parameter and the file."""
    from piezofin_ros.physics.fin import load_fin
    from piezofin_ros.physics.model import Model

    fin = load_fin("M8528-P1")
    model = Model.of(fin, {"drag_offset": [3.0]})
    path = tmp_path / "augmented_model.yaml"
    path.write_text(yaml.safe_dump(model.to_mapping()))
    bad = tmp_path / "bad.yaml"
    bad.write_text("fin: {}\neffects: {warp_drive: {}}\n")
    with graph() as g:
        sim = g.add(FinSim(context=g.context, parameter_overrides=params(autostart=False, model=str(path))))
        assert sim.trigger_configure() == TransitionCallbackReturn.SUCCESS
        rig = sim.rig
        assert rig is not None and rig.model is not None
        for _ in range(12):
            rig.command(9.0, 800.0, 1.0)
            block = rig.step(500)
        tip = float(np.sqrt(np.mean(block.tip_velocity**2)))
        assert tip == pytest.approx(float(model.predict(9.0, 800.0).tip_velocity_rms), rel=0.03)
        assert tip < 0.7 * float(harmonic_balance(fin, 9.0, 800.0).tip_velocity_rms)  # 3x drag shows
        broken = g.add(
            FinSim(context=g.context, node_name="broken", parameter_overrides=params(model=str(bad)))
        )
        assert broken.trigger_configure() == TransitionCallbackReturn.FAILURE
        ctl = g.add(
            Controller(context=g.context, parameter_overrides=params(mode="optimise", model=str(path)))
        )
        assert ctl.loop is not None and ctl.loop.optimiser.model is not None
        ctl.strategy.command(1.0)  # its first tick publishes a JSON status (it raised TypeError with a model)
        ctl._publish_status()
        assert json.loads(json.dumps(ctl.status()))["correction"]["resonance_scale"] == 1.0
        with pytest.raises(StartupError, match=r"parameter model: .*bad\.yaml"):
            Controller(
                context=g.context, node_name="c3", parameter_overrides=params(mode="optimise", model=str(bad))
            )


def test_the_estimator_takes_a_diagnosed_model_for_its_self_sensing(tmp_path) -> None:
    """`thrust_estimator -p model:=...`: its capacitance, loss, coupling and c_m calibrate every
    estimate (the live numbers are in test/estimation/test_selfsense.py); a bad file fails at start
    naming the parameter and the file."""
    from piezofin_ros.physics.fin import load_fin
    from piezofin_ros.physics.model import Model

    model = Model.of(load_fin("M8528-P1"), {"dielectric_loss": [0.08], "added_mass_offset": [1.2]})
    path = tmp_path / "augmented_model.yaml"
    path.write_text(yaml.safe_dump(model.to_mapping()))
    bad = tmp_path / "bad.yaml"
    bad.write_text("fin: {}\neffects: {warp_drive: {}}\n")
    with graph() as g:
        est = g.add(ThrustEstimator(context=g.context, parameter_overrides=params(model=str(path))))
        assert est.core.calibrate is not None
        cal = est.core.calibrate(9.0, 800.0)
        assert float(cal.conductance_s) == pytest.approx(0.08 * model.fin.C_eq * 2 * math.pi * 9.0)
        assert float(cal.mass) == pytest.approx(1.2) and float(cal.capacitance) == 1.0
        assert ThrustEstimator(context=g.context, node_name="plain").core.calibrate is None
        with pytest.raises(StartupError, match=r"parameter model: .*bad\.yaml"):
            ThrustEstimator(context=g.context, node_name="e3", parameter_overrides=params(model=str(bad)))


def test_a_drive_command_is_read_one_way_by_the_rig_and_the_speed_loop() -> None:
    """``cmd`` as a person types it (three numbers, then the optional offset) or labelled, read by
    one function (``drive_command``) for ``fin_sim`` and for the speed loop's door (``drive_point``,
    which then judges the values); one sample only, a malformed one refused with the reason."""
    assert drive_command(Float64MultiArray(data=[5.5, 800.0, 1.0])) == (5.5, 800.0, 1.0, 0.0)
    assert drive_command(Float64MultiArray(data=[5.5, 400.0, 1.0, -120.0])) == (5.5, 400.0, 1.0, -120.0)
    labelled = Block.from_columns(frequency_hz=[4.0], voltage_pp_V=[300.0], on=[0.0], bias_V=[50.0])
    assert drive_command(block_msg(labelled)) == (4.0, 300.0, 0.0, 50.0)
    assert drive_point(block_msg(labelled)) == (0.0, 4.0)  # (off: no voltage on the fin)
    assert drive_point(Float64MultiArray(data=[5.5, 800.0, 1.0])) == (800.0, 5.5)
    two = Block.from_columns(frequency_hz=[4.0, 5.0], voltage_pp_V=[300.0, 300.0], on=[1.0, 1.0])
    for read in (drive_command, drive_point):
        with pytest.raises(MessageRefused, match="one sample, got 2"):
            read(block_msg(two))
        with pytest.raises(BlockFormatError, match="must hold 3"):
            read(Float64MultiArray(data=[5.5, 800.0]))
    with pytest.raises(MessageRefused, match="hard cap"):
        drive_point(Float64MultiArray(data=[5.5, 1e4, 1.0]))


def test_inactive_fin_sim_drives_nothing_and_bad_commands_are_logged() -> None:
    with graph() as g:
        sim = g.add(
            FinSim(context=g.context, parameter_overrides=params(autostart=False, realtime_factor=20.0))
        )
        probe = g.add(__import__("rclpy").create_node("probe", context=g.context))
        drive: list[Block] = []
        probe.create_subscription(data_type("drive"), "drive", lambda m: drive.append(m), QOS_DATA)
        cmd = probe.create_publisher(Float64MultiArray, "cmd", QOS_COMMAND)

        def send(f: float, v: float, on: float) -> None:
            cmd.publish(block_msg(Block.from_record({"frequency_hz": f, "voltage_pp_V": v, "on": on})))

        sim.trigger_configure()
        g.spin_for(0.3)
        send(5.0, 800.0, 1.0)
        g.spin_until(lambda: sim.command_log, timeout=5.0)
        assert "not active" in sim.command_log[-1]
        assert drive == []
        sim.trigger_activate()
        g.spin_until(lambda: len(drive) > 3, timeout=5.0)
        for f, v, on, why in [
            (5.0, 2000.0, 1.0, "clamped"),
            (math.nan, 400.0, 1.0, "non-finite"),
            (-3.0, 100.0, 1.0, "outside"),
        ]:
            send(f, v, on)
            g.spin_until(
                lambda why=why: sim.command_log and why in sim.command_log[-1], timeout=5.0, what=why
            )
        bad = Float64MultiArray(data=[1.0, 2.0])
        cmd.publish(bad)
        g.spin_until(lambda: "malformed" in sim.command_log[-1], timeout=5.0)
        sim.trigger_deactivate()  # publishes the ramp to zero, then nothing more
        g.spin_for(0.3)
        n = len(drive)
        g.spin_for(0.3)
        assert len(drive) == n
        from piezofin_ros.nodes._common import msg_block

        v = np.concatenate([msg_block(m)["voltage_V"] for m in drive])
        assert np.max(np.abs(v)) <= 400.0 + 5 * 0.2 * 6  # never beyond 800 Vpp (noise aside)
        assert np.all(np.abs(v[-20:]) < 2.0)  # deactivate ramped it to zero


def test_a_flood_of_one_refusal_never_hides_a_clamp(capfd: pytest.CaptureFixture[str]) -> None:
    """Refusals are said at most once a second per kind: 20 malformed commands, then one that is
    clamped, within the same second: both kinds are said, and the next line of the flooded kind says
    how many of its kind went unsaid (CI once saw a clamp hidden behind a second of rejections)."""
    with graph() as g:
        sim = g.add(FinSim(context=g.context, parameter_overrides=params(realtime_factor=5.0)))
        probe = g.add(__import__("rclpy").create_node("probe", context=g.context))
        cmd = probe.create_publisher(Float64MultiArray, "cmd", QOS_COMMAND)
        sim.trigger_configure()
        sim.trigger_activate()
        g.spin_until(lambda: cmd.get_subscription_count() >= 1, timeout=10.0)
        for _ in range(20):
            cmd.publish(Float64MultiArray(data=[1.0, 2.0]))
            g.spin_for(0.01)
        cmd.publish(block_msg(Block.from_record({"frequency_hz": 5.0, "voltage_pp_V": 2000.0, "on": 1.0})))
        g.spin_until(lambda: sim.command_counts["clamped"] >= 1, timeout=5.0, what="the clamp")
        flooded = sim.command_counts["rejected"]
        g.spin_for(1.1)  # past the second: the next rejection is said with the count of the rest
        cmd.publish(Float64MultiArray(data=[1.0, 2.0]))
        g.spin_until(lambda: sim.command_counts["rejected"] > flooded, timeout=5.0, what="the last one")
        total = sim.command_counts["rejected"]
    err = capfd.readouterr().err
    assert flooded > 5 and "clamped:" in err, err
    # every rejection said or counted on the next line of its kind (a loaded machine may say one more
    # line within the flood; the last one, after a quiet second, is said with the rest)
    said = err.count("rejected: malformed command")
    unsaid = sum(int(n) for n in re.findall(r"\(and (\d+) more rejected since the last such line\)", err))
    assert said >= 2 and unsaid >= 1 and said + unsaid == total, (said, unsaid, total, err)


def test_drive_limits_can_be_tightened_live_over_the_parameter_service() -> None:
    """An operator lowers the cap on a running fin (`ros2 param set /fin_sim limits.voltage_pp_max 400`):
    the drive ramps down to it at once; relaxing a limit is refused with the reason; a band that
    leaves the running frequency out ramps the drive to zero."""
    from rclpy.parameter_client import AsyncParameterClient

    from piezofin_ros.nodes._common import msg_block

    with graph() as g:
        sim = g.add(FinSim(context=g.context, parameter_overrides=params(realtime_factor=10.0)))
        operator = g.add(__import__("rclpy").create_node("operator", context=g.context))
        drive: list[Any] = []
        operator.create_subscription(data_type("drive"), "drive", drive.append, QOS_DATA)
        cmd = operator.create_publisher(Float64MultiArray, "cmd", QOS_COMMAND)
        client = AsyncParameterClient(operator, "fin_sim")
        g.spin_until(client.services_are_ready, timeout=10.0, what="fin_sim's parameter services")

        def command(f: float, v: float) -> None:
            cmd.publish(block_msg(Block.from_record({"frequency_hz": f, "voltage_pp_V": v, "on": 1.0})))

        def set_limit(name: str, value: float) -> Any:
            future = client.set_parameters([Parameter(f"limits.{name}", value=value)])
            g.spin_until(future.done, timeout=10.0, what=f"set {name}")
            return future.result().results[0]

        def peak_after(t: float) -> float:
            blocks = [msg_block(m) for m in drive]
            v = np.concatenate([b["voltage_V"][b["t_s"] > t] for b in blocks])
            return float(np.max(np.abs(v))) if v.size else math.nan

        def latest_t() -> float:
            return float(msg_block(drive[-1])["t_s"][-1])

        sim.trigger_configure()
        sim.trigger_activate()
        g.spin_until(lambda: cmd.get_subscription_count() >= 1 and len(drive) > 0, timeout=10.0)
        for _ in range(10):  # 800 Vpp at 5 Hz, kept fed against the watchdog
            command(5.0, 800.0)
            g.spin_for(0.05)
        assert peak_after(latest_t() - 0.25) > 390.0
        result = set_limit("voltage_pp_max", 400.0)
        assert result.successful, result.reason
        t_set = latest_t()
        for _ in range(10):
            command(5.0, 800.0)  # still asks for 800: now clamped to 400
            g.spin_for(0.05)
        assert peak_after(t_set + 0.15) <= 200.0 + 2.0  # ramped within 0.1 s at 4000 Vpp/s (noise 0.2 V)
        assert "clamped" in sim.command_log[-1]
        refused = set_limit("voltage_pp_max", 600.0)
        assert not refused.successful and "only tighter limits" in refused.reason
        assert sim.get_parameter("limits.voltage_pp_max").value == 400.0
        assert set_limit("frequency_max_hz", 4.0).successful  # 5 Hz is now out of band
        t_band = latest_t()
        g.spin_for(0.3)
        assert peak_after(t_band + 0.15) < 2.0


def test_fin_sim_protocol_mode_one_command_one_trial() -> None:
    """`-p protocol:=true`: one typed command runs the paper's trial; the estimator reports it."""
    with graph() as g:
        sim = g.add(
            FinSim(
                context=g.context,
                parameter_overrides=params(
                    autostart=False, protocol=True, protocol_off_s=4.0, protocol_on_s=6.0,
                    realtime_factor=50.0, publish_clock=True, start_time_s=T0,
                ),
            )
        )  # fmt: skip
        est = g.add(
            ThrustEstimator(
                context=g.context, parameter_overrides=SIM_TIME + params(estimator__baseline_s=3.0)
            )
        )
        probe = g.add(__import__("rclpy").create_node("probe", context=g.context))
        cmd = probe.create_publisher(Float64MultiArray, "cmd", QOS_COMMAND)
        sim.trigger_configure()
        g.spin_until(lambda: sim.matched() >= 1 and cmd.get_subscription_count() >= 1, timeout=10.0)
        sim.trigger_activate()
        cmd.publish(Float64MultiArray(data=[9.0, 800.0, 1.0]))  # unlabelled, as typed by a person
        g.spin_until(lambda: any(e.final for e in est.estimates), timeout=30.0, what="the trial's estimate")
        e = next(e for e in est.estimates if e.final)
        assert e.frequency_hz == pytest.approx(9.0, rel=1e-4)
        assert e.loadcell_baselines == 2
        assert T0 + 4.0 < e.t_start < e.t_end <= T0 + 10.0 + 1e-3


def test_the_first_trial_waits_for_an_estimator_that_starts_last() -> None:
    """Under ros2 launch the estimator may start last: the controller holds the drive off and starts
    trial 0 only once an estimator publishes, so trial 0 gets its estimate (CI once lost it).  In a
    namespace of its own: an estimator an earlier test destroyed may linger in DDS discovery for a
    moment, and under parallel tests it was taken for this one's."""
    with graph() as g:
        ctx = g.context
        sim = g.add(
            FinSim(
                context=ctx,
                namespace="late",
                parameter_overrides=params(realtime_factor=20.0, publish_clock=True, start_time_s=T0),
            )
        )
        sim.trigger_configure()
        sim.trigger_activate()
        ctl = g.add(
            Controller(
                context=ctx,
                namespace="late",
                parameter_overrides=SIM_TIME
                + params(frequencies=[9.0], voltages=[800.0], off_s=1.0, on_s=4.0, wait_estimator_s=60.0),
            )
        )
        # 30 s of fin time with no estimator: nothing driven, the plan not begun (waited for in fin
        # time: at x20 that is 1.5 s of wall time, but a loaded machine once gave only 30.0 s in 3 s)
        rig = sim.rig
        assert rig is not None
        g.spin_until(lambda: rig.drive.t > T0 + 30.0, timeout=60.0, what="30 s of fin time")
        assert ctl.runner.t_begin is None and not ctl.runner.results
        assert rig.drive.amplitude == 0.0
        g.add(
            ThrustEstimator(
                context=ctx,
                namespace="late",
                parameter_overrides=SIM_TIME + params(estimator__baseline_s=0.5),
            )
        )
        g.spin_until(lambda: ctl.finished, timeout=30.0, what="the one trial")
    (result,) = ctl.runner.results
    assert result.estimate is not None and result.estimate.frequency_hz == pytest.approx(9.0, rel=1e-3)
    assert ctl.status()["state"] == "done"


def test_optimising_controller_ramps_down_when_estimates_stop() -> None:
    """Live: the controller optimises from self-sensed estimates; kill the estimator, the drive ramps to 0."""
    with graph() as g:
        ctx = g.context
        sim = g.add(
            FinSim(
                context=ctx,
                parameter_overrides=params(
                    autostart=False, realtime_factor=50.0, publish_clock=True, start_time_s=T0
                ),
            )
        )
        est = ThrustEstimator(
            context=ctx,
            parameter_overrides=SIM_TIME + params(estimator__window_s=2.0, estimator__settle_s=2.0),
        )
        g.executor.add_node(est)
        ctl = g.add(
            Controller(
                context=ctx,
                parameter_overrides=SIM_TIME
                + params(mode="optimise", demand_n=4e-3, estimate_timeout_s=3.0, slew_vpp_per_s=400.0),
            )
        )
        probe = g.add(__import__("rclpy").create_node("probe", context=ctx, parameter_overrides=SIM_TIME))
        sent: list[tuple[float, float, float]] = []
        states: list[str] = []  # the loop's state as each command arrived (one executor: no race)

        def on_cmd(m: Float64MultiArray) -> None:
            from piezofin_ros.nodes._common import msg_block

            b = msg_block(m)
            sent.append(
                (probe.get_clock().now().nanoseconds * 1e-9, b.scalar("voltage_pp_V"), b.scalar("on"))
            )
            states.append(ctl.loop.state)

        probe.create_subscription(Float64MultiArray, "cmd", on_cmd, QOS_COMMAND)
        sim.trigger_configure()
        g.spin_until(lambda: sim.matched() >= 1, timeout=10.0)
        sim.trigger_activate()
        g.spin_until(lambda: ctl.loop.trials >= 2, timeout=60.0, what="two optimiser trials")
        assert max(v for _, v, _ in sent) <= 800.0
        # one 2 s running window at a settled point: its noise, as test_selfsense's windows (a
        # whole segment agrees within 0.5 %, test_live_estimates_match_the_steady_state)
        assert ctl.status()["self_vs_vibrometer"] == pytest.approx(0.0, abs=0.02)
        # the estimator dies: out of the executor (destroyed only at the end: the executor may still
        # run a callback it had queued, which a destroyed node's publisher answers with InvalidHandle)
        g.executor.remove_node(est)
        t_kill = sent[-1][0]
        g.spin_until(lambda: ctl.loop.state == "stopped", timeout=60.0, what="ramp down")
        g.spin_for(0.2)
        assert sent[-1][1] == 0.0 and sent[-1][2] == 0.0
        # until the silence is noticed the loop may still move (a trial in flight, the fit's next point);
        # from then on it holds its point (the ramp to it goes on one way only), then only ramps down
        volts = [v for (t, v, _), s in zip(sent, states, strict=True) if t > t_kill]
        later = [s for (t, _, _), s in zip(sent, states, strict=True) if t > t_kill]
        assert "ramping down" in later, later[-20:]
        held = [v for v, s in zip(volts, later, strict=True) if s == "holding"]
        steps = [b - a for a, b in itertools.pairwise(held)]
        assert all(d >= -1e-9 for d in steps) or all(d <= 1e-9 for d in steps), held
        down = volts[later.index("ramping down") :]
        assert all(b <= a + 1e-9 for a, b in itertools.pairwise(down)), down
        t_zero = next(t for t, v, _ in sent if t > t_kill and v == 0.0)
        # bounded: a move in flight at the kill reaches its point (a full ramp), 2 x timeout of silence
        # there, then a full ramp down
        assert t_zero - t_kill <= 2 * 3.0 + 2 * 800.0 / 400.0 + 1.0
        est.destroy_node()


def test_player_offers_every_topic_before_its_first_message(tmp_path: Any) -> None:
    """`ros2 topic echo` started right after the player finds every topic's type: the publishers
    exist from the start (the bag's channels), not from each topic's first message.  A relative
    path that is not in the working directory is looked up in the package's share directory."""
    import os

    sample = "bags/sample_M8528-P1.mcap"
    cwd = os.getcwd()
    os.chdir(tmp_path)  # not the clone: the path resolves to the package's copy
    try:
        with graph() as g:
            player = g.add(Player(context=g.context, parameter_overrides=params(bag=sample, rate=0.01)))
            names = dict(player.get_topic_names_and_types())
    finally:
        os.chdir(cwd)
    assert player.published == {}  # nothing played yet (rate 0.01) ...
    assert names["/fin/cmd"] == ["std_msgs/msg/Float64MultiArray"]  # ... and every topic offered,
    for topic, named in (("drive", "Drive"), ("tip_velocity", "TipVelocity"), ("estimate", "Estimate")):
        assert names[f"/fin/{topic}"] == [f"piezofin_msgs/msg/{named}"], topic  # (older blocks, named)


def test_an_older_bags_estimates_play_as_the_named_message() -> None:
    """The sample bag holds its estimates as ``Float64MultiArray`` blocks (recorded before they were
    named): the player plays each as a ``piezofin_msgs/Estimate`` with the same values, stamped at its
    window's end, and says so once; today's controller and speed loop hear them."""
    from piezofin_msgs.msg import Estimate as EstimateMsg

    from piezofin_ros.nodes._common import QOS_ESTIMATE, msg_block

    sample = "bags/sample_M8528-P1.mcap"
    recorded = [block_of(m.type_name, m.data).as_dict() for m in read_messages(sample, ["/fin/estimate"])]
    assert len(recorded) >= 3
    heard: list[Any] = []
    with graph() as g:
        listener = g.add(rclpy_node("listener", g))
        listener.create_subscription(EstimateMsg, "/fin/estimate", heard.append, QOS_ESTIMATE)
        player = g.add(
            Player(
                context=g.context,
                parameter_overrides=params(bag=sample, rate=100.0, topics=["/fin/estimate"]),
            )
        )
        g.spin_until(lambda: player.done and len(heard) >= len(recorded), 30.0, "the estimates played")
    for m, old in zip(heard, recorded, strict=True):  # the older block's fields, the rest NaN
        named = msg_block(m).as_dict()
        assert {k: named[k] for k in old} == pytest.approx(old, nan_ok=True)
        assert all(math.isnan(v) for k, v in named.items() if k not in old)
    assert [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in heard] == pytest.approx(
        [r["t_end"] for r in recorded], abs=1e-9
    )


def test_doubles_stay_doubles_and_every_parameter_says_what_it_is() -> None:
    """`-p realtime_factor:=10` and `ros2 param set ... limits.voltage_pp_max 400` (integers) keep
    the parameters doubles; the estimator's twelve window parameters each have their own description."""
    with graph() as g:
        sim = g.add(
            FinSim(context=g.context, parameter_overrides=params(realtime_factor=10, autostart=False))
        )
        sim.trigger_configure()
        assert sim.get_parameter("realtime_factor").type_ == Parameter.Type.DOUBLE
        [result] = sim.set_parameters([Parameter("limits.voltage_pp_max", value=400)])
        assert result.successful, result.reason
        assert sim.get_parameter("limits.voltage_pp_max").type_ == Parameter.Type.DOUBLE
        est = g.add(ThrustEstimator(context=g.context))
        texts = [d.description for n, d in est._descriptors.items() if n.startswith("estimator.")]
    assert len(texts) == 12 and len(set(texts)) == 12, texts


# What rosbag2_storage_mcap (Jazzy) needs of a bag: rosbag2_storage/yaml.hpp decodes these keys of
# `serialized_metadata` (version 9) with no default, and qos.cpp these of each offered profile.
ROSBAG2_V9_KEYS = {
    "version", "storage_identifier", "duration", "starting_time", "message_count",
    "topics_with_message_count", "relative_file_paths", "compression_format", "compression_mode",
    "files", "custom_data", "ros_distro",
}  # fmt: skip
QOS_KEYS = {
    "history", "depth", "reliability", "durability", "deadline", "lifespan", "liveliness",
    "liveliness_lease_duration", "avoid_ros_namespace_conventions",
}  # fmt: skip
#: rmw_qos_*_policy_from_str accepts these; "unknown" is what rosbag2 itself writes for a policy
#: DDS does not tell (a remote publisher's history and depth), and replays with its default.
QOS_WORDS = {
    "history": {"system_default", "keep_last", "keep_all", "unknown"},
    "reliability": {"system_default", "reliable", "best_effort", "best_available"},
    "durability": {"system_default", "transient_local", "volatile", "best_available"},
    "liveliness": {"system_default", "automatic", "manual_by_topic", "best_available"},
}


def check_qos(profiles: list[dict[str, Any]]) -> None:
    assert profiles, "no offered profile"
    for p in profiles:
        assert set(p) == QOS_KEYS, p
        for key, words in QOS_WORDS.items():
            assert p[key] in words, (key, p[key])
        for key in ("deadline", "lifespan", "liveliness_lease_duration"):
            assert set(p[key]) == {"sec", "nsec"} and all(isinstance(v, int) for v in p[key].values())


@ON_ITS_WORKER
def test_the_bag_is_what_rosbag2_storage_mcap_reads(live: dict[str, Any], tmp_path: Any) -> None:
    """Checked with two readers that share no code with the writer: mcap's own reader against
    rosbag2's decoding rules, and rosbags' rosbag2 implementation on a bag directory."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader as Rosbag2Reader

    with open(live["bag"], "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = [m for m in reader.iter_metadata() if m.name == "rosbag2"]
    assert summary is not None and summary.statistics is not None
    assert len(records) == 2  # one at the start (a killed writer leaves it), the complete one at close
    first = yaml.safe_load(records[0].metadata["serialized_metadata"])
    meta = yaml.safe_load(records[-1].metadata["serialized_metadata"])
    for doc in (first, meta):
        assert set(doc) == ROSBAG2_V9_KEYS and doc["version"] == 9 and doc["ros_distro"] == "jazzy"
    stats = summary.statistics
    assert meta["message_count"] == stats.message_count
    assert meta["starting_time"]["nanoseconds_since_epoch"] == stats.message_start_time
    assert meta["duration"]["nanoseconds"] == stats.message_end_time - stats.message_start_time
    by_topic = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(by_topic) == set(channels)
    for cid, c in summary.channels.items():
        qos = yaml.safe_load(c.metadata["offered_qos_profiles"] or "[]")
        assert by_topic[c.topic]["message_count"] == stats.channel_message_counts[cid]
        assert by_topic[c.topic]["topic_metadata"]["offered_qos_profiles"] == qos
        if "/estimate/" in c.topic or "/cmd/" in c.topic:
            assert qos == []  # plot fields: written to the bag, never published
        else:
            check_qos(qos)  # what the publishers offered, read from the graph
    drive = yaml.safe_load(channels["/fin/drive"].metadata["offered_qos_profiles"])
    assert [(p["reliability"], p["durability"]) for p in drive] == [("reliable", "volatile")]
    clock = yaml.safe_load(channels["/clock"].metadata["offered_qos_profiles"])
    assert [p["reliability"] for p in clock] == ["best_effort"]  # replayed as offered

    # rosbags' rosbag2 reader: a bag directory with this file and its metadata as metadata.yaml
    bagdir = tmp_path / "bagdir"
    bagdir.mkdir()
    (bagdir / live["bag"].name).symlink_to(live["bag"])
    (bagdir / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": meta}))
    with Rosbag2Reader(bagdir) as r2:
        assert r2.message_count == stats.message_count
        conns = {c.topic: c for c in r2.connections}
        assert conns["/clock"].ext.offered_qos_profiles[0].reliability.name == "BEST_EFFORT"
        assert conns["/fin/drive"].ext.offered_qos_profiles[0].reliability.name == "RELIABLE"
        assert sum(1 for _ in r2.messages()) == stats.message_count


@ON_ITS_WORKER
def test_estimates_are_plottable_field_by_field(live: dict[str, Any]) -> None:
    """Foxglove and PlotJuggler plot `/fin/estimate.thrust_n` (each field of a piezofin_msgs/Estimate by
    name, stamped in fin time) and `/fin/cmd/<field>.data` (a Float64 per command).  Read by a reader
    that knows nothing of the project (rosbags), from the schema the bag carries."""
    from piezofin_ros.estimation.estimator import Estimate

    with AnyReader([live["bag"]]) as reader:
        series: dict[str, list[float]] = {}
        stamps = []
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic.startswith("/fin/cmd/"):
                assert conn.msgtype == "std_msgs/msg/Float64"
                series.setdefault(conn.topic, []).append(msg.data)
            elif conn.topic == "/fin/estimate":
                assert conn.msgtype == "piezofin_msgs/msg/Estimate"
                for name in Estimate.field_names():
                    series.setdefault(f"/fin/estimate.{name}", []).append(getattr(msg, name))
                stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
    assert not any(t.startswith("/fin/estimate/") for t in series)  # no plot copies: it is named itself
    thrust = series["/fin/estimate.thrust_n"]
    assert thrust == pytest.approx([e.thrust_n for e in live["estimates"]], rel=1e-12)
    assert stamps == pytest.approx([e.t_end for e in live["estimates"]], abs=1e-9)  # the fin's time
    assert stamps[0] > 0 and all(b >= a for a, b in itertools.pairwise(stamps))
    assert len(series["/fin/cmd/frequency_hz"]) == live["recorded"]["/fin/cmd"]


def test_bringup_summary_before_any_trial_says_so(capsys: pytest.CaptureFixture[str]) -> None:
    """An optimise run stopped before its first trial finished (nothing fitted, nothing held): the
    summary gives the map's point as predicted and says the calibration is not fitted and that there
    is no vibrometer (a fish), never "nan"."""
    import argparse

    from piezofin_ros.control.optimise import OperatingBox, Optimiser
    from piezofin_ros.nodes.bringup import _report_fin
    from piezofin_ros.physics.amplifier import LinearAmplifier
    from piezofin_ros.physics.fin import load_fin

    fin = load_fin("M8528-P1")
    opt = Optimiser(fin, OperatingBox(), demand_n=4e-3, source="self")
    st = {"mode": "optimise", "state": "driving", "trials": 0, "self_vs_vibrometer": math.nan}
    st |= opt.status()
    _report_fin("/fin", st, fin, argparse.Namespace(), False, LinearAmplifier())
    out = capsys.readouterr().out
    assert "predicted: no trial meets the task yet" in out
    assert "not fitted yet" in out and "no vibrometer" in out and "nan" not in out


def test_the_recorder_keeps_what_waits_in_its_queue_when_it_closes(tmp_path: Any) -> None:
    """The recorder takes its topics by a poll every 10 ms; what came since its last look is taken
    when it closes (a CI run's bag once held 392 of 393 speed readings sent before the stop).  The
    recorder here never spins: every reading waits in its queue until ``close``."""
    import rclpy

    from piezofin_ros.bags import decode
    from piezofin_ros.nodes._common import TOPIC_SPEED, speed_msg

    bag = tmp_path / "queue.mcap"
    with graph() as g:
        rec = Recorder(context=g.context, namespace="q", parameter_overrides=params(path=str(bag)))
        try:
            node = g.add(rclpy.create_node("sensor", namespace="q", context=g.context))
            pub = node.create_publisher(data_type(TOPIC_SPEED), TOPIC_SPEED, QOS_DATA)
            g.spin_until(lambda: pub.get_subscription_count() >= 1, 10.0, "the recorder's subscription")
            sent = [0.01 * k for k in range(1, 8)]
            for x in sent:
                pub.publish(speed_msg(data_type(TOPIC_SPEED), x, 1.0))
            g.spin_for(0.5)  # (the middleware delivers to the recorder's queue meanwhile)
            rec.close()
        finally:
            rec.destroy_node()
    got = [
        float(decode(m.type_name, m.data).twist.linear.x) for m in read_messages(bag, ["/q/" + TOPIC_SPEED])
    ]
    assert got == sent, (got, sent)
