"""The urdf stand: building chains from URDF files, safe reading, parameters, export."""
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
import yourdfpy

from platkit import get_platform
from platkit.cli import main
from platkit.errors import BadDescription, BadInput
from platkit.geometry import matrix_from_quat
from platkit.io.urdf_export import export_calibrated_urdf
from platkit.kinematics import PlatformModel
from platkit.plugins import default_host
from platkit.testing import check_platform
from platkit.urdf import read_urdf, serial_chain

TIAGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"
if not TIAGO.is_file():
    TIAGO = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"

# revolute, continuous, prismatic and a mimic joint on one chain, fixed joints with rotations,
# a side branch (a second leaf) and a mimic of an off-chain joint on that branch
MIXED = """<?xml version="1.0"?>
<robot name="mixed">
  <link name="base"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/><link name="e"/>
  <link name="tip"/><link name="side"/><link name="side2"/>
  <joint name="j_rev" type="revolute"><parent link="base"/><child link="a"/>
    <origin xyz="0.1 0.02 0.3" rpy="0.1 -0.2 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j_fix" type="fixed"><parent link="a"/><child link="b"/><origin xyz="0 0.05 0.1" rpy="1.5707963267948966 0 0.4"/></joint>
  <joint name="j_cont" type="continuous"><parent link="b"/><child link="c"/>
    <origin xyz="0.2 0 0" rpy="0 0.3 0"/><axis xyz="0.6 0 0.8"/></joint>
  <joint name="j_pri" type="prismatic"><parent link="c"/><child link="d"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="1 1 0"/><limit lower="0" upper="0.3" effort="1" velocity="1"/></joint>
  <joint name="j_mim" type="revolute"><parent link="d"/><child link="e"/>
    <origin xyz="0.05 0 0" rpy="0 0 -0.5"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/>
    <mimic joint="j_rev" multiplier="-0.5" offset="0.2"/></joint>
  <joint name="j_tool" type="fixed"><parent link="e"/><child link="tip"/><origin xyz="0 0 0.07"/></joint>
  <joint name="j_side" type="revolute"><parent link="a"/><child link="side"/><axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="j_side_mim" type="prismatic"><parent link="side"/><child link="side2"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="j_pri"/></joint>
</robot>
"""


def _write(tmp_path, text, name="robot.urdf"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _pinocchio_pose(urdf, chain, values, mimic=False):
    """Moving link in base link (R, p) from pinocchio, at URDF joint values of the actuated joints."""
    model = pin.buildModelFromUrdf(str(urdf), mimic)
    data = model.createData()
    q = pin.neutral(model)
    for j, v in zip(chain.actuated, values):
        joint = model.joints[model.getJointId(j.name)]
        if joint.nq == 2:
            q[joint.idx_q:joint.idx_q + 2] = np.cos(v), np.sin(v)
        else:
            q[joint.idx_q] = v
    pin.framesForwardKinematics(model, data, q)
    rel = data.oMf[model.getFrameId(chain.base_link, pin.BODY)].inverse() * data.oMf[model.getFrameId(chain.moving_link, pin.BODY)]
    return rel.rotation, rel.translation


def _random_td(spec, rng, offset=0.05, origin_m=0.01, origin_rad=0.02):
    td = spec.nominal_td()
    for i, p in enumerate(spec.parameters):
        if p.group == "offset":
            td[i] = rng.normal(0, offset)
        elif p.group == "origin":
            td[i] = rng.normal(0, origin_m if p.unit == "m" else origin_rad)
    return td


# ----------------------------------------------------------------------------- the stand


def test_default_description_is_the_shipped_arm_and_conforms():
    spec = get_platform("urdf")
    assert spec.control_names == ["shoulder_yaw_joint", "shoulder_pitch_joint", "elbow_joint"]
    assert [c.unit for c in spec.controls] == ["rad"] * 3
    assert spec.moving_frame == "tool0" and spec.base_frame == "base_link"
    report = check_platform(spec)
    assert report["round_trips"] == 20 and report["jacobian_fd_error"] < 1e-6
    # neutral: the arm straight up, tool at 0.12 + 0.08 + 0.30 + 0.25 m, 0.02 m forward
    q, X = (np.asarray(a).ravel() for a in spec.forward(spec.neutral_u(), spec.nominal_td()))
    np.testing.assert_allclose(X, [0.02, 0.0, 0.75], atol=1e-15)


def test_tiago_arm_chain_controls_parameters_and_conformance():
    spec = get_platform("urdf", TIAGO, base_link="base_link", moving_link="wrist_ft_tool_link")
    assert spec.control_names == ["torso_lift_joint"] + [f"arm_{i}_joint" for i in range(1, 8)]
    assert [c.unit for c in spec.controls] == ["m"] + ["rad"] * 7
    assert (spec.controls[0].lower, spec.controls[0].upper) == (0.0, 0.35)
    assert spec.n_td == 8 * 8
    names = spec.parameter_names
    assert names[:8] == ["torso_lift_joint.offset", "torso_lift_joint.scale"] + [
        f"torso_lift_joint.origin_{a}" for a in ("x", "y", "z", "rx", "ry", "rz")]
    groups = {p.group for p in spec.parameters}
    assert groups == {"offset", "scale", "origin"}
    # offsets and origin errors start free, scales fixed (the spec's urdf stand has no scales)
    assert all(p.free == (p.group != "scale") for p in spec.parameters)
    assert next(p for p in spec.parameters if p.name == "torso_lift_joint.offset").unit == "m"
    assert next(p for p in spec.parameters if p.name == "arm_5_joint.origin_rx").unit == "rad"
    # the URDF's nominal numbers are recorded
    src = next(p for p in spec.parameters if p.name == "arm_2_joint.origin_x").source
    assert "tiago_48_schunk.urdf: error of joint arm_2_joint <origin xyz='0.125 0.0195 -0.031' rpy='1.57079633 0 0'>" in src
    assert spec.extras["joint_origins"]["torso_lift_joint"]["xyz"] == [0.0, 0.0, 0.597]
    check_platform(spec)


def test_inverse_kinematics_from_another_start_reaches_the_pose():
    """Gauss-Newton over u from the neutral controls, not from the answer."""
    spec = get_platform("urdf", TIAGO, base_link="base_link", moving_link="wrist_ft_tool_link")
    model = PlatformModel(spec)
    u = spec.neutral_u() + np.array([0.1, 0.3, -0.2, 0.25, 0.5, -0.3, 0.2, 0.3])
    fk = model.forward(u)
    guess = u + np.random.default_rng(3).normal(0, 0.05, spec.n_u)
    u_back = model.inverse(fk.q, fk.X, strict=False, guess=guess)
    fk2 = model.forward(u_back, strict=False)
    assert np.linalg.norm(fk2.X - fk.X) < 1e-9 and 1 - abs(fk2.q @ fk.q) < 1e-12


def test_yaml_description_and_options(tmp_path):
    urdf = _write(tmp_path, MIXED)
    desc = tmp_path / "arm.yaml"
    desc.write_text(yaml.safe_dump({"urdf": "robot.urdf", "moving_link": "tip", "notes": "x"}))
    spec = get_platform("urdf", desc)
    assert spec.base_frame == "base" and spec.moving_frame == "tip"
    assert spec.control_names == ["j_rev", "j_cont", "j_pri"]  # the mimic joint is no control
    assert spec.description_path == desc and spec.description["urdf"] == str(urdf.resolve())
    # options override the description
    spec2 = get_platform("urdf", desc, moving_link="side")
    assert spec2.control_names == ["j_rev", "j_side"]
    spec3 = get_platform("urdf", urdf, base_link="b", moving_link="d")
    assert spec3.control_names == ["j_cont", "j_pri"]
    check_platform(spec)


def test_yaml_description_errors_name_the_field(tmp_path):
    _write(tmp_path, MIXED)
    bad = tmp_path / "bad.yaml"
    bad.write_text("urdf: robot.urdf\nmoving_lnk: tip\n")
    with pytest.raises(BadDescription, match=r"bad\.yaml: unknown field\(s\) \['moving_lnk'\]"):
        get_platform("urdf", bad)
    missing = tmp_path / "missing.yaml"
    missing.write_text("urdf: nowhere.urdf\n")
    with pytest.raises(BadDescription, match=r"missing\.yaml: field 'urdf' names .*nowhere\.urdf"):
        get_platform("urdf", missing)
    with pytest.raises(BadInput, match="unknown: \\['tool'\\]"):
        default_host().build("urdf", None, tool="x")


def test_chain_choice_errors(tmp_path):
    urdf = _write(tmp_path, MIXED)
    tree = read_urdf(urdf)
    with pytest.raises(BadInput, match=r"2 leaf links; choose moving_link among: tip, side2"):
        serial_chain(tree)
    with pytest.raises(BadInput, match=r"moving_link 'nope' is not a link"):
        serial_chain(tree, moving_link="nope")
    with pytest.raises(BadInput, match=r"moving_link 'a' is not below base_link 'side'"):
        serial_chain(tree, "side", "a")
    # the mimic on the side branch follows j_cont, which is not on that chain
    with pytest.raises(BadInput, match=r"joint 'j_side_mim' mimics 'j_pri', which is not an actuated joint of the chain base -> side2"):
        serial_chain(tree, moving_link="side2")
    with pytest.raises(BadInput, match=r"the chain a -> b has no actuated joint"):
        serial_chain(tree, "a", "b")
    with pytest.raises(BadInput, match=r"leaf links; choose moving_link among: base_laser_link"):
        get_platform("urdf", TIAGO)


def test_mixed_joint_types_and_mimic_match_pinocchio(tmp_path):
    urdf = _write(tmp_path, MIXED)
    spec = get_platform("urdf", urdf, moving_link="tip")
    chain = spec.extras["chain"]
    assert [j.name for j in chain.calibrated] == ["j_rev", "j_cont", "j_pri", "j_mim"]
    assert "j_mim.offset" not in spec.parameter_names and "j_mim.origin_rz" in spec.parameter_names
    lo, hi = spec.control_bounds()
    assert np.isinf(lo[1]) and np.isinf(hi[1])  # continuous: unbounded
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(10):
        u = rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3))
        q, X = (np.asarray(a).ravel() for a in spec.forward(u, spec.nominal_td()))
        R_ref, X_ref = _pinocchio_pose(urdf, chain, u, mimic=True)
        worst = max(worst, np.abs(X - X_ref).max(), np.abs(matrix_from_quat(q) - R_ref).max())
    assert worst < 1e-12
    check_platform(spec)


def test_offset_and_scale_act_on_the_joint_value():
    spec = get_platform("urdf")
    td = spec.nominal_td()
    names = spec.parameter_names
    u = np.array([0.3, -0.4, 0.9])
    td_cal = td.copy()
    td_cal[names.index("elbow_joint.offset")] = 0.05
    td_cal[names.index("shoulder_yaw_joint.scale")] = 1.1
    expected = np.array([1.1 * 0.3, -0.4, 0.9 - 0.05])
    for a, b in zip(spec.forward(u, td_cal), spec.forward(expected, td)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-15)


def test_origin_error_is_a_rigid_error_in_the_joint_frame():
    """elbow origin_x moves the tool along the upper arm's x axis; origin_ry tilts the forearm."""
    spec = get_platform("urdf")
    names = spec.parameter_names
    u = np.array([0.5, 0.0, 0.0])  # shoulder yaw 0.5 rad: the upper arm's x axis is (cos .5, sin .5, 0)
    td = spec.nominal_td()
    X0 = np.asarray(spec.forward(u, td)[1]).ravel()
    td1 = td.copy()
    td1[names.index("elbow_joint.origin_x")] = 1e-3
    X1 = np.asarray(spec.forward(u, td1)[1]).ravel()
    np.testing.assert_allclose(X1 - X0, 1e-3 * np.array([np.cos(0.5), np.sin(0.5), 0]), atol=1e-15)
    td2 = td.copy()
    td2[names.index("elbow_joint.origin_ry")] = 0.01  # same as turning the elbow by 0.01 rad
    for a, b in zip(spec.forward(u, td2), spec.forward(u + [0, 0, 0.01], td)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-15)


# ----------------------------------------------------------------------------- safe reading


def test_entities_and_dtds_are_refused(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("0 0 1")
    xxe = f"""<?xml version="1.0"?>
<!DOCTYPE robot [<!ENTITY ax SYSTEM "file://{secret}">]>
<robot name="x"><link name="a"/><link name="b"/>
<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="&ax;"/></joint></robot>"""
    with pytest.raises(BadDescription, match=r"xxe\.urdf: line 2: DTDs and XML entities are not accepted"):
        read_urdf(_write(tmp_path, xxe, "xxe.urdf"))
    laughs = '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;">]>\n<robot name="&b;"/>'
    with pytest.raises(BadDescription, match="DTDs and XML entities are not accepted"):
        read_urdf(_write(tmp_path, laughs, "laughs.urdf"))
    utf16 = ('<?xml version="1.0" encoding="UTF-16"?>\n<!DOCTYPE robot [<!ENTITY a "x">]>\n<robot name="&a;"/>')
    path16 = tmp_path / "utf16.urdf"
    path16.write_bytes(utf16.encode("utf-16"))
    with pytest.raises(BadDescription, match="DTDs and XML entities are not accepted"):
        read_urdf(path16)


@pytest.mark.parametrize("fragment, message", [
    ('<origin xyz="0 0 abc"/>', r"joint 'j' <origin xyz> must be 3 numbers, got '0 0 abc'"),
    ('<origin rpy="0 0"/>', r"joint 'j' <origin rpy> must be 3 finite numbers"),
    ('<origin xyz="0 nan 0"/>', r"joint 'j' <origin xyz> must be 3 finite numbers"),
    ('<axis xyz="0 0 0"/>', r"joint 'j' <axis xyz> is the zero vector"),
    ('<limit lower="low" upper="1" effort="1" velocity="1"/>', r"joint 'j' <limit lower> must be a number"),
    ('<mimic multiplier="2"/>', r"joint 'j' <mimic> names no joint"),
])
def test_bad_numbers_name_the_joint_and_element(tmp_path, fragment, message):
    text = f'<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="revolute"><parent link="a"/><child link="b"/>{fragment}</joint></robot>'
    with pytest.raises(BadDescription, match=message):
        read_urdf(_write(tmp_path, text))


def test_malformed_files_fail_in_one_line(tmp_path):
    with pytest.raises(BadDescription, match=r"broken\.urdf: line 3: not well-formed XML"):
        read_urdf(_write(tmp_path, '<robot name="x">\n<link name="a">\n</robot>', "broken.urdf"))
    with pytest.raises(BadDescription, match=r"the top element must be <robot>, got <sdf>"):
        read_urdf(_write(tmp_path, "<sdf/>"))
    with pytest.raises(BadDescription, match=r"joint 'j' names link 'c', which the file does not define"):
        read_urdf(_write(tmp_path, '<robot name="x"><link name="a"/><joint name="j" type="fixed"><parent link="a"/><child link="c"/></joint></robot>'))
    with pytest.raises(BadDescription, match=r"joint 'j' has type 'hinge'"):
        read_urdf(_write(tmp_path, '<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="hinge"><parent link="a"/><child link="b"/></joint></robot>'))
    cycle = ('<robot name="x"><link name="r"/><link name="a"/><link name="b"/>'
             '<joint name="j1" type="fixed"><parent link="a"/><child link="b"/></joint>'
             '<joint name="j2" type="fixed"><parent link="b"/><child link="a"/></joint></robot>')
    with pytest.raises(BadDescription, match=r"the joints form a cycle through link 'a'"):
        read_urdf(_write(tmp_path, cycle))
    floating = '<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="floating"><parent link="a"/><child link="b"/></joint></robot>'
    with pytest.raises(BadInput, match=r"joint 'j' on the chain a -> b is floating"):
        serial_chain(read_urdf(_write(tmp_path, floating)))
    assert main(["describe", "--platform", "urdf", "--description", str(tmp_path / "broken.urdf")]) == 2


def test_cli_describe_and_fk(capsys):
    assert main(["describe", "--platform", "urdf"]) == 0
    out = capsys.readouterr().out
    assert "shoulder_yaw_joint" in out and "elbow_joint.origin_rz" in out
    assert main(["fk", "--platform", "urdf", "--u", "0,0,0", "--json"]) == 0
    pose = yaml.safe_load(capsys.readouterr().out)
    assert abs(pose["z"] - 750.0) < 1e-9 and abs(pose["x"] - 20.0) < 1e-9


# ----------------------------------------------------------------------------- export


def test_export_folds_calibration_into_origins_tiago(tmp_path):
    """The exported URDF at the raw controls equals the calibrated model (checked with pinocchio)."""
    spec = get_platform("urdf", TIAGO, base_link="base_link", moving_link="wrist_ft_tool_link")
    rng = np.random.default_rng(11)
    td = _random_td(spec, rng)
    out = export_calibrated_urdf(spec, td, tmp_path / "out" / "tiago_calibrated.urdf")
    chain = spec.extras["chain"]
    lo, hi = spec.control_bounds()
    worst = 0.0
    for _ in range(8):
        u = rng.uniform(lo, hi)
        q, X = (np.asarray(a).ravel() for a in spec.forward(u, td))
        R_ref, X_ref = _pinocchio_pose(out, chain, u)
        worst = max(worst, np.abs(X - X_ref).max(), np.abs(matrix_from_quat(q) - R_ref).max())
        # and the calibration really moved the tool (the test can fail)
        assert np.linalg.norm(X - np.asarray(spec.forward(u, spec.nominal_td())[1]).ravel()) > 1e-3
    assert worst < 1e-12
    # the exported file is a URDF platkit reads again, unchanged elsewhere; calibrated at nominal td
    again = get_platform("urdf", out, base_link="base_link", moving_link="wrist_ft_tool_link")
    u = rng.uniform(lo, hi)
    np.testing.assert_allclose(np.asarray(again.forward(u, again.nominal_td())[1]), np.asarray(spec.forward(u, td)[1]), atol=1e-12)
    assert "calibrated by platkit" in out.read_text() and "Copyright (c) 2011, PAL Robotics" in out.read_text()


def test_export_with_mimic_and_prismatic(tmp_path):
    urdf = _write(tmp_path, MIXED)
    spec = get_platform("urdf", urdf, moving_link="tip")
    rng = np.random.default_rng(5)
    td = _random_td(spec, rng)
    out = export_calibrated_urdf(spec, td, tmp_path / "mixed_cal.urdf")
    chain = spec.extras["chain"]
    for _ in range(5):
        u = rng.uniform([-2, -3, 0], [2, 3, 0.3])
        q, X = (np.asarray(a).ravel() for a in spec.forward(u, td))
        R_ref, X_ref = _pinocchio_pose(out, chain, u, mimic=True)
        assert np.abs(X - X_ref).max() < 1e-12 and np.abs(matrix_from_quat(q) - R_ref).max() < 1e-12


def test_export_refuses_scales_and_writes_nothing(tmp_path):
    spec = get_platform("urdf")
    td = spec.nominal_td()
    td[spec.parameter_names.index("elbow_joint.scale")] = 1.001
    target = tmp_path / "never.urdf"
    with pytest.raises(BadInput, match=r"elbow_joint\.scale = 1\.001: a URDF joint has no scale"):
        export_calibrated_urdf(spec, td, target)
    with pytest.raises(BadInput, match="expected 24 parameters"):
        export_calibrated_urdf(spec, td[:3], target)
    assert not target.exists() and list(tmp_path.iterdir()) == []
    with pytest.raises(BadInput, match="not described by a URDF chain"):
        export_calibrated_urdf(get_platform("stewart"), get_platform("stewart").nominal_td(), target)


def test_mimic_joint_before_its_master(tmp_path):
    text = """<robot name="m"><link name="a"/><link name="b"/><link name="c"/>
  <joint name="first" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.1 0 0.2" rpy="0 0.2 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/><mimic joint="second" multiplier="2" offset="-0.1"/></joint>
  <joint name="second" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint></robot>"""
    urdf = _write(tmp_path, text)
    spec = get_platform("urdf", urdf)
    assert spec.control_names == ["second"]
    rng = np.random.default_rng(4)
    td = _random_td(spec, rng)
    out = export_calibrated_urdf(spec, td, tmp_path / "m_cal.urdf")
    chain = spec.extras["chain"]
    # pinocchio refuses a mimic before its master; yourdfpy's own forward kinematics is the reference
    for path, params in ((urdf, spec.nominal_td()), (out, td)):
        ref = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)
        for u in (np.array([0.7]), np.array([-1.3])):
            ref.update_cfg({"second": float(u[0])})
            T = ref.get_transform(frame_to=chain.moving_link, frame_from=chain.base_link)
            q, X = (np.asarray(a).ravel() for a in spec.forward(u, params))
            assert np.abs(X - T[:3, 3]).max() < 1e-12 and np.abs(matrix_from_quat(q) - T[:3, :3]).max() < 1e-12


def test_export_calibration_yaml_with_markers_and_mocap_frame(tmp_path):
    """A calibration.yaml of the rotary rig -> URDF: marker links seen from the added mocap link
    are where the calibrated model puts the markers in the motion-capture frame."""
    from platkit.geometry import matrix_from_rotvec
    from platkit.io.calibration import Calibration
    from platkit.io.urdf_export import main as export_main

    spec = get_platform("rotary")
    td = _random_td(spec, np.random.default_rng(8), offset=0.01, origin_m=0.002, origin_rad=0.005)
    markers = np.array([[0.1, 0.0, 0.02], [0.0, 0.12, 0.03], [-0.08, -0.05, 0.01]])
    cal = Calibration(
        platform="rotary", description=None, spec=spec, td=td, td_std=np.full(spec.n_td, np.nan),
        td_nominal=spec.nominal_td(), td_status=["estimated"] * spec.n_td,
        mocap_rotvec=np.array([0.1, -0.2, 0.3]), mocap_translation=np.array([1.0, 2.0, 0.5]), mocap_std=np.full(6, np.nan),
        marker_names=["M1", "M2", "M3"], marker_positions=markers, marker_std=np.full((3, 3), np.nan),
        rms_before=1e-3, rms_after=1e-4,
    )
    cal_path = tmp_path / "calibration.yaml"
    cal_path.write_text(cal.to_yaml())
    out = tmp_path / "rotary_calibrated.urdf"
    assert export_main([str(cal_path), str(out)]) == 0
    model = pin.buildModelFromUrdf(str(out))
    data = model.createData()
    mocap_R = matrix_from_rotvec(cal.mocap_rotvec)
    for u in ([30.0, -20.0], [-150.0, 75.0]):
        pin.framesForwardKinematics(model, data, np.radians(u))
        mocap = data.oMf[model.getFrameId("mocap", pin.BODY)]
        q, X = (np.asarray(a).ravel() for a in spec.forward(np.array(u), td))
        for name, m in zip(cal.marker_names, markers):
            seen = (mocap.inverse() * data.oMf[model.getFrameId(f"marker_{name}", pin.BODY)]).translation
            expected = mocap_R @ (X + matrix_from_quat(q) @ m) + cal.mocap_translation
            assert np.abs(seen - expected).max() < 1e-12
    assert export_main([str(tmp_path / "missing.yaml"), str(tmp_path / "x.urdf")]) == 2
    # exporting the exported file again would add marker_M1 twice
    again = get_platform("urdf", out, moving_link="platform")
    with pytest.raises(BadInput, match=r"already has a link or joint named 'marker_M1'"):
        export_calibrated_urdf(again, again.nominal_td(), tmp_path / "y.urdf", markers={"M1": [0, 0, 0]})
    assert not (tmp_path / "y.urdf").exists()
