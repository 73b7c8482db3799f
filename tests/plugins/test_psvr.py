"""The psvr stand: the paper's equations, the neutral pose, round trips, the branch, bad descriptions."""
import json
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import platkit_psvr
from platkit import get_platform
from platkit.errors import BadDescription, OutOfWorkspace, WrongBranch
from platkit.geometry import matrix_from_quat
from platkit.kinematics import PlatformModel

R_ROD = np.sqrt(0.060**2 + 0.450**2)


@pytest.fixture(scope="module")
def spec():
    return get_platform("psvr")


@pytest.fixture(scope="module")
def model(spec):
    return PlatformModel(spec)


def crank_state(spec, u, p):
    """(a, D, E, t) as numpy arrays (columns per motor) at controls u and pose p, nominal td."""
    u_s, td_s, q_s, X_s = ca.SX.sym("u", 3), ca.SX.sym("td", 26), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
    out = platkit_psvr.crank_geometry(u_s, td_s, q_s, X_s, spec.extras["crank_planes"].T)
    f = ca.Function("state", [u_s, td_s, q_s, X_s], list(out))
    q, X = spec.pose(p)
    return [np.asarray(v) for v in f(u, spec.nominal_td(), q, X)]


def test_td_is_the_papers_26_numbers_in_order(spec):
    names = spec.parameter_names
    assert len(names) == 26
    assert names[:6] == ["k_A", "k_B", "k_C", "u0_A", "u0_B", "u0_C"]
    assert names[6:9] == ["V_A_x", "V_A_y", "V_A_z"] and names[15:18] == ["S_A_x", "S_A_y", "S_A_z"]
    assert names[24:] == ["R_rod", "r_crank"]
    td = spec.nominal_td()
    assert td[24] == pytest.approx(R_ROD, abs=1e-9) and td[25] == pytest.approx(0.120)
    # SI inside: the description's millimetres are metres here
    assert td[6:9] == pytest.approx([0.440, 0.0, 0.150])
    assert spec.control_names == ["A", "B", "C"] and {c.unit for c in spec.controls} == {"count"}
    assert spec.coordinate_names == ["alpha", "beta", "h"]


def test_neutral_pose_cranks_horizontal_at_2047_2_counts(spec, model):
    u0 = spec.neutral_u()
    assert u0 == pytest.approx(1000 + (np.pi / 2) / 0.0015, abs=1e-3)  # 2047.1976 counts
    assert np.round(u0, 1).tolist() == [2047.2] * 3
    a, D, E, t = crank_state(spec, u0, spec.neutral_p())
    assert np.asarray(a).ravel() == pytest.approx([np.pi / 2] * 3, abs=1e-7)
    # crank tips at radius 0.44 + 0.12 and the pivots' height; rods 60 mm in, 450 mm up
    assert np.hypot(D[0], D[1]) == pytest.approx([0.560] * 3, abs=1e-7)
    assert D[2] == pytest.approx([0.150] * 3, abs=1e-7)
    assert (E - D)[2] == pytest.approx([0.450] * 3, abs=1e-7)
    fk = model.forward(u0)
    assert fk.p == pytest.approx([0.0, 0.0, 0.600], abs=1e-9)
    assert fk.q == pytest.approx([1, 0, 0, 0], abs=1e-9) and fk.X == pytest.approx([0, 0, 0.6], abs=1e-9)
    assert fk.on_branch and fk.iterations <= 3


def test_platform_joints_follow_the_papers_eq_2(spec):
    """E = C + Rx(alpha) Ry(beta) S, written out as in the paper."""
    rng = np.random.default_rng(1)
    S = spec.extras["platform_joints_m"]
    for alpha, beta, h in rng.uniform([-0.4, -0.4, 0.4], [0.4, 0.4, 0.8], (5, 3)):
        _, _, E, _ = crank_state(spec, spec.neutral_u(), [alpha, beta, h])
        ca_, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
        Sx, Sy, Sz = S.T
        E_paper = np.array([
            cb * Sx + sb * Sz,
            sa * sb * Sx + ca_ * Sy - sa * cb * Sz,
            h - ca_ * sb * Sx + sa * Sy + ca_ * cb * Sz,
        ])
        assert E == pytest.approx(E_paper, abs=1e-12)


def test_crank_tip_is_the_papers_eq_1_for_a_motor_at_180_degrees():
    """D = (V_x - r sin a, V_y, V_z - r cos a) when the crank plane points along -x."""
    e = np.array([[-1.0], [0.0], [0.0]]) @ np.ones((1, 3))
    td = np.zeros(26)
    td[0:3] = 0.002
    td[3:6] = 100.0
    td[6:15] = np.tile([-0.44, 0.01, 0.15], 3)
    td[24], td[25] = 0.45, 0.12
    u = np.array([300.0, 900.0, 1500.0])
    u_s, td_s, q_s, X_s = ca.SX.sym("u", 3), ca.SX.sym("td", 26), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
    a, D, _, _ = platkit_psvr.crank_geometry(u_s, td_s, q_s, X_s, e)
    f = ca.Function("D", [u_s, td_s, q_s, X_s], [a, D])
    a_num, D_num = (np.asarray(v) for v in f(u, td, [1, 0, 0, 0], [0, 0, 0.6]))
    a_num = a_num.ravel()
    assert a_num == pytest.approx(0.002 * (u - 100.0))
    assert D_num == pytest.approx(np.array([-0.44 - 0.12 * np.sin(a_num), 0.01 + 0 * a_num, 0.15 - 0.12 * np.cos(a_num)]), abs=1e-12)


def test_no_yaw_and_coordinates_invert_the_pose_function(spec, model):
    for p in ([0.3, -0.2, 0.55], [-0.1, 0.25, 0.65], [0.0, 0.0, 0.6]):
        q, X = model.pose(p)
        R = matrix_from_quat(q)
        # Rx(alpha) Ry(beta): the platform's y axis stays in the base y-z plane (no yaw)
        assert R[0, 1] == pytest.approx(0.0, abs=1e-12)
        assert X[:2] == pytest.approx([0, 0], abs=0) and X[2] == pytest.approx(p[2])
        assert model.coordinates(q, X) == pytest.approx(p, abs=1e-12)


@settings(derandomize=True, deadline=None, max_examples=40)
@given(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(0.57, 0.63))  # inside the strokes (a 5^3 grid checks it)
def test_inverse_then_forward_returns_the_pose(alpha, beta, h):
    spec = get_platform("psvr")
    model = PlatformModel(spec)
    q, X = model.pose([alpha, beta, h])
    u = model.inverse(q, X)
    assert np.linalg.norm(model.residual(u, [alpha, beta, h])) < 1e-12
    fk = model.forward(u)
    assert fk.on_branch
    assert fk.p == pytest.approx([alpha, beta, h], abs=1e-9)


@settings(derandomize=True, deadline=None, max_examples=40)
@given(st.lists(st.floats(1500.0, 2600.0), min_size=3, max_size=3))
def test_forward_then_inverse_returns_the_counts(u):
    spec = get_platform("psvr")
    model = PlatformModel(spec)
    fk = model.forward(u)
    assert fk.on_branch and fk.residual < 1e-10
    assert model.inverse(fk.q, fk.X) == pytest.approx(u, abs=1e-6)


def test_mirror_below_the_crank_tips_is_detected(spec, model):
    """The same counts close the rods with the platform reflected below the crank tips (h = -300 mm)."""
    u0 = spec.neutral_u()
    with pytest.raises(WrongBranch, match="mirror"):
        model.forward(u0, guess=[0.0, 0.0, -0.2])
    mirror = model.forward(u0, guess=[0.0, 0.0, -0.2], allow_mirror=True)
    assert not mirror.on_branch
    assert mirror.p == pytest.approx([0.0, 0.0, -0.300], abs=1e-7)
    assert np.linalg.norm(model.residual(u0, mirror.p)) < 1e-10
    g = np.asarray(spec.branch(u0, spec.nominal_td(), mirror.q, mirror.X)).ravel()
    assert np.all(g[:3] > 0) and np.all(g[3:] < 0)  # cranks still outward; rods folded the wrong way


def test_the_inward_crank_root_closes_the_rod_but_is_off_branch(spec, model):
    """The rod equation's second root (crank pointing inward) satisfies F = 0 and has g < 0."""
    p = [0.1, -0.05, 0.62]
    q, X = model.pose(p)
    u = model.inverse(q, X)
    a, D, E, t = crank_state(spec, u, p)
    a = np.asarray(a).ravel()
    w = E - spec.extras["crank_pivots_m"].T
    e = spec.extras["crank_planes"].T
    P, Q = np.sum(w * e, axis=0), -w[2]
    a_other = np.pi - 2 * np.arctan2(Q, P) - a  # the reflection of a about the line V -> E
    td = spec.nominal_td()
    u_other = td[3:6] + a_other / td[0:3]
    assert np.linalg.norm(model.residual(u_other, p)) < 1e-9
    assert np.all(np.sin(a_other) < 0)
    g = np.asarray(spec.branch(u_other, td, q, X)).ravel()
    assert np.all(g < 0)
    # Newton started at the inward root converges to it; the closed form keeps the outward one
    u_newton = model._inverse_newton(q, X, td, u_other + 1.0)
    assert u_newton == pytest.approx(u_other, abs=1e-5)
    assert u == pytest.approx(model._inverse_newton(q, X, td, spec.neutral_u()), abs=1e-5)


def test_unreachable_pose_has_no_inverse(spec, model):
    q, X = model.pose([0.0, 0.0, 1.2])  # rods too short to lift the platform 1.2 m
    assert np.all(np.isnan(np.asarray(spec.inverse(spec.nominal_td(), q, X)).ravel()))
    with pytest.raises(OutOfWorkspace, match="no real inverse"):
        model.inverse(q, X)
    q, X = model.pose([0.0, 0.0, 0.72])  # reachable (2954.6 counts), but beyond the stroke's 2847.2
    with pytest.raises(OutOfWorkspace, match="control A .*outside its"):
        model.inverse(q, X)


def test_counts_outside_the_stroke_are_refused(spec, model):
    with pytest.raises(OutOfWorkspace, match="control A"):
        model.forward([3000.0, 2047.2, 2047.2])


def _write(tmp_path, data) -> Path:
    path = tmp_path / "psvr-bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _default():
    return yaml.safe_load(Path(get_platform("psvr").description_path).read_text())


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d.pop("rod_length"), "rod_length"),
        (lambda d: d.__setitem__("crank_length", -120.0), "crank_length"),
        (lambda d: d["motors"].pop(), "motors"),
        (lambda d: d["motors"][1].__setitem__("crank_pivot", [1.0, 2.0]), "motors[1].crank_pivot"),
        (lambda d: d["motors"][2].__setitem__("stroke", [2800.0, 1200.0]), "motors[2].stroke"),
        (lambda d: d["motors"][0].__setitem__("rad_per_count", "fast"), "motors[0].rad_per_count"),
        (lambda d: d["neutral_pose"].__setitem__("h", 1500.0), "neutral_pose"),
        (lambda d: d.__setitem__("units", {"length": "inch"}), "units.length"),
    ],
)
def test_bad_description_is_one_line_naming_file_and_field(tmp_path, edit, field):
    data = _default()
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(BadDescription) as info:
        platkit_psvr.build(path, {})
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg and field in msg


def test_measured_description_changes_the_model(tmp_path):
    """A description with other numbers is read, not ignored: a longer rod lifts the neutral pose."""
    data = _default()
    data["rod_length"] = 463.982379
    data["neutral_pose"]["h"] = 610.0
    spec = platkit_psvr.build(_write(tmp_path, data), {})
    assert spec.nominal_td()[24] == pytest.approx(0.463982379)
    # with the rod 10 mm longer, h = 610 mm needs the cranks about where h = 600 mm did before
    assert spec.neutral_u() == pytest.approx([2047.2] * 3, abs=2.0)
    assert not spec.neutral_u() == pytest.approx([2047.1976] * 3, abs=1e-3)


def test_cli_fk_at_neutral_counts():
    out = subprocess.run(
        [sys.executable, "-m", "platkit.cli", "fk", "--platform", "psvr", "--u", "2047.1976,2047.1976,2047.1976", "--json"],
        capture_output=True, text=True, check=True,
    )
    pose = json.loads(out.stdout)
    assert pose["z"] == pytest.approx(600.0, abs=1e-3) and pose["coordinates"]["h"] == pytest.approx(600.0, abs=1e-3)
    assert pose["roll"] == pytest.approx(0.0, abs=1e-7) and pose["on_branch"] is True
