"""The rotary stand: the two-stage rig of spec/stands.md on the URDF route."""
import json

import numpy as np
import pinocchio as pin
import pytest

from platkit import get_platform
from platkit.cli import main
from platkit.errors import BadDescription, BadInput
from platkit.geometry import matrix_from_quat, matrix_from_rpy, rotvec_from_matrix
from platkit.io.urdf_export import export_calibrated_urdf
from platkit.kinematics import PlatformModel
from platkit.plugins import default_host
from platkit.testing import check_platform


def Rz(a):
    return matrix_from_rpy(0.0, 0.0, a)


def Ry(a):
    return matrix_from_rpy(0.0, a, 0.0)


def Rx(a):
    return matrix_from_rpy(a, 0.0, 0.0)


@pytest.fixture(scope="module")
def spec():
    return get_platform("rotary")


def _pose(spec, u, td=None):
    q, X = spec.forward(np.asarray(u, float), spec.nominal_td() if td is None else td)
    return matrix_from_quat(np.asarray(q).ravel()), np.asarray(X).ravel()


def _set(spec, **values):
    td = spec.nominal_td()
    for name, v in values.items():
        td[spec.parameter_names.index(name.replace("__", "."))] = v
    return td


def test_controls_and_parameters(spec):
    assert spec.control_names == ["u1", "u2"]
    assert [c.unit for c in spec.controls] == ["deg", "deg"]
    np.testing.assert_allclose(spec.control_bounds(), [[-180, -90], [180, 90]], rtol=1e-15)
    assert spec.neutral_u().tolist() == [0.0, 0.0]
    assert spec.base_frame == "base" and spec.moving_frame == "platform"
    expected = []
    for j in ("joint1", "joint2"):
        expected += [f"{j}.offset", f"{j}.scale"] + [f"{j}.origin_{a}" for a in ("x", "y", "z", "rx", "ry", "rz")]
    assert spec.parameter_names == expected
    assert all(p.free for p in spec.parameters)  # the spec calibrates offsets, scales and origin errors
    assert {p.name: p.nominal for p in spec.parameters}["joint2.scale"] == 1.0


def test_conformance(spec):
    report = check_platform(spec)
    assert report["round_trips"] == 20 and report["jacobian_fd_error"] < 1e-6


def test_nominal_geometry(spec):
    R, X = _pose(spec, [0, 0])
    np.testing.assert_allclose(R, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(X, [0, 0, 0.150], atol=1e-15)  # joint 2 sits 150 mm above joint 1
    for u1, u2 in [(90, 0), (0, 30), (-135, 60), (170, -85)]:
        R, X = _pose(spec, [u1, u2])
        np.testing.assert_allclose(R, Rz(np.radians(u1)) @ Ry(np.radians(u2)), atol=1e-15)
        np.testing.assert_allclose(X, [0, 0, 0.150], atol=1e-15)
    # a marker 100 mm along the platform's x axis: u2 = +90 deg turns it down (right-handed about y)
    R, X = _pose(spec, [0, 90])
    np.testing.assert_allclose(X + R @ [0.1, 0, 0], [0, 0, 0.05], atol=1e-15)


def test_angle_is_k_times_u_minus_u0(spec):
    k1, u01_deg, k2, u02_deg = 1.02, 3.0, 0.97, -1.5
    td = _set(spec, joint1__scale=k1, joint1__offset=np.radians(u01_deg), joint2__scale=k2, joint2__offset=np.radians(u02_deg))
    u = np.array([40.0, -25.0])
    R, X = _pose(spec, u, td)
    R_ref, X_ref = _pose(spec, [k1 * (u[0] - u01_deg), k2 * (u[1] - u02_deg)])
    np.testing.assert_allclose(R, R_ref, atol=1e-15)
    np.testing.assert_allclose(X, X_ref, atol=1e-15)


def test_origin_errors_axis_offset_and_misalignment(spec):
    # axis offset: joint 2's axis 2 mm along the outer stage's x; at u1 = 90 deg that is base +y
    R, X = _pose(spec, [90, 20], _set(spec, joint2__origin_x=0.002))
    np.testing.assert_allclose(X, [0, 0.002, 0.150], atol=1e-15)
    # non-perpendicularity: joint 2's axis tilted by 10 mrad about the outer stage's x
    tilt = 0.01
    u2 = np.radians(30.0)
    R, X = _pose(spec, [0, 30], _set(spec, joint2__origin_rx=tilt))
    np.testing.assert_allclose(R, Rx(tilt) @ Ry(u2), atol=1e-15)
    axis = Rx(tilt) @ [0, 1, 0]
    # the platform turns about the tilted axis: R Rx(tilt)^T is the rotation by u2 about it
    np.testing.assert_allclose(rotvec_from_matrix(R @ Rx(tilt).T), u2 * axis, atol=1e-12)
    # axis misalignment of joint 1 (a tilted base axis) moves the stage's top off the z axis
    R, X = _pose(spec, [0, 0], _set(spec, joint1__origin_ry=0.01))
    np.testing.assert_allclose(X, [0.150 * np.sin(0.01), 0, 0.150 * np.cos(0.01)], atol=1e-15)


def test_inverse_from_neutral_start(spec):
    model = PlatformModel(spec)
    td = _set(spec, joint1__offset=0.01, joint2__origin_x=0.001, joint2__origin_rz=0.005)
    fk = model.forward([50.0, -35.0], td)
    u = model.inverse(fk.q, fk.X, td)  # Gauss-Newton from u = (0, 0)
    np.testing.assert_allclose(u, [50.0, -35.0], atol=1e-8)


def test_export_matches_pinocchio_in_radians(spec, tmp_path):
    rng = np.random.default_rng(2)
    td = _set(spec, joint1__offset=0.02, joint2__offset=-0.03, joint1__origin_rx=0.004, joint2__origin_x=0.0015,
              joint2__origin_y=-0.001, joint2__origin_z=0.002, joint2__origin_ry=0.01, joint2__origin_rz=-0.006)
    out = export_calibrated_urdf(spec, td, tmp_path / "rotary_calibrated.urdf")
    model = pin.buildModelFromUrdf(str(out))
    data = model.createData()
    for _ in range(6):
        u = rng.uniform([-180, -90], [180, 90])
        R, X = _pose(spec, u, td)
        pin.framesForwardKinematics(model, data, np.radians(u))  # the URDF's controls are radians
        ref = data.oMf[model.getFrameId("platform", pin.BODY)]
        np.testing.assert_allclose(X, ref.translation, atol=1e-12)
        np.testing.assert_allclose(R, ref.rotation, atol=1e-12)
    with pytest.raises(BadInput, match=r"joint1\.scale = 1\.01"):
        export_calibrated_urdf(spec, _set(spec, joint1__scale=1.01), tmp_path / "no.urdf")


def test_description_errors(tmp_path):
    three = tmp_path / "three.urdf"
    three.write_text(
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>'
        + "".join(f'<joint name="j{i}" type="revolute"><parent link="{p}"/><child link="{c}"/><axis xyz="0 0 1"/></joint>'
                  for i, (p, c) in enumerate([("a", "b"), ("b", "c"), ("c", "d")]))
        + "</robot>")
    with pytest.raises(BadDescription, match=r"three\.urdf: the rotary rig needs exactly two revolute joints"):
        get_platform("rotary", three)
    with pytest.raises(BadInput, match=r"the rotary stand takes the options base_link, moving_link; unknown: \['tool'\]"):
        default_host().build("rotary", None, tool="platform")
    # markers on the inner stage's own link: the same rig; on the outer stage: not a two-stage chain
    assert default_host().build("rotary", None, moving_link="inner_stage").moving_frame == "inner_stage"
    with pytest.raises(BadDescription, match=r"needs exactly two revolute joints from base to outer_stage"):
        default_host().build("rotary", None, moving_link="outer_stage")
    yaml_file = tmp_path / "rig.yaml"
    yaml_file.write_text("a: 1\n")
    with pytest.raises(BadDescription, match=r"rig\.yaml: the rotary stand reads \.urdf files"):
        get_platform("rotary", yaml_file)


def test_cli_fk_takes_degrees(capsys):
    assert main(["fk", "--platform", "rotary", "--u", "90,0", "--json"]) == 0
    pose = json.loads(capsys.readouterr().out)
    assert abs(pose["yaw"] - np.pi / 2) < 1e-12 and abs(pose["z"] - 150.0) < 1e-9


def test_identifiable_parameters_with_unknown_mocap_transform_and_markers(spec):
    """From three markers on the platform, with the base-to-mocap transform and the markers'
    positions unknown, exactly four combinations of td are identifiable: both scales, joint 2's
    axis offset along x and its non-perpendicularity (rx); everything else is absorbed."""
    import casadi as ca

    from platkit.geometry import ca_matrix_from_quat, ca_matrix_from_rpy

    u = ca.SX.sym("u", 2)
    td = ca.SX.sym("td", spec.n_td)
    markers = ca.SX.sym("m", 9)
    mocap = ca.SX.sym("b", 6)
    q, X = spec.forward(u, td)
    R, Rb = ca_matrix_from_quat(q), ca_matrix_from_rpy(mocap[3], mocap[4], mocap[5])
    y = ca.vertcat(*[ca.mtimes(Rb, X + ca.mtimes(R, markers[3 * i:3 * i + 3])) + mocap[:3] for i in range(3)])
    jac = ca.Function("J", [u, td, markers, mocap], [ca.jacobian(y, td), ca.jacobian(y, ca.vertcat(markers, mocap))])
    rng = np.random.default_rng(0)
    m0 = np.array([0.1, 0, 0.02, 0, 0.1, 0.03, -0.08, -0.05, 0.01])
    blocks = [jac(rng.uniform([-180, -90], [180, 90]), spec.nominal_td(), m0, np.zeros(6)) for _ in range(30)]
    J_td = np.vstack([np.asarray(b[0]) for b in blocks])
    J_nuisance = np.vstack([np.asarray(b[1]) for b in blocks])
    J_td = J_td - J_nuisance @ np.linalg.lstsq(J_nuisance, J_td, rcond=None)[0]  # nuisance projected out
    s = np.linalg.svd(J_td, compute_uv=False)
    assert np.sum(s > 1e-9 * s[0]) == 4
    names = spec.parameter_names
    alone = [n for i, n in enumerate(names) if np.linalg.norm(J_td[:, i]) > 1e-9]
    assert alone == ["joint1.scale", "joint2.scale", "joint2.origin_x", "joint2.origin_rx"]
