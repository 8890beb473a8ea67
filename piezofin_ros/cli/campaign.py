"""``piezofin campaign paper``: the paper's whole campaign through the live suite, in one command.

For each fin (default: the three of Table 1), through ``bringup`` (``fin_sim``, ``thrust_estimator``,
``controller`` and ``recorder``: the live suite with the simulated rig; one process per fin and
stage, the fins in parallel, each process in its own ROS domain since each has its own ``/clock``):

1. an in-air stepped sine (``fin_sim`` ``medium:=air``, ``controller`` ``mode:=frf``) and
2. an underwater one, then the identification of each fin from its two bags (-> Table 2, ``c_m``,
   ``c_d``, Fig. 5);
3. the thrust protocol (10 s off, 10 s on, 10 s off) at 1-11 Hz, widened to the fin's band (up to
   1.25 times its underwater resonance), and 400/600/800 Vpp, with the estimator and controller
   using the *identified* fin, plus 5.5 Hz for M8528-P1 (-> Figs. 6-11);
4. the report: every number the paper publishes beside the suite's (:data:`PAPER`), the figures,
   the bags and the identified fin files.

The rig simulates the preset (the truth); with ``--fin-model FILE`` (an augmented model from
``piezofin diagnose --report``) it simulates that twin instead for the fin it describes: under water
the model, in air its bare fin (the library's effects are the fin in water and its drive).

The analysis (:func:`analyse`) needs no ROS: it reads the bags and the controllers' status files, so
a campaign recorded elsewhere (a real rig, same topics) can be analysed too.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..bags.reader import Damage
from ..errors import CliError
from ..identification.frf import read_sweep
from ..identification.identify import Identification, identify
from ..physics.fin import FinConfigError, config_dir, load_fin, read_yaml_file
from .campaign_plan import CampaignConfig, filename, namespace
from .campaign_report import analyse


class CampaignError(CliError):
    """A stage of the campaign failed (its log says why)."""


def sweep_frequencies(f0: float, n: int, low: float, high: float) -> list[float]:
    """``n`` points from ``low f0`` to ``high f0``, denser near ``f0`` (the resonance)."""
    u = np.linspace(-1.0, 1.0, n)
    span = np.where(u < 0, 1.0 - low, high - 1.0)
    return sorted(
        {round(float(f0 * (1.0 + s * np.sign(x) * abs(x) ** 1.6)), 3) for x, s in zip(u, span, strict=True)}
    )


def _base_config() -> dict[str, Any]:
    path = config_dir() / "bringup.yaml"
    doc = read_yaml_file(path)
    if not isinstance(doc, dict) or "/**/thrust_estimator" not in doc:
        raise CampaignError(f"{path}: not the package's bring-up parameter file")
    return doc


def _stage_config(cfg: CampaignConfig, stage: str, fin_files: dict[str, str]) -> dict[str, Any]:
    """The ROS 2 parameter file of one stage: the package's bring-up file plus one section per fin."""
    doc = _base_config()
    doc["/**/thrust_estimator"]["ros__parameters"]["estimator"]["window_s"] = (
        2.0 if stage != "protocol" else 5.0
    )
    for name in cfg.fins:
        ns = namespace(name)
        truth = cfg.truth(name)
        sim: dict[str, Any] = {"fin": name}
        if name in cfg.models:
            if stage == "air":
                sim["fin"] = fin_files[f"{name}:truth"]
            else:
                sim["model"] = str(Path(cfg.models[name]).resolve())
        ctl: dict[str, Any] = {"fin": fin_files.get(name, name)}
        if stage in ("air", "water"):
            # in air around f_sc (0.7-1.3 x) at air_vpp; under water around the linear resonance
            # (0.45-1.6 x: the drag widens it) at water_vpp, which settles more slowly
            f0, low, high, vpp, timeout = (
                (truth.f_sc, 0.7, 1.3, cfg.air_vpp, 30.0)
                if stage == "air"
                else (truth.f_water_linear, 0.45, 1.6, cfg.water_vpp, 60.0)
            )
            ctl.update(
                mode="frf",
                voltages=[vpp],
                settle_timeout_s=timeout,
                frequencies=sweep_frequencies(f0, cfg.sweep_points, low, high),
            )
        else:
            freqs = cfg.protocol_frequencies(name)
            ctl.update(mode="protocol", frequencies=freqs, voltages=list(cfg.voltages), after="stop")
        doc[f"/{ns}/fin_sim"] = {"ros__parameters": sim}
        doc[f"/{ns}/thrust_estimator"] = {"ros__parameters": {"fin": fin_files.get(name, name)}}
        doc[f"/{ns}/controller"] = {"ros__parameters": ctl}
    return doc


#: Where the stage's ROS domains come from: ``first-last`` (inclusive); 1-100 unless set.
DOMAINS_VARIABLE = "PIEZOFIN_ROS_DOMAINS"


def _domains(n: int) -> list[int]:
    """``n`` ROS domain ids for the stage's processes, none the caller's own: each process has its
    own ``/clock``, which must not reach the others.  They are drawn from ``$PIEZOFIN_ROS_DOMAINS``
    (``first-last``), so that a machine running other ROS work can keep them apart from it."""
    own = os.environ.get("ROS_DOMAIN_ID", "0")
    text = os.environ.get(DOMAINS_VARIABLE, "1-100")
    try:
        first, last = (int(x) for x in text.split("-"))
    except ValueError:
        raise CampaignError(f"{DOMAINS_VARIABLE}={text!r}: expected first-last, such as 1-100") from None
    if not 0 <= first <= last <= 232:
        raise CampaignError(f"{DOMAINS_VARIABLE}={text!r}: ROS domain ids lie within 0-232")
    free = [d for d in range(first, last + 1) if str(d) != own]
    if len(free) < n:
        raise CampaignError(
            f"{DOMAINS_VARIABLE}={text!r} holds {len(free)} domain(s) besides ROS_DOMAIN_ID, "
            f"the stage needs {n}"
        )
    rng = np.random.default_rng()
    return [int(d) for d in rng.choice(free, size=n, replace=False)]


def run_bringups(jobs: dict[str, list[str]], logs: dict[str, Path], say: Callable[[str], None]) -> None:
    """``bringup`` once per fin, all at once, each in its own process and ROS domain; their progress
    lines go to ``say`` (prefixed with the fin) and everything they print to their ``logs``.
    Raises :class:`CampaignError` naming the log of any that fails."""
    procs: dict[str, subprocess.Popen[str]] = {}
    handles = {}
    threads = []
    lock = threading.Lock()
    for (name, args), domain in zip(jobs.items(), _domains(len(jobs)), strict=True):
        # the ROS wheels' bootstrapper re-executes a child python with its library path unless told it
        # has done so: an inherited flag from a parent that imported rclpy would skip that
        env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
        env["ROS_DOMAIN_ID"] = str(domain)
        env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # a simulation needs no network
        handles[name] = fh = open(logs[name], "w")  # noqa: SIM115 (closed below)
        procs[name] = proc = subprocess.Popen(
            [sys.executable, "-m", "piezofin_ros.nodes.bringup", *args],
            stdin=subprocess.DEVNULL,
            stdout=fh,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )

        def pump(name: str = name, proc: subprocess.Popen[str] = proc, fh: Any = fh) -> None:
            assert proc.stderr is not None
            for line in proc.stderr:
                with lock:
                    fh.write(line)
                    if line.startswith("  ") and " s: " in line:
                        say(f"   {name}: {line.strip()}")
                    elif line.startswith(("error", "bringup: stopping")) or "[ERROR]" in line:
                        say(f"   {name}: {line.rstrip()}")

        threads.append(threading.Thread(target=pump, daemon=True))
        threads[-1].start()
    failed = []
    try:
        for name, proc in procs.items():
            if proc.wait() != 0:
                failed.append(name)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.terminate()
                proc.wait()
        for t in threads:
            t.join(timeout=5)
        for fh in handles.values():
            fh.close()
    if failed:
        raise CampaignError("bringup failed for " + ", ".join(f"{n} (see {logs[n]})" for n in failed))


def run_stage(
    cfg: CampaignConfig, stage: str, fin_files: dict[str, str], say: Callable[[str], None]
) -> dict[str, Path]:
    """One stage of the live suite, one ``bringup`` per fin in parallel; returns each fin's status JSON."""
    out = cfg.out
    params = out / "logs" / f"{stage}.params.yaml"
    params.write_text(yaml.safe_dump(_stage_config(cfg, stage, fin_files), sort_keys=False))
    jobs, logs, statuses = {}, {}, {}
    for name in cfg.fins:
        bag = out / "bags" / f"{stage}_{filename(name)}.mcap"
        if bag.exists():
            bag.unlink()  # a campaign's own output directory: the previous run's bag is replaced
        statuses[name] = out / "logs" / f"{stage}_{filename(name)}.status.json"
        logs[name] = out / "logs" / f"{stage}_{filename(name)}.log"
        jobs[name] = [
            "--config",
            str(params),
            "--namespaces",
            namespace(name),
            "--bag",
            str(bag),
            "--realtime-factor",
            f"{cfg.realtime_factor:g}",
            "--json",
            str(statuses[name]),
            "--frequency-max",
            "100",
        ] + (["--medium", "air"] if stage == "air" else [])
    run_bringups(jobs, logs, say)
    return statuses


def planned(cfg: CampaignConfig, stage: str, name: str) -> int:
    """The points (``air``, ``water``) or trials (``protocol``) a stage planned for a fin: from the
    parameter file it ran with (``logs/<stage>.params.yaml``: a campaign analysed again keeps its own
    plan), else from ``cfg``."""
    try:
        doc = read_yaml_file(cfg.out / "logs" / f"{stage}.params.yaml")
        ctl = doc[f"/{namespace(name)}/controller"]["ros__parameters"]
        return len(ctl["frequencies"]) * len(ctl["voltages"])
    except (OSError, KeyError, TypeError, FinConfigError):
        if stage == "protocol":
            return len(cfg.protocol_frequencies(name)) * len(cfg.voltages)
        return cfg.sweep_points


def identify_all(
    cfg: CampaignConfig, fin_files: dict[str, str], say: Callable[[str], None]
) -> tuple[dict[str, Identification], list[str]]:
    """Each fin from its two sweep bags in ``cfg.out/bags``; writes ``fins/<fin>.yaml`` and notes its
    path.  Returns the identifications and what makes any of them untrustworthy: a damaged bag, a
    sweep with fewer points than planned (data lost), a fit that does not fit."""
    idents: dict[str, Identification] = {}
    problems: list[str] = []
    bags = cfg.out / "bags"
    for name in cfg.fins:
        ns = namespace(name)
        sweeps = {}
        for stage in ("air", "water"):
            bag = bags / f"{stage}_{filename(name)}.mcap"
            damages: list[Damage] = []
            sweeps[stage] = read_sweep(bag, ns, on_damage=damages.append)
            problems += [f"{name}: {d}" for d in damages]
            if len(sweeps[stage]) < (plan := planned(cfg, stage, name)):
                problems.append(
                    f"{name}: {bag.name} gives {len(sweeps[stage])} of the {plan} points "
                    "planned: data lost (a cut bag, steps that did not settle)"
                )
        ident = identify(
            sweeps["air"],
            sweeps["water"],
            load_fin(name) if name not in cfg.models else cfg.truth(name),
            name,
        )
        problems += [f"{name}: {p}" for p in ident.problems]
        path = cfg.out / "fins" / f"{filename(name)}.yaml"
        path.write_text(ident.fin_yaml())
        fin_files[name] = str(path.resolve())
        idents[name] = ident
        say(
            f"   {name}: f_sc {ident.fin.f_sc:.2f} Hz, zeta {ident.fin.zeta * 100:.2f} %, "
            f"theta {ident.fin.theta * 1e3:.2f}e-3, C_eq {ident.fin.C_eq * 1e9:.2f} nF, "
            f"c_m {ident.fin.c_m:.3f}, c_d {ident.fin.c_d:.2f}"
            + ("" if ident.trusted else " (NOT TRUSTED: see the report)")
        )
    return idents, problems


def _statuses(cfg: CampaignConfig) -> dict[str, dict[str, Any]]:
    out = {}
    for name in cfg.fins:
        path = cfg.out / "logs" / f"protocol_{filename(name)}.status.json"
        try:
            out[name] = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise CampaignError(f"{path}: cannot read the protocol's status ({exc})") from None
    return out


def run_campaign(
    cfg: CampaignConfig, say: Callable[[str], None] = print, analyse_only: bool = False
) -> dict[str, Any]:
    """The whole campaign (module docstring); returns the report's numbers (also in ``report.json``).

    ``analyse_only``: no live stage; identify and report from the bags and status files already in
    ``cfg.out`` (a campaign recorded before, or on a real rig with the same topics and file names).
    """
    t0 = time.monotonic()
    for sub in ("bags", "fins", "logs"):
        (cfg.out / sub).mkdir(parents=True, exist_ok=True)
    fin_files: dict[str, str] = {}
    for name in cfg.models:  # the twin's bare fin, for the in-air sweep
        path = cfg.out / "fins" / f"{filename(name)}.truth.yaml"
        path.write_text(yaml.safe_dump(cfg.truth(name).inputs(), sort_keys=False))
        fin_files[f"{name}:truth"] = fin_files[name] = str(path.resolve())  # until it is identified
    n = len(cfg.fins)
    if not analyse_only:
        say(f"[1/4] in-air stepped sines, {n} fin(s) x {cfg.sweep_points} points at {cfg.air_vpp:g} Vpp")
        run_stage(cfg, "air", fin_files, say)
        say(
            f"[2/4] underwater stepped sines, {n} fin(s) x {cfg.sweep_points} points at "
            f"{cfg.water_vpp:g} Vpp ({time.monotonic() - t0:.0f} s)"
        )
        run_stage(cfg, "water", fin_files, say)
    say(f"[3/4] identification of {n} fin(s) ({time.monotonic() - t0:.0f} s)")
    idents, problems = identify_all(cfg, fin_files, say)
    if not analyse_only:
        trials = "/".join(str(len(cfg.protocol_frequencies(nm)) * len(cfg.voltages)) for nm in cfg.fins)
        say(f"[4/4] thrust protocol, {trials} trials of 30 s ({time.monotonic() - t0:.0f} s)")
        run_stage(cfg, "protocol", fin_files, say)
    statuses = _statuses(cfg)
    for name in cfg.fins:
        plan = planned(cfg, "protocol", name)
        done = len(statuses[name]["fins"][f"/{namespace(name)}"]["results"])
        if done < plan:
            problems.append(f"{name}: the thrust protocol gives {done} of the {plan} trials planned")
    report = analyse(cfg, idents, statuses, problems)
    report["wall_s"] = time.monotonic() - t0
    (cfg.out / "report.json").write_text(json.dumps(report, indent=1, default=float))  # with the time
    if problems:
        say(
            f"done in {report['wall_s']:.0f} s, NOT TO BE TRUSTED ({len(problems)} problem(s), listed at the "
            f"top of {cfg.out / 'report.md'}):"
        )
        for p in problems:
            say(f"   {p}")
    else:
        say(f"done in {report['wall_s']:.0f} s: {cfg.out / 'report.md'}")
    return report
