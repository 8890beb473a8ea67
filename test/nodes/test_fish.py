"""A fish's stack as `ros2 run` starts it: a hidden fin, the estimator and the optimising controller,
each in its own process, only the drive's voltage and current between them and the controller."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import rclpy
import yaml
from std_msgs.msg import String

from piezofin_ros.nodes._common import QOS_COMMAND, QOS_DATA, msg_block
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.model import Model

from ..rosutil import data_type, graph, start, stop

pytestmark = [pytest.mark.ros, pytest.mark.slow]

FIN = load_fin("M8528-P1")
#: The fin in the water: dielectric loss and a coupling that grows with the field, which the
#: controller is not told (it starts from the paper's M8528-P1).
HIDDEN = Model.of(FIN, {"dielectric_loss": [0.08], "field_coupling": [0.3, 1.0]})


# exclusive: what nine trials of fin time at x10 identify depends on how fast the fits run against
# the trials, so on the machine's load (beside the parallel phase's CPU-bound tests it fitted a
# coupling of 0.14 in two of the recent full runs, and with two CPU burners failed 2 of 3; alone 2 of 2)
@pytest.mark.exclusive
def test_a_fish_meets_its_demand_in_truth_on_a_fin_it_was_not_told(tmp_path: Path) -> None:
    """fin_sim streams the hidden fin (x10); thrust_estimator (the paper's fin) and controller
    (`mode:=optimise source:=self demand_n:=...`) run as `ros2 run` starts them.  The raw self-sensed
    thrust reads the loss current as motion; the controller's fit of the drive's admittance finds
    the loss and the coupling, says its mode and its calibration bound, and the point it holds meets
    the demand on the hidden fin itself; the estimator, calibrated by the controller's fitted fin
    (``controller/model``), then self-senses the hidden fin's thrust within 10 %."""
    path = tmp_path / "hidden.yaml"
    path.write_text(yaml.safe_dump(HIDDEN.to_mapping()))
    demand = 3e-3
    ns = "/fish"
    common = ["-r", f"__ns:={ns}"]
    sim = start(
        "fin_sim", *common, "-p", f"model:={path}", "-p", "realtime_factor:=10.0", "-p", "publish_clock:=true"
    )
    est = start("thrust_estimator", *common, "-p", "use_sim_time:=true")
    ctl = start(
        "controller",
        *common,
        "-p",
        "use_sim_time:=true",
        "-p",
        "mode:=optimise",
        "-p",
        "source:=self",
        "-p",
        f"demand_n:={demand}",
    )
    statuses: list[dict] = []
    estimates: list = []
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("watcher", namespace=ns.strip("/"), context=g.context))
            node.create_subscription(
                String, "controller/status", lambda m: statuses.append(json.loads(m.data)), QOS_COMMAND
            )
            node.create_subscription(
                data_type("estimate"), "estimate", lambda m: estimates.append(msg_block(m)), QOS_DATA
            )
            g.spin_until(
                lambda: (
                    bool(statuses) and statuses[-1].get("trials", 0) >= 9 and statuses[-1]["held"] is not None
                ),
                timeout=240.0,
                what="nine optimiser trials and a held point",
            )
    finally:
        outs = stop(ctl, est, sim)
    st = statuses[-1]
    assert st["source"] == "self" and st["optimiser_mode"] in ("model", "search") and st["optimiser_reason"]
    c = st["correction"]
    assert c["loss_tan_delta"] == pytest.approx(0.08, abs=0.03), c
    assert c["coupling_k"] == pytest.approx(0.3, abs=0.1), c
    assert 0 < st["self_sensing_bound"] < 0.25  # (drive only: coupling, stiffness and c_m trade off)
    held = st["held"]
    truth = float(HIDDEN.predict(held["frequency_hz"], held["voltage_pp"]).thrust_n)
    assert truth >= demand, (truth, held, outs[0][-2000:])
    assert held["thrust_n"] == pytest.approx(truth, rel=max(st["self_sensing_bound"], 0.02) + 0.02)
    # the estimator, once the fit calibrated it: its self-sensed thrust on the hidden fin's own
    assert "self-sensed thrust calibrated by the controller's fitted fin" in outs[1], outs[1][-3000:]
    last = {n: float(estimates[-1].values[estimates[-1].names.index(n), 0]) for n in estimates[-1].names}
    hidden = float(HIDDEN.predict(last["frequency_hz"], last["voltage_pp"]).thrust_n)
    assert last["thrust_self_n"] == pytest.approx(hidden, rel=0.1), (last, hidden)
