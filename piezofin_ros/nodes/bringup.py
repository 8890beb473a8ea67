"""``bringup``: the whole suite in one process and one executor, for one fin or several.

For each fin (namespace): ``fin_sim`` (configured and activated here), ``thrust_estimator`` and
``controller``; one ``recorder`` for all of them and ``/clock``.  Parameters come from a ROS 2
parameter file (default: the package's ``config/bringup.yaml``) and the command line.  The run
ends when every controller has finished its trials (or on Ctrl-C / SIGTERM); then the drives
ramp to zero, the bag is closed and a summary table (and with ``--plot`` a figure) is printed.

One timer on the steady clock steps every ``fin_sim`` together (:class:`Pacer`), so all fins share
one time, and only while every estimator and the recorder have taken what was published (at most
``MAX_LAG_BLOCKS`` behind): when the machine cannot keep up with the requested factor, the
simulation slows down instead of dropping samples.  The run is bounded in fin time (the plan's
length, plus a margin) and stops, saying why, if fin time stops advancing.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from ..control.report import frf_table, plot_trials, trial_table
from ..control.strategy import ControllerMode
from ..control.trials import parse_frequencies
from ..errors import ControlError, PiezofinError
from ..physics.amplifier import Amplifier
from ..physics.fin import config_dir
from ..physics.model import Model, load_model
from ._common import StartupError, StopFlag
from .controller import Controller
from .fin_sim import FinSim, Pacer
from .params import load_parameter_file, node_parameters
from .recorder import Recorder, default_bag_path
from .thrust_estimator import ThrustEstimator


def _overrides(params: dict[str, Any]) -> list[Parameter]:
    return [Parameter(name, value=value) for name, value in params.items()]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bringup", description=__doc__.splitlines()[0])
    p.add_argument("--config", help="ROS 2 parameter file (default: config/bringup.yaml of the package)")
    p.add_argument("--namespaces", nargs="+", default=["fin"], help="one namespace per fin (default: fin)")
    p.add_argument("--fins", nargs="+", help="fin preset or YAML per namespace (default: the config's fin)")
    p.add_argument(
        "--models",
        nargs="+",
        help="model preset or YAML per namespace (or one for all), simulated by fin_sim and loaded by "
        "the estimator and controller (e.g. paper-twin-M8528-P1, the paper's rig as a twin); nominal: "
        "the fin alone",
    )
    p.add_argument("--bag", help="output .mcap (default: bags/piezofin_<time>.mcap)")
    p.add_argument("--realtime-factor", type=float, default=40.0, help="simulated s per wall s (default 40)")
    p.add_argument(
        "--frequencies",
        nargs="+",
        help="trial frequencies, Hz: values and/or start:stop:step (stop included) (override the config)",
    )
    p.add_argument("--voltages", type=float, nargs="+", help="trial voltages, Vpp (override the config)")
    p.add_argument("--mode", choices=[m.value for m in ControllerMode], help="controller mode (override)")
    p.add_argument(
        "--medium",
        choices=("water", "air"),
        help="fin_sim's medium (override; air: no hydrodynamic load, for the in-air sweep of "
        "`piezofin identify`)",
    )
    p.add_argument(
        "--frequency-max",
        type=float,
        help="highest drive frequency, Hz, for the controller and fin_sim's limits (default 40; the in-air "
        "resonances of the presets are 35-46 Hz)",
    )
    p.add_argument("--demand", type=float, help="optimise: thrust demand, N")
    p.add_argument("--duration", type=float, help="optimise: simulated seconds to run")
    p.add_argument("--plot", help="write a figure of the results to this PNG")
    p.add_argument("--json", help="write the controllers' final status to this JSON file")
    p.add_argument(
        "--timeout",
        type=float,
        help="stop after this many seconds of fin time (default: what the work needs x 1.25 + 60 s: the "
        "trial plan, or optimise's --duration; optimise without --duration runs until stopped)",
    )
    args = p.parse_args(argv)
    if args.frequencies:
        try:
            args.frequencies = [float(f) for f in parse_frequencies(args.frequencies, "--frequencies")]
        except ControlError as exc:
            p.error(str(exc))
    if args.frequency_max is not None and not (
        math.isfinite(args.frequency_max) and 0 < args.frequency_max <= 1000
    ):
        p.error("--frequency-max must be within (0, 1000] Hz")
    if args.fins and len(args.fins) != len(args.namespaces):
        p.error(f"--fins gives {len(args.fins)} fins for {len(args.namespaces)} namespaces")
    if args.models and len(args.models) == 1:
        args.models = args.models * len(args.namespaces)  # one for every fin
    if args.models and len(args.models) != len(args.namespaces):
        p.error(f"--models gives {len(args.models)} models for {len(args.namespaces)} namespaces")
    if args.models and args.fins and any(m != "nominal" for m in args.models):
        p.error("--models and --fins: a model holds its fin (give one of them, or --models nominal)")
    if not (math.isfinite(args.realtime_factor) and 0.01 <= args.realtime_factor <= 1000):
        p.error("--realtime-factor must be within [0.01, 1000]")
    if args.timeout is not None and not (math.isfinite(args.timeout) and args.timeout > 0):
        p.error("--timeout must be a positive number of seconds")
    return args


#: How far (blocks) an estimator or the recorder may fall behind before the fins wait for it:
#: well inside the data topics' history of 200, so nothing is ever dropped.
MAX_LAG_BLOCKS = 20
#: Wall seconds without any fin-time progress after which the run is declared stalled.
STALL_S = 30.0


def consumer_lag(suite: Suite) -> int:
    """Blocks the slowest consumer (estimator or recorder, any fin, any topic) is behind."""
    worst = 0
    rec = suite.recorder.received
    for sim, est in zip(suite.fin_sims, suite.estimators, strict=True):
        ns = sim.get_namespace().rstrip("/")
        for topic, got in est.received.items():
            worst = max(worst, sim.blocks_published - got, sim.blocks_published - rec[f"{ns}/{topic}"])
    return worst


def _controller_options(args: argparse.Namespace) -> dict[str, Any]:
    """The controller parameters the command line sets (the file's values otherwise)."""
    out: dict[str, Any] = {}
    if args.frequencies:
        out["frequencies"] = [float(f) for f in args.frequencies]
    if args.voltages:
        out["voltages"] = [float(v) for v in args.voltages]
    if args.mode:
        out["mode"] = args.mode
    if args.frequency_max is not None:
        out["frequency_max_hz"] = float(args.frequency_max)
    if args.demand is not None:
        out["demand_n"] = float(args.demand)
    if args.duration is not None:
        out["duration_s"] = float(args.duration)
    return out


class Suite:
    """The nodes of one bring-up, built in one context (usable from tests)."""

    def __init__(self, context: rclpy.context.Context, args: argparse.Namespace) -> None:
        config = Path(args.config) if args.config else config_dir() / "bringup.yaml"
        doc = load_parameter_file(config)
        self.bag_path = Path(args.bag) if args.bag else default_bag_path()
        self.fin_sims: list[FinSim] = []
        self.estimators: list[ThrustEstimator] = []
        self.controllers: list[Controller] = []
        t0 = time.time()  # one time origin for every fin (the start of the run)
        self.fins = []
        for k, ns in enumerate(args.namespaces):

            def params(name: str, extra: dict[str, Any], ns: str = ns, k: int = k) -> list[Parameter]:
                merged = {**node_parameters(doc, name, ns), **extra}
                if args.fins:
                    merged["fin"] = args.fins[k]
                if args.models and args.models[k] != "nominal":
                    merged["model"] = args.models[k]  # (fin_sim, thrust_estimator and controller take it)
                return _overrides(merged)

            sim_extra = {"realtime_factor": args.realtime_factor, "publish_clock": k == 0, "start_time_s": t0}
            sim_extra["autostart"] = False
            # each fin its own noise: the k-th adds k to the seed it is given (two fins shared seed 0)
            sim_extra["seed"] = int(node_parameters(doc, "fin_sim", ns).get("seed", 0)) + k
            if args.medium:
                sim_extra["medium"] = args.medium
            if args.frequency_max is not None:
                sim_extra["limits.frequency_max_hz"] = float(args.frequency_max)
            sim = FinSim(context=context, namespace=ns, parameter_overrides=params("fin_sim", sim_extra))
            sim_time = {"use_sim_time": True}
            est_extra = {**sim_time, **({"medium": args.medium} if args.medium else {})}
            est = ThrustEstimator(
                context=context, namespace=ns, parameter_overrides=params("thrust_estimator", est_extra)
            )
            ctl_extra = {**sim_time, **_controller_options(args)}
            ctl = Controller(
                context=context, namespace=ns, parameter_overrides=params("controller", ctl_extra)
            )
            self.fin_sims.append(sim)
            self.estimators.append(est)
            self.controllers.append(ctl)
            self.fins.append(est.fin)
        rec_params = {
            **node_parameters(doc, "recorder", ""),
            "path": str(self.bag_path),
            "namespaces": list(args.namespaces),
            "use_sim_time": True,
        }
        self.recorder = Recorder(context=context, parameter_overrides=_overrides(rec_params))
        for sim in self.fin_sims:
            if sim.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise StartupError(f"{sim.get_fully_qualified_name()} failed to configure (see the log)")

    def activate(self, executor: Any, timeout_s: float = 5.0) -> None:
        """Activate the drives once estimator and recorder are matched (no first block lost)."""
        deadline = time.monotonic() + timeout_s
        while any(s.matched() < 2 for s in self.fin_sims) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
        for sim in self.fin_sims:
            sim.trigger_activate()

    @property
    def nodes(self) -> list[Any]:
        return [*self.fin_sims, *self.estimators, *self.controllers, self.recorder]

    @property
    def finished(self) -> bool:
        return all(c.finished for c in self.controllers)

    def fin_time_budget(self) -> float | None:
        """Fin time the work needs, with a margin (None: an optimiser with no duration runs on)."""
        needs = [c.planned_s() for c in self.controllers]
        if any(n is None for n in needs):
            return None
        return 1.25 * max(n for n in needs if n is not None) + 60.0

    def close(self) -> None:
        """Ramp the drives down, flush the estimators, close the bag (in that order)."""
        for sim in self.fin_sims:
            if sim.active:
                sim.trigger_deactivate()
        for est in self.estimators:
            est.close()
        self.recorder.close()


def _why_stop(suite: Suite, pacer: Pacer, budget: float | None) -> str | None:
    """Why the run must stop now (the recording stopped, past the fin-time budget, or fin time
    stalled), or None."""
    if suite.recorder.exit_code is not None:  # (what the run measures would be lost: stop now)
        return f"stopping: the recorder cannot write {suite.bag_path} (said above); nothing more is kept"
    fin_s = suite.fin_sims[0].rig.elapsed if suite.fin_sims[0].rig is not None else 0.0
    if budget is not None and fin_s > budget:
        late = [c.get_namespace() for c in suite.controllers if not c.finished]
        return (
            f"stopping after {fin_s:.0f} s of fin time, past the {budget:.0f} s the work "
            f"needs; not finished: {', '.join(late)}"
        )
    if pacer.stalled_s() > STALL_S:
        return (
            f"stopping: fin time has not advanced for {pacer.stalled_s():.0f} s "
            f"(a consumer is {consumer_lag(suite)} blocks behind)"
        )
    return None


def _spin(suite: Suite, executor: Any, args: argparse.Namespace, stop: StopFlag, wall0: float) -> int:
    """Run the suite until its controllers finish, a stop, or a reason to stop (exit code 1)."""
    pacer = Pacer(suite.fin_sims, ready=lambda: consumer_lag(suite) <= MAX_LAG_BLOCKS)
    suite.activate(executor)
    budget = args.timeout if args.timeout is not None else suite.fin_time_budget()
    print(f"bringup: {', '.join(args.namespaces)} -> {suite.bag_path}", file=sys.stderr, flush=True)
    last = -1.0
    while suite.recorder.context.ok() and not suite.finished and not stop:
        executor.spin_once(timeout_sec=0.1)
        why = _why_stop(suite, pacer, budget)
        if why is not None:
            print(f"bringup: {why}", file=sys.stderr)
            return 1
        elapsed = time.monotonic() - wall0
        if elapsed - last >= 5.0:
            last = elapsed
            line = ", ".join(c.strategy.progress() for c in suite.controllers)
            print(f"  {elapsed:5.1f} s: {line}", file=sys.stderr, flush=True)
    return 0


def _report_fin(
    ns: str,
    st: dict[str, Any],
    fin: Any,
    args: argparse.Namespace,
    several: bool,
    amplifier: Amplifier,
    model_name: str = "",
) -> None:
    """One fin's outcome: the optimiser's choice, or the trial table (and its plot, under the curves of
    ``model_name``, the model preset or YAML that ran; ``""``: the fin's own)."""
    if st.get("mode") == ControllerMode.OPTIMISE:
        demand = st["demand_n"]
        held = st["held"] or {  # nothing measured meets the task yet: the map's choice
            "frequency_hz": st["frequency_hz"],
            "voltage_pp": st["voltage_pp"],
            "thrust_n": st["predicted_thrust_n"],
            "power_w": st["predicted_power_w"],
        }
        print(
            f"\n{ns}: {fin.name}, optimiser {st['state']} after {st['trials']} trials, "
            f"{'converged' if st['converged'] else 'not converged'}: {held['frequency_hz']:.2f} Hz, "
            f"{held['voltage_pp']:.0f} Vpp, thrust {held['thrust_n'] * 1e3:.3f} mN, "
            f"power {held['power_w'] * 1e3:.3f} mW ({st.get('watt', 'fin')} watt)"
            + (f" (demand {demand * 1e3:.2f} mN)" if demand else "")
            + ("" if st["held"] else " (predicted: no trial meets the task yet)")
            + (
                f"; self-sensed vs vibrometer thrust {gap * 100:+.2f} %"
                if math.isfinite(gap := float(st["self_vs_vibrometer"]))
                else "; no vibrometer to compare the self-sensed thrust with"
            )
            + f"\n  {st['optimiser_mode']}: {st['optimiser_reason']}"
            + (
                f"; thrust estimate's calibration +-{bound * 100:.1f} % (2 sigma)"
                if math.isfinite(bound := float(st["self_sensing_bound"]))
                else "; thrust estimate's calibration: not fitted yet (no trial finished)"
            )
        )
        return
    print(f"\n{ns}: {fin.name}, {st['state']}" + (f" ({st['reason']})" if st["reason"] else ""))
    if st.get("mode") == "frf":  # a sweep for `piezofin identify`: the response, not thrust per watt
        print(frf_table(st["results"]))
        return
    watt = st.get("watt", "fin")
    print(trial_table(st["results"], st["chosen"], watt))
    if args.plot:
        out = Path(args.plot)
        if several:
            out = out.with_name(f"{out.stem}_{ns.strip('/').replace('/', '_')}{out.suffix}")
        lines = model_name or "the paper's model"
        title = f"{fin.name} ({ns}): trials, thrust per {watt} watt; lines: {lines}"
        model = load_model(model_name) if model_name else Model(fin)
        plot_trials(out, model, st["results"], st["chosen"], title, watt, amplifier, model_name)
        print(f"plot: {out}")


def _report(suite: Suite, statuses: dict[str, dict[str, Any]], args: argparse.Namespace, wall: float) -> int:
    """Every fin's outcome, the bag, the speed; 1 if a fin's run was aborted."""
    sim_s = max((s.rig.elapsed for s in suite.fin_sims if s.rig is not None), default=0.0)
    for k, ((ns, st), fin, est) in enumerate(
        zip(statuses.items(), suite.fins, suite.estimators, strict=True)
    ):
        model = args.models[k] if args.models and args.models[k] != "nominal" else ""
        _report_fin(ns, st, fin, args, len(statuses) > 1, est.core.amplifier, model)
    counts = suite.recorder.counts
    size_mb = suite.bag_path.stat().st_size / 1e6
    print(f"\nbag: {suite.bag_path} ({sum(counts.values())} messages, {size_mb:.1f} MB)")
    print(f"simulated {sim_s:.0f} s in {wall:.1f} s of wall time (x{sim_s / wall:.1f})")
    if args.json:
        Path(args.json).write_text(json.dumps({"bag": str(suite.bag_path), "fins": statuses}, indent=1))
    aborted = [ns for ns, st in statuses.items() if st.get("state") == "aborted"]
    if aborted:
        print(f"aborted: {', '.join(aborted)}", file=sys.stderr)
    if suite.recorder.exit_code is not None:
        print(f"bringup: {suite.bag_path} is incomplete: the recorder had to stop", file=sys.stderr)
    return 1 if aborted or suite.recorder.exit_code is not None else 0


def main(argv: list[str] | None = None) -> int:
    from rclpy.experimental import EventsExecutor

    args = parse_args(argv if argv is not None else sys.argv[1:])
    context = rclpy.Context()
    rclpy.init(args=["bringup"], context=context, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopFlag().install()
    suite = None
    executor = EventsExecutor(context=context)
    wall0 = time.monotonic()
    exit_code = 0
    statuses: dict[str, dict[str, Any]] = {}
    try:
        suite = Suite(context, args)
        for node in suite.nodes:
            executor.add_node(node)
        exit_code = _spin(suite, executor, args, stop, wall0)
    except (PiezofinError, ValueError, ParameterException) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        stop.signal = signal.SIGINT
    finally:
        if stop:
            print("bringup: interrupted, closing the bag", file=sys.stderr)
        if suite is not None:
            suite.close()
            statuses = {c.get_namespace(): c.status() for c in suite.controllers}
        wall = time.monotonic() - wall0
        executor.shutdown()
        if suite is not None:
            for n in suite.nodes:
                n.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)
        stop.restore()
    assert suite is not None
    return _report(suite, statuses, args, wall) or exit_code


if __name__ == "__main__":
    sys.exit(main())
