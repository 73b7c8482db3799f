"""JSON out of platkit parses with a strict reader (jq, JavaScript): no NaN or Infinity (before:
`describe --json` of a URDF with a continuous joint printed "lower": -Infinity)."""
import json

import numpy as np
import pytest

from platkit.cli import main
from platkit.io.jsonout import dumps, strict


def _strict_load(text):
    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_strict_turns_non_finite_numbers_into_null():
    data = {"a": np.float64("nan"), "b": [1.5, float("inf"), np.int64(3)], "c": np.array([-np.inf, 2.0]),
            "d": (np.bool_(True), None, "x")}
    assert strict(data) == {"a": None, "b": [1.5, None, 3], "c": [None, 2.0], "d": [True, None, "x"]}
    assert _strict_load(dumps(data)) == strict(data)


def test_describe_json_of_a_continuous_joint(tmp_path, capsys):
    urdf = tmp_path / "c.urdf"
    urdf.write_text('<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="continuous">'
                    '<parent link="a"/><child link="b"/><origin xyz="0.1 0 0"/><axis xyz="0 0 1"/></joint></robot>')
    assert main(["describe", "--platform", "urdf", "--description", str(urdf), "--json"]) == 0
    out = _strict_load(capsys.readouterr().out)
    assert out["controls"][0]["lower"] is None and out["controls"][0]["upper"] is None


def test_workspace_json_is_strict(tmp_path, capsys):
    assert main(["workspace", "--platform", "rotary", "--no-plots", "--out", str(tmp_path / "ws"), "--json"]) == 0
    printed = _strict_load(capsys.readouterr().out)
    assert printed == _strict_load((tmp_path / "ws" / "workspace.json").read_text())
    with pytest.raises(ValueError):
        _strict_load('{"x": NaN}')
