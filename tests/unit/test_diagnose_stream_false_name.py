"""platkit diagnose of a stream without holds whose response was calibrated in the first order, on a
stand whose drives follow a second-order response (the physical simulator's): the response is chosen
again before any effect is tried (platkit.diagnose.response_kind), so that what a second-order
drive does beyond a first-order lag is not named as an effect of the stand.

Without it, a clean 20 s multisine of two rigid bodies alone (Stewart, seed 4111) was reported
``unexplained`` (a scale nonlinearity took a slice of the response's misfit first), and with a 1 mm
backlash at L1, 30 s, ``scale_nonlinearity`` at L2 was named beside it (docs/diagnosis-streams.md).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from bodies_alone import strip_markers
from scipy import sparse

from platkit.calibrate.motion import LocalResponseTerm
from platkit.calibrate.motion_kind import theta_by_name
from platkit.calibrate.response import ResponseModel
from platkit.cli import main
from platkit.diagnose.response_kind import ROUND_RESPONSE, second_order_response


@pytest.fixture(scope="module")
def clean_first_order(tmp_path_factory):
    root = tmp_path_factory.mktemp("stream_first_order")
    sim = root / "sim"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "multisine", "--duration-s", "20",
                 "--rate-hz", "40", "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2", "--seed", "4111",
                 "--out", str(sim)]) == 0
    strip_markers(sim, root / "bodies")
    assert main(["calibrate", str(root / "bodies"), "--quiet", "--no-report", "--response-kind", "first-order",
                 "--out", str(root / "cal")]) == 0
    return root


def test_a_clean_stream_calibrated_in_the_first_order_names_nothing(clean_first_order):
    root = clean_first_order
    assert main(["diagnose", str(root / "bodies"), "--calibration", str(root / "cal" / "calibration.yaml"),
                 "--out", str(root / "diag"), "--quiet", "--no-report"]) == 0
    d = json.loads((root / "diag" / "diagnosis.json").read_text())
    # before: [unexplained] (the first order's misfit, located in time, a scale nonlinearity its closest name)
    assert d["findings"] == [], [(f["effect"], f["where"]) for f in d["findings"]]
    (response,) = [r for r in d["rounds"] if r.get("round") == ROUND_RESPONSE]
    assert response["kept"] and response["heldout_rms_after"] < response["heldout_rms_before"]
    # nothing named, but the model changed: calibration.yaml carries the response the findings were judged
    # in (before: the first order as given, which predicted the windows worse than the model diagnosed)
    cal = yaml.safe_load((root / "diag" / "calibration.yaml").read_text())
    given = yaml.safe_load((root / "cal" / "calibration.yaml").read_text())
    assert given["actuator_response"]["response"]["kind"] == "first_order"
    assert cal["actuator_response"]["response"]["kind"] == "second_order"
    assert cal["actuator_response"]["why"].endswith("the response chosen again by platkit diagnose: second order at "
                                                    "every actuator (diagnosis.json, rounds)")
    assert "calibration.yaml carries it" in response["text"]


def test_the_second_order_starts_at_the_first_orders_lag():
    """Each first-order actuator's time constant halved, damping 1: the same lag at low frequency
    (2 zeta tau); a second-order actuator's own values and the clock's shift as they were; a response
    already second order everywhere is not tried again."""
    names = [f"L{k}" for k in range(1, 7)]
    T, U = np.arange(5) * 0.05, np.zeros((5, 6))
    proj, sample_t = sparse.eye(5, format="csr"), np.arange(5) * 0.05
    first = ResponseModel("second_order", "step", 6, first=(0, 1, 2, 3))  # L5, L6 second order already
    theta = theta_by_name(first, names, {"shift_s": 0.012, **{f"tau_s.{c}": 0.1 + 0.01 * k for k, c in enumerate(names)},
                                         "damping.L5": 1.3, "damping.L6": 0.9})
    term = LocalResponseTerm(first, T, U, names, theta, np.full(len(theta), 1e-4), None, proj, sample_t)
    freer = second_order_response(term, names)
    assert freer is not None and freer.model.kind == "second_order" and not freer.model.first
    old, new = first.split(theta), freer.model.split(freer.initial)
    lag_old = np.where(np.isnan(old["damping"]), old["tau_s"], 2 * old["damping"] * old["tau_s"])
    assert np.allclose(2 * new["damping"] * new["tau_s"], lag_old)
    assert np.allclose(new["damping"][4:], [1.3, 0.9]) and np.allclose(new["tau_s"][4:], old["tau_s"][4:])
    assert freer.initial[0] == 0.012
    assert second_order_response(freer, names) is None
