"""``piezofin``: the command-line front end of the physics core (no ROS needed).

    piezofin sweep --fin M8528-P1 --vpp 400 600 800 --freq 1:11:0.1 [--json] [--plot F.png]

Errors in the arguments or in a fin file end the command with a one-line message and
exit status 2, never a traceback.  Work that ran but whose result is not to be trusted (an
identification whose fit does not fit, a campaign that lost data) ends with exit status 3 and says
why.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import workers
from ..errors import PiezofinError
from ..files import save_figure
from ..physics.fin import Fin, FinConfigError, load_fin, preset_names
from ..physics.steady import SteadyState, harmonic_balance
from .args import (
    EXIT_UNTRUSTED,
    EXIT_USAGE,
    PLOT_SUFFIXES,
    UsageError,
    parse_frequencies,
    writable_folder,
    writable_path,
)

if TYPE_CHECKING:
    from ..diagnosis.paper import Twin


def _load(fin_arg: str, c_d: float | None) -> Fin:
    try:
        fin = load_fin(fin_arg)
        return fin if c_d is None else fin.replace(c_d=c_d)
    except (FinConfigError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from None


def sweep_result(fin: Fin, state: SteadyState, U: float, harmonics: int) -> dict[str, object]:
    """The ``--json`` object: the fin, every model parameter (SI, paper symbols), the points."""
    out: dict[str, object] = {"fin": fin.name}
    out.update({k: v for k, v in fin.model_parameters().items() if k != "name"})
    out["U"] = U
    out["harmonics"] = harmonics
    out["points"] = state.records()
    return out


def format_table(fin: Fin, state: SteadyState) -> str:
    head = (
        f"# {fin.name}: psi={fin.psi:.3f} c_m={fin.c_m:.3f} c_d={fin.c_d:g} mu={fin.mu:.3f} "
        f"linear underwater resonance {fin.f_water_linear:.2f} Hz\n"
        f"{'f_Hz':>7} {'Vpp':>6} {'v_tip_rms_m/s':>14} {'I_rms_mA':>9} {'P_mW':>9} "
        f"{'T_mN':>9} {'T/P_mN/W':>9}"
    )
    rows = [
        f"{r['frequency_hz']:7.2f} {r['voltage_pp']:6.0f} {r['tip_velocity_rms']:14.5f} "
        f"{1e3 * r['current_rms']:9.4f} {1e3 * r['power_w']:9.4f} {1e3 * r['thrust_n']:9.4f} "
        f"{1e3 * r['thrust_per_watt']:9.1f}"
        for r in state.records()
    ]
    return "\n".join([head, *rows])


def plot_sweep(fin: Fin, state: SteadyState, path: str) -> None:
    """Thrust, power and thrust per watt against frequency, one curve per voltage."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    panels = [
        (state.thrust_n * 1e3, "mean thrust (mN)"),
        (state.power_w * 1e3, "mean electrical power (mW)"),
        (state.thrust_per_watt * 1e3, "thrust per watt (mN/W)"),
    ]
    f = state.frequency_hz[:, 0]
    for ax, (values, label) in zip(axes, panels, strict=False):
        for j, vpp in enumerate(state.voltage_pp[0]):
            ax.plot(f, values[:, j], label=f"{vpp:g} Vpp")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[2].set_yscale("log")
    axes[0].legend()
    fig.suptitle(
        f"{fin.name}: steady state, harmonic balance (psi = {fin.psi:.2f}, c_m = {fin.c_m:.3f}, "
        f"c_d = {fin.c_d:g} assumed)"
    )
    save_figure(fig, path)


def _add_sweep_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fin", default="M8528-P1", help="preset name or path to a fin YAML (default: M8528-P1)")
    p.add_argument(
        "--vpp",
        type=float,
        nargs="+",
        default=[400.0, 600.0, 800.0],
        help="peak-to-peak voltages, V (default: 400 600 800)",
    )
    p.add_argument(
        "--freq",
        nargs="+",
        default=["1:11:0.1"],
        help="frequencies, Hz: values and/or start:stop:step (default: 1:11:0.1)",
    )
    p.add_argument("--U", type=float, default=0.0, help="swimming speed for Eq. (19), m/s (default 0)")
    p.add_argument("--c-d", type=float, default=None, help="override the fin's drag coefficient c_d")
    p.add_argument(
        "--harmonics",
        type=int,
        default=1,
        help="odd harmonics kept in the balance: 1 = the paper's single term (default)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--plot", metavar="FILE.png", help="draw thrust, power and thrust/W vs frequency")
    p.add_argument(
        "--model",
        metavar="AUGMENTED.yaml",
        help="an augmented model saved by `diagnose --report` (its fin and effects)",
    )


def _voltages(values: Sequence[float]) -> np.ndarray:
    vpp = np.asarray(values, dtype=float)
    if np.any(~np.isfinite(vpp)) or np.any(vpp < 0):
        raise UsageError("--vpp: voltages must be finite and >= 0 V")
    return vpp


def run_sweep(args: argparse.Namespace) -> int:
    if args.plot:
        writable_path("--plot", args.plot, PLOT_SUFFIXES)  # (before the work)
    if args.model:
        return _sweep_augmented(args)
    fin = _load(args.fin, args.c_d)
    freqs = parse_frequencies(args.freq)
    vpp = _voltages(args.vpp)
    if not 1 <= args.harmonics <= 10:
        raise UsageError("--harmonics: expected 1..10")
    if not np.isfinite(args.U):
        raise UsageError("--U: expected a finite speed in m/s")
    state = harmonic_balance(fin, freqs[:, None], vpp[None, :], U=args.U, harmonics=args.harmonics)
    if args.json:
        json.dump(sweep_result(fin, state, args.U, args.harmonics), sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(format_table(fin, state))
    if args.plot:
        try:
            plot_sweep(fin, state, args.plot)  # (checked before the work, at the top)
        except OSError as exc:
            raise UsageError(f"--plot {args.plot}: cannot write ({exc.strerror})") from None
        print(f"wrote {args.plot}", file=sys.stderr)
    return 0


def _sweep_augmented(args: argparse.Namespace) -> int:
    from ..physics.effects import ModelError
    from ..physics.model import load_model

    try:
        model = load_model(args.model)
    except ModelError as exc:
        raise UsageError(f"--model: {exc}") from None
    freqs = parse_frequencies(args.freq)
    vpp = _voltages(args.vpp)
    f, v = (x.ravel() for x in np.meshgrid(freqs, vpp, indexing="ij"))
    p = model.predict(f, v)
    records = [
        {
            "frequency_hz": float(f[j]),
            "voltage_pp": float(v[j]),
            "tip_velocity_rms": float(p.tip_velocity_rms[j]),
            "current_rms": float(p.current_rms[j]),
            "power_w": float(p.power_w[j]),
            "thrust_n": float(p.thrust_loadcell_n[j]),
            "thrust_per_watt": float(p.thrust_per_watt[j]),
        }
        for j in range(f.size)
    ]
    if args.json:
        json.dump(
            {"fin": model.fin.name, "effects": model.parameters(), "points": records}, sys.stdout, indent=1
        )
        sys.stdout.write("\n")
        return 0
    print(f"# {model.fin.name} with {', '.join(model.names) or 'no effect'}")
    print(f"{'f [Hz]':>7} {'Vpp':>5} {'u_rms [mm/s]':>12} {'P [mW]':>8} {'T [mN]':>8} {'T/P [mN/W]':>10}")
    for r in records:
        print(
            f"{r['frequency_hz']:7.2f} {r['voltage_pp']:5.0f} {r['tip_velocity_rms'] * 1e3:12.2f} "
            f"{r['power_w'] * 1e3:8.3f} {r['thrust_n'] * 1e3:8.3f} {r['thrust_per_watt'] * 1e3:10.1f}"
        )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="piezofin", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sweep = sub.add_parser("sweep", help="steady-state table/plot over frequency and voltage")
    _add_sweep_args(sweep)
    sweep.set_defaults(func=run_sweep)
    diag = sub.add_parser("diagnose", help="where, why and how far the model misses measured trials")
    _add_diagnose_args(diag)
    diag.set_defaults(func=run_diagnose)
    fins = sub.add_parser("fins", help="list the preset fins and their derived parameters")
    fins.set_defaults(func=run_fins)
    est = sub.add_parser("estimate", help="run the thrust estimator offline on a recorded bag")
    est.add_argument("bag", help="an .mcap file recorded by the suite (or a rig driver)")
    est.add_argument("--namespace", default="/fin", help="the fin's namespace in the bag (default /fin)")
    est.add_argument("--fin", default="M8528-P1", help="fin preset or YAML (default M8528-P1)")
    est.add_argument("--json", action="store_true", help="print the estimates as JSON")
    est.set_defaults(func=run_estimate)
    ident = sub.add_parser("identify", help="a fin's parameters from in-air and underwater stepped-sine bags")
    _add_identify_args(ident)
    ident.set_defaults(func=run_identify)
    camp = sub.add_parser("campaign", help="the paper's whole campaign through the live suite (needs ROS 2)")
    camp.add_argument("which", choices=("paper",), help="the campaign: paper (Figs. 5-11, Table 2)")
    camp.add_argument("-o", "--out", default="out/campaign", help="output directory (default out/campaign)")
    camp.add_argument(
        "--fins", nargs="+", help="the paper's fins to run (default: M8528-P1 M8514-P1 M8507-P1)"
    )
    camp.add_argument(
        "--fin-model",
        action="append",
        default=[],
        metavar="FILE",
        help="an augmented model from `piezofin diagnose --report`: the rig simulates this twin for its fin",
    )
    camp.add_argument(
        "--frequencies",
        nargs="+",
        help="protocol frequencies, Hz (default: 1-11 Hz widened to each fin's band)",
    )
    camp.add_argument(
        "--voltages", nargs="+", type=float, help="protocol voltages, Vpp (default 400 600 800)"
    )
    camp.add_argument("--sweep-points", type=int, default=21, help="points per stepped sine (default 21)")
    camp.add_argument(
        "--realtime-factor", type=float, default=200.0, help="fin s per wall s, at most (default 200)"
    )
    camp.add_argument(
        "--analyse-only",
        action="store_true",
        help="no live stage: identify and report from the bags and status files already in --out",
    )
    camp.add_argument("--force", action="store_true", help="replace a campaign already in --out")
    camp.set_defaults(func=run_campaign_cmd)

    from . import watts as _watts  # (when the parser is built: its imports are not all light)

    watts = sub.add_parser(
        "watts", help="the best thrust per watt of each fin in each watt (fin, apparent, supply), and Fig. 10"
    )
    _watts.add_arguments(watts)
    watts.set_defaults(func=_watts.run)
    from . import swim as _swim

    swim = sub.add_parser(
        "swim", help="how fast and how far on one charge: a fish's body, battery and amplifier on each fin"
    )
    _swim.add_arguments(swim)
    swim.set_defaults(func=_swim.run)
    bag = sub.add_parser("bag", help="bag tools: recover a damaged or unclosed bag")
    bag_sub = bag.add_subparsers(dest="bag_command", required=True)
    rec = bag_sub.add_parser(
        "recover", help="copy every readable message of a damaged or unclosed bag into a complete one"
    )
    rec.add_argument("bag", help="the damaged .mcap (e.g. from a recorder that was killed)")
    rec.add_argument("-o", "--output", help="the new file (default <bag>.recovered.mcap; never overwritten)")
    rec.set_defaults(func=run_bag_recover)
    return parser


def _add_identify_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--air", required=True, help="bag of the in-air stepped sine (low voltage)")
    p.add_argument("--water", help="bag of the underwater stepped sine (gives c_m and c_d)")
    p.add_argument(
        "--geometry",
        required=True,
        help="Table 1 of the fin: a preset name or a YAML file with L, L_active, b, b_active, h, m_s",
    )
    p.add_argument("--name", help="name of the identified fin (default: the geometry's)")
    p.add_argument("--namespace", default="/fin", help="the fin's namespace in the bags (default /fin)")
    p.add_argument("-o", "--output", help="write the fin YAML here (never overwritten)")
    p.add_argument("--plot", help="write Fig. 5 (measured and model velocity FRFs) to this PNG")
    p.add_argument("--json", action="store_true", help="print the identified values and the points as JSON")
    p.add_argument(
        "--accept-poor-fit",
        action="store_true",
        help="write the fin file (-o) even when the fit is not to be trusted (it is marked so inside)",
    )
    p.epilog = (
        "exit status: 0 identified; 2 bad input (one line); 3 identified, but the fit is not to be "
        "trusted (each cause said; no fin file written unless --accept-poor-fit)"
    )


def run_identify(args: argparse.Namespace) -> int:
    from ..bags import BagError
    from ..identification.frf import IdentificationError, read_sweep
    from ..identification.identify import identify, known_resonance, load_geometry
    from .plots import plot_frf

    if args.output and Path(args.output).exists():
        raise UsageError(f"{args.output} exists; choose another --output (it is never overwritten)")
    if args.plot and Path(args.plot).exists():
        raise UsageError(f"{args.plot} exists; choose another --plot (it is never overwritten)")
    for option, path, suffixes in (("--output", args.output, ()), ("--plot", args.plot, PLOT_SUFFIXES)):
        if path:
            writable_path(option, path, suffixes)  # (before the work: no fin file left without its plot)
    try:
        geometry = load_geometry(args.geometry)
        air = read_sweep(args.air, args.namespace)
        water = read_sweep(args.water, args.namespace) if args.water else None
        ident = identify(air, water, geometry, args.name, known_resonance(args.geometry))
    except (BagError, IdentificationError, FinConfigError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        out = {
            "fin": ident.fin.inputs(),
            "identified": ident.values(),
            "trusted": ident.trusted,
            "problems": ident.problems,  # why not, each with its likely cause
            "corrections": list(ident.corrections),  # reversed sensors found and turned back
            "notes": ident.warnings,  # what the data cannot identify, or identify only coarsely
            "air_points": [p.record() for p in ident.air_points],
            "water_points": [p.record() for p in ident.water_points],
        }
        print(json.dumps(out, indent=2, allow_nan=True))
    else:
        print(ident.table())
    said = sys.stderr if args.json else sys.stdout
    write_fin = args.output and (ident.trusted or args.accept_poor_fit)
    try:
        if write_fin:
            with open(args.output, "x") as fh:
                fh.write(ident.fin_yaml())
            load_fin(args.output)  # what was written loads
            print(f"fin: {args.output}{'' if ident.trusted else ' (marked NOT TRUSTED inside)'}", file=said)
        if args.plot:
            plot_frf(args.plot, ident)  # (the plot is where a misfit shows: written either way)
            print(f"plot: {args.plot}", file=said)
    except OSError as exc:
        raise UsageError(f"cannot write {exc.filename or 'the output'} ({exc.strerror or exc})") from None
    if ident.trusted:
        return 0
    print(
        f"identify: the fit is not to be trusted ({len(ident.problems)} problem(s), above); "
        + (
            f"no fin file written to {args.output} (--accept-poor-fit writes it, marked)"
            if args.output and not write_fin
            else "exit status 3"
        ),
        file=sys.stderr,
    )
    return EXIT_UNTRUSTED


def run_campaign_cmd(args: argparse.Namespace) -> int:
    from ..bags import BagError
    from ..identification.frf import IdentificationError
    from ..physics.effects import ModelError
    from ..physics.model import load_model
    from .campaign import CampaignConfig, CampaignError, run_campaign

    cfg = CampaignConfig(out=Path(args.out))
    if args.fins:
        cfg.fins = tuple(args.fins)
    unknown = [n for n in cfg.fins if n not in preset_names()]
    if unknown:
        raise UsageError(
            f"--fins: {', '.join(unknown)} not a preset ({', '.join(preset_names())}); for another fin, "
            "record its sweeps and use `piezofin identify`, or give a diagnosed model with --fin-model"
        )
    try:
        for path in args.fin_model:
            model = load_model(path)
            cfg.models[model.fin.name] = path
            if model.fin.name not in cfg.fins:
                cfg.fins = (*cfg.fins, model.fin.name)
    except (FinConfigError, ModelError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from None
    if args.frequencies:
        cfg.frequencies = tuple(float(f) for f in parse_frequencies(args.frequencies, "--frequencies"))
    if args.voltages:
        if not all(0 < v <= 800 for v in args.voltages):
            raise UsageError("--voltages: each within (0, 800] Vpp")
        cfg.voltages = tuple(args.voltages)
    if not 5 <= args.sweep_points <= 200:
        raise UsageError("--sweep-points: between 5 and 200")
    cfg.sweep_points = args.sweep_points
    if not (np.isfinite(args.realtime_factor) and 1 <= args.realtime_factor <= 1000):
        raise UsageError("--realtime-factor: within [1, 1000]")
    cfg.realtime_factor = args.realtime_factor
    if cfg.out.exists() and not cfg.out.is_dir():
        raise UsageError(f"-o {cfg.out}: a file, not a folder")
    if (
        not args.analyse_only
        and not args.force
        and (cfg.out / "bags").is_dir()
        and any((cfg.out / "bags").iterdir())
    ):
        raise UsageError(
            f"{cfg.out} holds a campaign already; give --force to replace it (or --analyse-only)"
        )
    campaign_folder = (cfg.out / "report.json").exists() or (cfg.out / "bags").is_dir()
    theirs = sorted(x.name for x in cfg.out.iterdir()) if cfg.out.is_dir() else []
    if theirs and not campaign_folder and not args.force:
        raise UsageError(
            f"-o {cfg.out}: a folder that holds other files ({', '.join(theirs[:3])}"
            f"{', ...' if len(theirs) > 3 else ''}), not a campaign's; choose an empty one (or --force)"
        )
    if not args.analyse_only:
        writable_folder("-o", cfg.out)
    try:
        report = run_campaign(cfg, say=lambda m: print(m, flush=True), analyse_only=args.analyse_only)
    except KeyboardInterrupt:
        print(f"piezofin: interrupted; what was recorded so far is in {cfg.out}", file=sys.stderr)
        return 130
    except (CampaignError, BagError, IdentificationError, FinConfigError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"-o {cfg.out}: cannot write {exc.filename or ''} ({exc.strerror or exc})") from None
    if report["problems"]:
        print(
            f"campaign: not to be trusted: {len(report['problems'])} problem(s) (above, and in the report)",
            file=sys.stderr,
        )
        return EXIT_UNTRUSTED
    return 0


def identify_main(argv: Sequence[str] | None = None) -> int:
    """``ros2 run piezofin_ros identify ...``: the ``identify`` sub-command on its own."""
    parser = argparse.ArgumentParser(prog="identify", description="a fin's parameters from stepped-sine bags")
    _add_identify_args(parser)
    parser.set_defaults(func=run_identify)
    return _run(parser, argv)


def run_bag_recover(args: argparse.Namespace) -> int:
    from ..bags import BagError, recover, resolve_bag

    try:
        report = recover(resolve_bag(args.bag), args.output)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"{args.output or args.bag}: {exc.strerror or exc}") from None
    print(report.summary())
    return 0


def run_estimate(args: argparse.Namespace) -> int:
    from ..bags import BagError, resolve_bag
    from ..estimation.offline import replay_estimates

    fin = _load(args.fin, None)
    try:
        replay = replay_estimates(resolve_bag(args.bag), fin, args.namespace)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    for line in replay.skipped_lines():
        print(f"skipped {line}", file=sys.stderr)
    if args.json:
        print(json.dumps([e.as_dict() for e in replay.replayed], indent=1))
    else:
        print(
            f"{'t_start':>12} {'final':>5} {'f [Hz]':>7} {'Vpp':>5} {'T [mN]':>8} {'T_self':>8} "
            f"{'T_cell':>8} {'P [mW]':>8} {'T/P [mN/W]':>10}"
        )
        for e in replay.replayed:
            print(
                f"{e.t_start:12.3f} {int(e.final):5d} {e.frequency_hz:7.3f} {e.voltage_pp:5.0f} "
                f"{e.thrust_n * 1e3:8.3f} {e.thrust_self_n * 1e3:8.3f} {e.thrust_loadcell_n * 1e3:8.3f} "
                f"{e.power_w * 1e3:8.3f} {e.thrust_per_watt * 1e3:10.1f}"
            )
    if replay.recorded:
        diff = replay.max_relative_difference()
        same = "reproduces" if diff <= 1e-9 else "DIFFERS FROM"
        print(
            f"{len(replay.replayed)} estimates; {same} the {len(replay.recorded)} recorded live "
            f"(largest relative difference {diff:.1e})",
            file=sys.stderr,
        )
    if not replay.replayed and replay.n_skipped:
        # (a bag whose one drive block of five held 1e300 V said "0 estimates; DIFFERS", exit 0)
        print(
            f"piezofin: error: no estimate from {args.bag}: {replay.n_skipped} message(s) of the fin could "
            "not be used (the lines above say why), and what was left makes no full window",
            file=sys.stderr,
        )
        return EXIT_UNTRUSTED
    return 0


def _add_diagnose_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "data", nargs="*", help="MCAP bags of trials (the suite's topics), or one CSV of per-trial summaries"
    )
    p.add_argument(
        "--paper", action="store_true", help="check what the paper reports for M8528-P1 (no data needed)"
    )
    p.add_argument("--fin", default="M8528-P1", help="fin preset or YAML (default M8528-P1)")
    p.add_argument("--namespace", default="/fin", help="the fin's namespace in the bags (default /fin)")
    p.add_argument(
        "--amplifier",
        default="paper-bench",
        help="the amplifier that drove the fin (preset or YAML): bags with a supply meter are checked "
        "against it (the supply stage)",
    )
    p.add_argument("--json", metavar="OUT.json", help="write the findings as JSON")
    p.add_argument(
        "--twin",
        metavar="OUT_DIR",
        help="with --paper: write the paper's rig as a twin (a model per fin, and twin.md) here",
    )
    p.add_argument(
        "--report", metavar="OUT_DIR", help="write report.md, plots, JSON and augmented_model.yaml here"
    )
    p.add_argument(
        "--relative-sigma",
        type=float,
        default=0.02,
        help="CSV without *_sigma columns: 1-sigma relative uncertainty (0.02)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument(
        "--force", action="store_true", help="replace an existing --json file or --report directory's files"
    )
    workers.add_arguments(p)  # --workers, --ray: where --paper fits its hypotheses


def _write_twin(out: Path, twin: Twin, text: str) -> None:
    """The twin's files: ``paper-twin-<fin>.yaml`` per fin (any command or node loads them by path;
    the package ships them as presets, ``model:=paper-twin-M8528-P1``) and ``twin.md``."""
    import yaml

    try:
        out.mkdir(parents=True, exist_ok=True)
        for name, model in twin.models().items():
            (out / f"paper-twin-{name}.yaml").write_text(
                "# The paper's rig as a twin (piezofin diagnose --paper --twin); its amplifier is\n"
                "# config/amplifiers/paper-bench.yaml (amplifier:=paper-bench, the nodes' default)\n"
                + yaml.safe_dump(model.to_mapping(), sort_keys=False)
            )
        (out / "twin.md").write_text(text)
    except OSError as exc:
        raise UsageError(f"--twin {out}: cannot write ({exc.strerror or exc})") from None
    print(f"wrote {out}/paper-twin-*.yaml and {out}/twin.md", file=sys.stderr)


def _refuse_existing(args: argparse.Namespace) -> None:
    """Outputs are never replaced without ``--force``, and each can be written; checked before the
    work, not after it (a file or ``/proc/x`` as ``--twin`` was refused after 292 s of it)."""
    for option in ("--json", "--twin", "--report"):
        value = getattr(args, option[2:], None)
        if not value:
            continue
        if "\0" in str(value):
            raise UsageError(f"{option} {value!r}: not a usable name (a NUL byte)")
        p = Path(value)
        if option == "--json":
            if p.exists() and not p.is_file():
                raise UsageError(f"{option} {p}: exists and is not a file")
            writable_folder(option, p.parent, f"{option} {p}: its folder")
        else:
            if p.exists() and not p.is_dir():
                raise UsageError(f"{option} {p}: exists and is not a directory")
            writable_folder(option, p)
    if args.force:
        return
    if args.json and Path(args.json).exists():
        raise UsageError(f"--json {args.json}: exists (give --force to replace it)")
    twin = getattr(args, "twin", None)
    if twin and Path(twin).is_dir():
        # what _write_twin writes: twin.md and a paper-twin-*.yaml per fin (twin.md was replaced, exit 0)
        ours = [
            p.name for p in Path(twin).iterdir() if p.name == "twin.md" or p.name.startswith("paper-twin-")
        ]
        if ours:
            raise UsageError(
                f"--twin {twin}: holds {', '.join(sorted(ours))} already (give --force to replace)"
            )
    if args.report and Path(args.report).exists():
        report = Path(args.report)
        if not report.is_dir():
            raise UsageError(f"--report {report}: exists and is not a directory")
        if any(report.iterdir()):
            raise UsageError(f"--report {report}: not empty (give --force to replace its files)")


def run_diagnose(args: argparse.Namespace) -> int:
    import time

    from ..bags import BagError
    from ..diagnosis.data import DataError, from_bags, from_csv
    from ..physics.amplifier import AmplifierError, load_amplifier

    fin = _load(args.fin, None)
    try:
        amplifier = load_amplifier(args.amplifier)
    except AmplifierError as exc:
        raise UsageError(f"--amplifier: {exc}") from None
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:5.1f} s] {msg}", file=sys.stderr, flush=True)

    if not (np.isfinite(args.relative_sigma) and 0 < args.relative_sigma < 1):
        raise UsageError("--relative-sigma: expected a number in (0, 1)")
    _refuse_existing(args)
    if args.paper:
        from ..diagnosis import paper

        if args.data:
            raise UsageError("--paper takes no data files")
    elif args.twin:
        raise UsageError("--twin goes with --paper (the paper's facts make the twin)")
    if args.paper:
        result = paper.paper_gap(progress=say, workers=args.workers, ray_address=args.ray)
        print(paper.paper_text(result))
        if args.json:
            try:
                Path(args.json).parent.mkdir(parents=True, exist_ok=True)
                with open(args.json, "w") as fh:
                    json.dump(paper.summary_json(result), fh, indent=1)
            except OSError as exc:
                raise UsageError(f"cannot write the output ({exc})") from None
        if args.twin:
            twin = paper.paper_twin(result, progress=say, workers=args.workers, ray_address=args.ray)
            twin_md = paper.twin_text(twin)
            print(twin_md)
            _write_twin(Path(args.twin), twin, twin_md)
        return 0
    if not args.data:
        raise UsageError("give one or more bags, or one CSV (or --paper)")
    csvs = [d for d in args.data if d.lower().endswith(".csv")]
    try:
        if csvs:
            if len(args.data) != 1:
                raise UsageError("give either one CSV or one or more bags, not a mix")
            say(f"reading {csvs[0]}")
            trials = from_csv(csvs[0], relative_sigma=args.relative_sigma)
        else:
            trials, skipped = from_bags(args.data, fin, args.namespace, progress=say, amplifier=amplifier)
            for line in skipped:
                print(f"skipped {line}", file=sys.stderr)
        say(f"{len(trials)} trials; checking each stage, then fitting the candidate effects")
        # (the fits' modules, scipy.stats and .optimize, a second: after the data, so that a file
        # refused is refused at once)
        from ..diagnosis.attribute import diagnose, summary_json
        from ..diagnosis.report import text, write

        d = diagnose(trials, fin, progress=say)
    except (BagError, DataError) as exc:
        raise UsageError(str(exc)) from None
    summary = summary_json(d)
    print(text(d))
    try:
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)  # as --report makes its directory
            with open(args.json, "w") as fh:
                json.dump(summary, fh, indent=1, default=float)
            say(f"wrote {args.json}")
        if args.report:
            for path in write(d, args.report, summary):
                say(f"wrote {path}")
    except OSError as exc:
        raise UsageError(f"cannot write the output ({exc})") from None
    say("done")
    return 0


def diagnose_main(argv: Sequence[str] | None = None) -> int:
    """``ros2 run piezofin_ros diagnose ...``: the ``diagnose`` sub-command on its own."""
    parser = argparse.ArgumentParser(
        prog="diagnose", description="sim-to-real gap diagnosis of measured trials"
    )
    _add_diagnose_args(parser)
    parser.set_defaults(func=run_diagnose)
    return _run(parser, argv)


def run_fins(args: argparse.Namespace) -> int:
    for name in preset_names():
        fin = load_fin(name)
        print(
            f"{name}: psi={fin.psi:.3f} c_m={fin.c_m:.3f} mu={fin.mu:.2f} gamma={fin.gamma:.4g} "
            f"m_v={fin.m_v:.4g} kg/m f_sc={fin.f_sc} Hz -> linear underwater {fin.f_water_linear:.2f} Hz"
        )
    return 0


def _run(parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> int:
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except UsageError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except workers.TaskError as exc:  # --workers 0, an unreachable Ray, a task that kills its worker
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. `piezofin sweep | head`
        return 0
    except PiezofinError as exc:  # any input the package refuses on purpose (a FIFO as a file, a NUL
        # byte in a path, a value out of range) that a command did not word itself: one line, exit 2
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE


def main(argv: Sequence[str] | None = None) -> int:
    return _run(build_parser(), argv)


def sweep_main(argv: Sequence[str] | None = None) -> int:
    """``ros2 run piezofin_ros sweep ...``: the ``sweep`` sub-command on its own."""
    parser = argparse.ArgumentParser(prog="sweep", description="steady-state sweep of a fin")
    _add_sweep_args(parser)
    parser.set_defaults(func=run_sweep)
    return _run(parser, argv)


if __name__ == "__main__":
    sys.exit(main())
