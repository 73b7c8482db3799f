"""A URDF stand's calibration whose joint scales are not 1 cannot be written as a URDF: the reason
is a warning of the calibration (calibration.yaml and report.json list it, calibrate says it), not
only a field of report.json."""
import dataclasses
import json

import numpy as np
import yaml
from test_urdf_tree import MAPPING, MARKERS, commands, observe, tree_spec, true_td

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.report import write_outputs
from platkit.poses import PoseSet


def test_a_calibrated_urdf_not_written_is_a_warning_in_every_file(tmp_path):
    spec = tree_spec()
    rng = np.random.default_rng(3)
    U = commands(spec, 30, rng)
    poses = PoseSet("urdf", U, observe(spec, true_td(spec, rng), U, rng), list(MARKERS), moving_link=MAPPING)
    cal = calibrate(poses, spec)
    td = cal.td.copy()
    td[spec.parameter_names.index("torso_yaw.scale")] = 1.05
    cal = dataclasses.replace(cal, td=td, warnings=[])
    written = write_outputs(cal, tmp_path / "out", poses, with_html=False)
    assert not any(p.name == "calibrated.urdf" for p in written)
    said = [w for w in cal.warnings if w.startswith("calibrated.urdf not written: torso_yaw.scale = 1.05")]
    assert len(said) == 1
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["calibrated_urdf"].startswith("not written: torso_yaw.scale")
    assert said[0] in report["warnings"]
    assert said[0] in yaml.safe_load((tmp_path / "out" / "calibration.yaml").read_text())["warnings"]
