"""A calibration.yaml read back and written again says what it said: the residual block (counts,
the noise) and the warnings too, as ``platkit diagnose`` writes the given calibration unchanged
where it names nothing."""
from __future__ import annotations

import yaml

from platkit.cli import main
from platkit.io.calibration import read_calibration, write_calibration_yaml


def test_a_calibration_read_and_written_again_keeps_its_residual_block_and_warnings(tmp_path):
    assert main(["calibrate", "--platform", "stewart", "--out", str(tmp_path / "cal"), "--quiet", "--no-report"]) == 0
    first = yaml.safe_load((tmp_path / "cal" / "calibration.yaml").read_text())
    assert first["residual"]["n_observations"] > 0 and first["residual"]["noise_sigma_per_axis"] > 0
    cal = read_calibration(tmp_path / "cal" / "calibration.yaml")
    cal.warnings = ["a warning the file carries"]
    (tmp_path / "again").mkdir()
    (tmp_path / "twice").mkdir()
    write_calibration_yaml(cal, tmp_path / "again")
    cal = read_calibration(tmp_path / "again" / "calibration.yaml")
    write_calibration_yaml(cal, tmp_path / "twice")
    twice = yaml.safe_load((tmp_path / "twice" / "calibration.yaml").read_text())
    assert twice["residual"] == first["residual"]
    assert twice["warnings"] == ["a warning the file carries"]
