"""A physical simulator of URDF trees that bend under their own weight: settled poses of a robot
with elastic joints and elastic links, the loads from every branch, the equilibrium solved.

The true robot is the nominal URDF with, drawn from the seed:

- geometric nuisances: every moving joint's origin moved (``origin_mm`` RMS per axis) and turned
  (``origin_mrad``), every recorded joint's zero offset (``offset_mrad``);
- joint elasticity: joint j's link side sits at ``q_cmd - k_j tau_j(q)`` (k_j >= 0 rad/(N m),
  tau_j the gravity torque it holds);
- link bending: at joint j two virtual revolute joints about the axes across its axis (the frame
  of :func:`platkit_effects`-independent :func:`across` below), turned by ``-k_b M`` under the
  moment's components along them (the lumped model of a link that bends);
- a payload at a link.

The equilibrium ``q = q_cmd - K tau(q)`` over every real and virtual joint of the whole tree is
solved by fixed-point iteration (each step the loads of the deflected tree, pinocchio's rnea
through platkit.tree_loads) to 1e-12 rad. Markers sit at random places on their links, seen
through a random mocap_from_base with white noise; a session folder holds session.yaml, the
nominal URDF, poses.csv (settled, mm) and truth.yaml.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from platkit.errors import BadInput, NoConvergence
from platkit.geometry import matrix_from_rpy
from platkit.io.atomic import atomic_output_dir
from platkit.simulate.stand import random_mocap_from_base
from platkit.tree_loads import Payload, TreeLoads, payload_option
from platkit.urdf import read_urdf, urdf_rpy

#: largest fixed-point iterations of the equilibrium
MAX_ITERATIONS = 200


def across(axis: np.ndarray) -> np.ndarray:
    """(2, 3) two unit vectors across ``axis`` (the same rule as the link_bending effect's)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(a, e)
    u /= np.linalg.norm(u)
    return np.array([u, np.cross(a, u)])


@dataclass
class ElasticTruth:
    """The true robot: joint compliances (name -> rad/(N m)), bending compliances (name ->
    (k_u, k_v)), origin errors (name -> (xyz m, rpy rad)), zero offsets (name -> rad)."""

    joint_compliance: dict[str, float] = field(default_factory=dict)
    bending: dict[str, tuple[float, float]] = field(default_factory=dict)
    origin_error: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    offset: dict[str, float] = field(default_factory=dict)


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in v)


def true_urdf(nominal: Path, truth: ElasticTruth, out: Path) -> Path:
    """The nominal URDF with the truth's origin errors and a virtual bending pair before every bent
    joint (massless links ``<joint>__bu``, ``<joint>__bv``; joints ``<joint>__bend_u``, ``_v``)."""
    tree = ET.parse(nominal)
    robot = tree.getroot()
    for j in list(robot.findall("joint")):
        name = j.get("name")
        origin = j.find("origin")
        if origin is None:
            origin = ET.SubElement(j, "origin")
        xyz = np.array([float(x) for x in (origin.get("xyz") or "0 0 0").split()])
        rpy = np.array([float(x) for x in (origin.get("rpy") or "0 0 0").split()])
        if name in truth.origin_error:
            dx, dr = truth.origin_error[name]
            R = matrix_from_rpy(*rpy) @ matrix_from_rpy(*dr)
            xyz = xyz + matrix_from_rpy(*rpy) @ dx
            rpy = urdf_rpy(R)
        origin.set("xyz", _fmt(xyz))
        origin.set("rpy", _fmt(rpy))
        if name in truth.bending:
            axis_el = j.find("axis")
            axis = np.array([float(x) for x in (axis_el.get("xyz") if axis_el is not None else "1 0 0").split()])
            u, v = across(axis)
            parent = j.find("parent").get("link")
            for tag, vec, child in (("u", u, f"{name}__bu"), ("v", v, f"{name}__bv")):
                ET.SubElement(robot, "link", name=child)
                vj = ET.SubElement(robot, "joint", name=f"{name}__bend_{tag}", type="revolute")
                ET.SubElement(vj, "parent", link=parent)
                ET.SubElement(vj, "child", link=child)
                if tag == "u":
                    ET.SubElement(vj, "origin", xyz=_fmt(xyz), rpy=_fmt(rpy))
                else:
                    ET.SubElement(vj, "origin", xyz="0 0 0", rpy="0 0 0")
                ET.SubElement(vj, "axis", xyz=_fmt(vec))
                ET.SubElement(vj, "limit", lower="-1", upper="1", effort="1", velocity="1")
                parent = child
            j.find("parent").set("link", parent)
            origin.set("xyz", "0 0 0")
            origin.set("rpy", "0 0 0")
    tree.write(out)
    return out


def equilibrium(T: TreeLoads, Q_cmd: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N, J) the configuration where every joint sits at ``Q_cmd - k tau(Q)`` (k (J,) rad/(N m),
    zero for rigid joints), by fixed-point iteration to 1e-12 rad."""
    Q = np.array(Q_cmd, float)
    for _ in range(MAX_ITERATIONS):
        new = Q_cmd - k[None] * T.loads(Q).torque
        step = np.max(np.abs(new - Q))
        Q = new
        if step < 1e-12:
            return Q
    raise NoConvergence("the elastic tree's equilibrium", MAX_ITERATIONS, float(step),
                        "the compliances are too large for the loads")


@dataclass
class ElasticSession:
    """Settled poses of the elastic tree: ``commands`` (N, R) of ``joints`` (rad; m for a prismatic
    joint); ``markers`` (N, M, 3) m in the mocap frame, noisy; ``exact`` the same without noise;
    ``marker_names``, ``marker_links``; ``rigid`` (N, M, 3) m where the rigid true robot (no
    elasticity) would put them; ``payload`` what the robot carried."""

    joints: list[str]
    commands: np.ndarray
    markers: np.ndarray
    exact: np.ndarray
    rigid: np.ndarray
    marker_names: list[str]
    marker_links: list[str]
    mocap_from_base: np.ndarray
    payload: tuple[Payload, ...] = ()


def placed_markers(T: TreeLoads, marker_links: dict[str, str], rng: np.random.Generator, spread_m: float):
    """The markers ``marker_links`` (name -> link) at random places within ``spread_m`` of their
    link's origin and a random mocap transform M (4x4), drawn from ``rng`` in that order: (markers,
    M), markers(Q) (N, M, 3) m in the mocap frame at the configurations Q (N, T.nq)."""
    names = list(marker_links)
    places = rng.uniform(-spread_m, spread_m, size=(len(names), 3))
    M = random_mocap_from_base(rng, 2.0)

    def markers(Qs: np.ndarray) -> np.ndarray:
        out = np.zeros((len(Qs), len(names), 3))
        for m, n in enumerate(names):
            o, R = T.link_placements(Qs, marker_links[n])
            out[:, m] = o + np.einsum("nab,b->na", R, places[m])
        return out @ M[:3, :3].T + M[:3, 3]

    return markers, M


def simulate_elastic_tree(nominal: Path, truth: ElasticTruth, commands: np.ndarray, joints: list[str],
                          marker_links: dict[str, str], seed: int, noise_mm: float = 0.1,
                          marker_spread_m: float = 0.05, workdir: Path | None = None,
                          payload=None) -> ElasticSession:
    """Settled poses at ``commands`` (N, len(joints)) rad of the recorded ``joints`` (others at
    zero): markers ``marker_links`` (name -> link) at random places within ``marker_spread_m`` of
    their link's origin. ``seed`` draws the marker places, the mocap transform and the noise."""
    rng = np.random.default_rng(seed)
    workdir = Path(workdir or nominal.parent)
    true_path = true_urdf(nominal, truth, workdir / f"true_{seed}.urdf")
    T = TreeLoads(true_path, payload)
    cmd = np.atleast_2d(np.asarray(commands, float)).copy()
    for i, n in enumerate(joints):
        cmd[:, i] -= truth.offset.get(n, 0.0)
    Q_cmd = T.configuration(joints, cmd)
    k = np.zeros(len(T.joints))
    for n, c in truth.joint_compliance.items():
        k[T.index[n]] = c
    for n, (cu, cv) in truth.bending.items():
        k[T.index[f"{n}__bend_u"]], k[T.index[f"{n}__bend_v"]] = cu, cv
    Q = equilibrium(T, Q_cmd, k)
    names = list(marker_links)
    markers, M = placed_markers(T, marker_links, rng, marker_spread_m)
    exact, rigid = markers(Q), markers(Q_cmd)
    noisy = exact + rng.normal(scale=noise_mm * 1e-3, size=exact.shape)
    return ElasticSession(list(joints), np.asarray(commands, float), noisy, exact, rigid, names,
                          [marker_links[n] for n in names], M, T.payloads)


def write_elastic_session(sim: ElasticSession, nominal: Path, out: Path, moving_link: str | dict,
                          rows: np.ndarray | None = None) -> Path:
    """A session folder (poses.csv in mm, the nominal URDF beside it) of the rows ``rows`` (default
    all): the session's length unit is every length's, a prismatic joint's command too (mm); the
    payload the robot carried, if any, in session.yaml."""
    rows = np.arange(len(sim.commands)) if rows is None else np.asarray(rows)
    joints = read_urdf(Path(nominal)).joints
    unit = np.array([1e3 if joints[n].type == "prismatic" else 1.0 for n in sim.joints])
    if not len(rows):
        raise BadInput("elastic tree: no rows to write")
    with atomic_output_dir(out) as tmp:
        tmp = Path(tmp)
        (tmp / nominal.name).write_bytes(Path(nominal).read_bytes())
        meta = {"platform": "urdf", "description": nominal.name, "units": {"length": "mm", "time": "s"},
                "markers": sim.marker_names, "mocap_rate_hz": 100, "moving_link": moving_link,
                "notes": "platkit.simulate.elastic_tree: settled poses of an elastic tree"}
        if sim.payload:
            meta["payload"] = payload_option(sim.payload)
        (tmp / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
        head = ["t", *sim.joints] + [f"{n}_{a}" for n in sim.marker_names for a in "xyz"]
        lines = [",".join(head)]
        for r, k in enumerate(rows):
            vals = [f"{float(r):.1f}", *(f"{v:.10g}" for v in sim.commands[k] * unit),
                    *(f"{1e3 * v:.6f}" for v in sim.markers[k].ravel())]
            lines.append(",".join(vals))
        (tmp / "poses.csv").write_text("\n".join(lines) + "\n")
    return out
