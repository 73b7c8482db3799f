"""A slow raw stream of an elastic tree: the elastic tree of :mod:`platkit.simulate.elastic_tree`
moved through held commands slowly enough to be quasi-static, recorded by the motion capture.

Each command is reached by a minimum-jerk move of every recorded joint together (``move_s``
seconds), then held (``hold_s``). The moves are slow against the tree's own dynamics, so at every
instant the tree sits in its static equilibrium ``q = q_cmd(t) - K tau(q)`` under the loads of the
whole tree (joint elasticity, link bending, payload: the truth's), at the commanded configuration
of that instant. The equilibrium is solved every ``every``-th sample and its deflection
``q - q_cmd`` interpolated between by a cubic spline in time (the deflection is smooth along a
min-jerk move and constant in a hold; the end of every hold is solved exactly). Markers sit at random places on their links, seen
through a random mocap_from_base with white noise at every sample; the folder holds session.yaml,
the nominal URDF, commands.csv (the commands as sent), markers.csv (the stream) and truth.yaml.

Without holds (:func:`simulate_elastic_motion`): a steady stream of commands (a slow multisine,
`plan --motion`'s commands.csv) that each drive follows through a first-order lag; the tree is in
its static equilibrium at the drives' positions of every sample, as between holds.

    sim = simulate_elastic_stream(nominal, truth, commands, joints, {"R1": "right_tcp", ...}, seed=3)
    write_elastic_stream(sim, nominal, "out/session")
    t, U = slow_multisine(amplitude, 60.0, 50.0, rng)
    write_elastic_stream(simulate_elastic_motion(nominal, truth, t, U, joints, links, seed=3), nominal, "out/m")
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.interpolate import CubicSpline

from platkit.errors import BadInput
from platkit.io.atomic import atomic_output_dir
from platkit.simulate.elastic_tree import ElasticTruth, equilibrium, placed_markers, true_urdf
from platkit.simulate.files import csv_text
from platkit.tree_loads import TreeLoads, payload_option
from platkit.urdf import read_urdf

__all__ = ["ElasticStream", "first_order", "simulate_elastic_motion", "simulate_elastic_stream", "slow_multisine",
           "write_elastic_stream"]

#: seconds from the start of the recording to the first command
LEAD_IN_S = 0.5


@dataclass
class ElasticStream:
    """The stream of an elastic tree: ``command_t`` (N,) s and ``commands`` (N, R) of ``joints``
    (SI) as sent; ``marker_t`` (K,) s and ``markers`` (K, M, 3) m in the mocap frame, noisy;
    ``settled`` (N, M, 3) m, every marker at the end of each hold without noise; ``rigid``
    (N, M, 3) m where the rigid true robot (no elasticity) would hold them; ``marker_names``,
    ``marker_links``, ``mocap_from_base``; ``truth``; ``seed``; ``payload``; ``noise_m``."""

    joints: list[str]
    command_t: np.ndarray
    commands: np.ndarray
    marker_t: np.ndarray
    markers: np.ndarray
    settled: np.ndarray
    rigid: np.ndarray
    marker_names: list[str]
    marker_links: list[str]
    mocap_from_base: np.ndarray
    truth: ElasticTruth
    seed: int
    noise_m: float
    payload: tuple = ()
    drive_tau_s: float | None = None  # without holds: the drives' first-order time constant
    delay_s: float | None = None  # without holds: the motion capture's clock behind the commands'


def _min_jerk(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


def commanded(command_t: np.ndarray, commands: np.ndarray, start: np.ndarray, move_s: float,
              t: np.ndarray) -> np.ndarray:
    """(K, R) the commanded joints at times t: a min-jerk move of ``move_s`` from the previous
    command (``start`` before the first) after each command time, then held."""
    i = np.searchsorted(command_t, t, side="right") - 1  # -1 before the first command
    j = np.maximum(i, 0)
    target = commands[j]
    before = np.where((i <= 0)[:, None], start[None], commands[np.maximum(i - 1, 0)])
    s = _min_jerk((t - command_t[j]) / move_s)
    u = before + s[:, None] * (target - before)
    return np.where((i < 0)[:, None], start[None], u)


def simulate_elastic_stream(nominal: Path, truth: ElasticTruth, commands: np.ndarray, joints: list[str],
                            marker_links: dict[str, str], seed: int, noise_mm: float = 0.1, hold_s: float = 2.0,
                            move_s: float = 1.5, rate_hz: float = 50.0, every: int = 5,
                            marker_spread_m: float = 0.05, workdir: Path | None = None,
                            payload=None) -> ElasticStream:
    """The stream of the elastic tree (module docstring) through ``commands`` (N, len(joints)) SI
    of the recorded ``joints`` (others at zero), from their zero. ``seed`` draws the marker places,
    the mocap transform and the noise."""
    cmd = np.atleast_2d(np.asarray(commands, float))
    if cmd.ndim != 2 or cmd.shape[1] != len(joints) or len(cmd) < 1:
        raise BadInput(f"elastic stream: commands must be (N, {len(joints)}) for the joints {joints}")
    if not (hold_s > 0 and move_s > 0 and rate_hz > 0 and every >= 1 and noise_mm >= 0):
        raise BadInput("elastic stream: hold_s, move_s and rate_hz must be positive, every at least 1, noise_mm "
                       "0 or more")
    rng = np.random.default_rng(seed)
    T, k, offset = _true_tree(nominal, truth, joints, workdir, seed, payload)
    command_t = np.round(LEAD_IN_S + np.arange(len(cmd)) * (move_s + hold_s), 6)
    end = command_t[-1] + move_s + hold_s
    t = np.round(np.arange(0.0, end, 1.0 / rate_hz), 6)
    Q_cmd = T.configuration(joints, commanded(command_t, cmd, np.zeros(len(joints)), move_s, t) - offset)
    rest = np.clip(np.searchsorted(t, command_t + move_s + hold_s, side="left") - 1, 0, len(t) - 1)
    Q_rest_cmd = T.configuration(joints, cmd - offset)
    Q_rest = equilibrium(T, Q_rest_cmd, k)
    Q = _quasi_static(T, k, Q_cmd, every, rest, Q_rest)
    return _observed(T, Q, Q_rest, Q_rest_cmd, list(joints), command_t, cmd, t, marker_links, truth, seed, noise_mm,
                     marker_spread_m, rng, rng)


def first_order(command_t: np.ndarray, commands: np.ndarray, tau_s: float, t: np.ndarray) -> np.ndarray:
    """(K, R) the joints at times t of drives that hold each command until the next (a step
    reference) and follow it through ``tau_s x' + x = r``, at rest on the first command before it:
    exact (the state at each command instant by the zero-order-hold recursion, then the free
    response to each t)."""
    p = np.empty_like(commands)
    p[0] = commands[0]
    decay = np.exp(-np.diff(command_t) / tau_s)
    for i in range(1, len(commands)):
        p[i] = commands[i - 1] + (p[i - 1] - commands[i - 1]) * decay[i - 1]
    i = np.clip(np.searchsorted(command_t, t, side="right") - 1, 0, len(commands) - 1)
    span = np.maximum(t - command_t[i], 0.0)
    return commands[i] + (p[i] - commands[i]) * np.exp(-span / tau_s)[:, None]


def slow_multisine(amplitude: np.ndarray, duration_s: float, rate_hz: float, rng: np.random.Generator,
                   band_hz: tuple[float, float] = (0.03, 0.2), components: int = 4,
                   ramp_s: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """(command_t (N,) s, commands (N, R)) streamed every 1/rate_hz s for ``duration_s``: per joint a
    sum of ``components`` sines at frequencies spread logarithmically over ``band_hz`` with random
    phases, scaled so its largest magnitude is ``amplitude`` (R,), from zero and back to zero along a
    raised-cosine ramp of ``ramp_s`` at each end."""
    amplitude = np.asarray(amplitude, float)
    if not (duration_s > 2 * ramp_s and rate_hz > 0 and components >= 1 and 0 < band_hz[0] <= band_hz[1]):
        raise BadInput(f"slow multisine: the duration must exceed two ramps ({2 * ramp_s:g} s), the rate be positive "
                       "and the band increasing")
    t = np.round(np.arange(0.0, duration_s, 1.0 / rate_hz), 6)
    f = np.geomspace(band_hz[0], band_hz[1], components)
    out = np.zeros((len(t), len(amplitude)))
    for j in range(len(amplitude)):
        ph = rng.uniform(0, 2 * np.pi, components)
        out[:, j] = np.sum(np.sqrt(f[0] / f)[None] * np.sin(2 * np.pi * f[None] * t[:, None] + ph[None]), axis=1)
    ramp = np.clip(np.minimum(t, t[-1] - t) / ramp_s, 0.0, 1.0)
    out *= (0.5 - 0.5 * np.cos(np.pi * ramp))[:, None]
    return t, out * (amplitude / np.maximum(np.abs(out).max(axis=0), 1e-12))[None]


def simulate_elastic_motion(nominal: Path, truth: ElasticTruth, command_t: np.ndarray, commands: np.ndarray,
                            joints: list[str], marker_links: dict[str, str], seed: int, noise_mm: float = 0.1,
                            tau_s: float = 0.02, delay_s: float = 0.0, rate_hz: float = 50.0, every: int = 5,
                            lead_out_s: float = 1.0, marker_spread_m: float = 0.05, workdir: Path | None = None,
                            payload=None, noise_seed: int | None = None) -> ElasticStream:
    """The elastic tree streamed without holds: ``commands`` (N, len(joints)) SI sent at
    ``command_t`` (N,) s (a steady stream, e.g. :func:`slow_multisine` or `plan --motion`'s
    commands.csv), each joint following them through a first-order drive of ``tau_s``
    (:func:`first_order`), the motion capture's clock ``delay_s`` behind. Slow motion is
    quasi-static: at every sample the tree sits in its static equilibrium at the drives' positions
    of that instant (solved every ``every``-th sample, the deflection splined between). ``settled``
    and ``rigid`` are the tree at rest at each command (elastic and rigid). ``seed`` draws the
    marker places and the mocap transform as :func:`simulate_elastic_stream` does (the same seed:
    the same markers and set-up), the noise from ``noise_seed`` when given (a held-out session of
    the same set-up with noise of its own), from ``seed`` otherwise."""
    cmd = np.atleast_2d(np.asarray(commands, float))
    command_t = np.asarray(command_t, float)
    if cmd.ndim != 2 or cmd.shape[1] != len(joints) or len(cmd) < 2 or command_t.shape != (len(cmd),):
        raise BadInput(f"elastic motion: commands must be (N >= 2, {len(joints)}) for the joints {joints}, with "
                       "one time each")
    if not (np.all(np.diff(command_t) > 0) and tau_s > 0 and delay_s >= 0 and rate_hz > 0 and every >= 1
            and noise_mm >= 0 and lead_out_s >= 0):
        raise BadInput("elastic motion: command times must increase; tau_s and rate_hz be positive, delay_s, lead_out_s "
                       "and noise_mm 0 or more, every at least 1")
    rng = np.random.default_rng(seed)
    T, k, offset = _true_tree(nominal, truth, joints, workdir, seed, payload)
    t = np.round(np.arange(0.0, command_t[-1] + lead_out_s, 1.0 / rate_hz), 6)
    Q_cmd = T.configuration(joints, first_order(command_t, cmd, tau_s, t - delay_s) - offset)
    Q_rest_cmd = T.configuration(joints, cmd - offset)
    Q_rest = equilibrium(T, Q_rest_cmd, k)
    Q = _quasi_static(T, k, Q_cmd, every)
    noise = rng if noise_seed is None else np.random.default_rng(noise_seed)
    sim = _observed(T, Q, Q_rest, Q_rest_cmd, list(joints), command_t, cmd, t, marker_links, truth, seed, noise_mm,
                    marker_spread_m, rng, noise)
    sim.drive_tau_s, sim.delay_s = float(tau_s), float(delay_s)
    return sim


def _true_tree(nominal: Path, truth: ElasticTruth, joints: list[str], workdir, seed: int, payload):
    """The true tree's loads, its compliance per tree joint (J,) and the recorded joints' zero offsets."""
    workdir = Path(workdir or nominal.parent)
    T = TreeLoads(true_urdf(nominal, truth, workdir / f"true_{seed}.urdf"), payload)
    offset = np.array([truth.offset.get(n, 0.0) for n in joints])
    k = np.zeros(len(T.joints))
    for n, c in truth.joint_compliance.items():
        k[T.index[n]] = c
    for n, (cu, cv) in truth.bending.items():
        k[T.index[f"{n}__bend_u"]], k[T.index[f"{n}__bend_v"]] = cu, cv
    return T, k, offset


def _quasi_static(T: TreeLoads, k: np.ndarray, Q_cmd: np.ndarray, every: int, exact: np.ndarray | None = None,
                  Q_exact: np.ndarray | None = None) -> np.ndarray:
    """The equilibrium at every row of Q_cmd: solved every ``every``-th row (and the last), its
    deflection splined between; the rows ``exact`` set to ``Q_exact``."""
    grid = np.unique(np.append(np.arange(0, len(Q_cmd), every), len(Q_cmd) - 1))
    deflection = equilibrium(T, Q_cmd[grid], k) - Q_cmd[grid]
    Q = Q_cmd + CubicSpline(grid, deflection, axis=0)(np.arange(len(Q_cmd)))
    if exact is not None:
        Q[exact] = Q_exact
    return Q


def _observed(T: TreeLoads, Q, Q_rest, Q_rest_cmd, joints, command_t, cmd, t, marker_links, truth, seed, noise_mm,
              marker_spread_m, rng, noise_rng) -> ElasticStream:
    """The markers (random places on their links, a random mocap transform, both from ``rng``) at
    the configurations Q with white noise (from ``noise_rng``), and at rest (Q_rest, Q_rest_cmd)."""
    names = list(marker_links)
    markers, M = placed_markers(T, marker_links, rng, marker_spread_m)
    stream = markers(Q) + noise_rng.normal(scale=noise_mm * 1e-3, size=(len(t), len(names), 3))
    return ElasticStream(joints, command_t, cmd, t, stream, markers(Q_rest), markers(Q_rest_cmd), names,
                         [marker_links[n] for n in names], M, truth, seed, noise_mm * 1e-3, T.payloads)


def write_elastic_stream(sim: ElasticStream, nominal: Path, out: str | Path) -> Path:
    """The session folder (session.yaml, the nominal URDF, commands.csv and markers.csv in mm, a
    prismatic joint's commands in mm too) and truth.yaml (SI), whole or not at all."""
    joints = read_urdf(Path(nominal)).joints
    unit = np.array([1e3 if joints[n].type == "prismatic" else 1.0 for n in sim.joints])
    with atomic_output_dir(Path(out)) as tmp:
        tmp = Path(tmp)
        (tmp / Path(nominal).name).write_bytes(Path(nominal).read_bytes())
        meta = {"platform": "urdf", "description": Path(nominal).name, "units": {"length": "mm", "time": "s"},
                "markers": sim.marker_names, "base_markers": [], "mocap_rate_hz": float(1.0 / np.median(np.diff(sim.marker_t))),
                "imu": None, "moving_link": dict(zip(sim.marker_names, sim.marker_links)),
                "notes": f"platkit.simulate.elastic_stream: a slow stream of an elastic tree (seed {sim.seed}); the "
                         "truth is in truth.yaml"}
        if sim.payload:
            meta["payload"] = payload_option(sim.payload)
        (tmp / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
        rows = [[f"{t:.6f}", *(f"{v:.10g}" for v in row * unit)] for t, row in zip(sim.command_t, sim.commands)]
        (tmp / "commands.csv").write_text(csv_text(["t", *sim.joints], rows), encoding="utf-8")
        Y = sim.markers.reshape(len(sim.marker_t), -1) * 1e3
        line = "%.6f" + ",%.4f" * Y.shape[1]
        text = "\n".join(line % tuple(r) for r in np.column_stack([sim.marker_t, Y]).tolist())
        cols = [f"{m}_{a}" for m in sim.marker_names for a in "xyz"]
        (tmp / "markers.csv").write_text(",".join(["t", *cols]) + "\n" + text + "\n", encoding="utf-8")
        tr = sim.truth
        truth = {"simulator": "elastic_stream", "seed": int(sim.seed), "units": {"length": "m", "angle": "rad"},
                 "joint_compliance": {n: float(v) for n, v in tr.joint_compliance.items()},
                 "bending": {n: [float(a), float(b)] for n, (a, b) in tr.bending.items()},
                 "offset": {n: float(v) for n, v in tr.offset.items()},
                 "origin_error": {n: {"xyz": [float(x) for x in xyz], "rpy": [float(x) for x in rpy]}
                                  for n, (xyz, rpy) in tr.origin_error.items()},
                 "mocap_from_base": [[float(x) for x in r] for r in sim.mocap_from_base],
                 "marker_links": dict(zip(sim.marker_names, sim.marker_links)), "marker_noise_m": float(sim.noise_m)}
        if sim.drive_tau_s is not None:
            truth |= {"holds": False, "drive_tau_s": sim.drive_tau_s, "delay_s": sim.delay_s}
        (tmp / "truth.yaml").write_text(yaml.safe_dump(truth, sort_keys=False), encoding="utf-8")
    return Path(out)
