"""platkit plan --monte-carlo on a local Dask cluster of 2 worker processes: every plan scored on
the same true stands, each draw what the library's draw() gives in this process, a re-run that
skips the draws done, and the spread near the plan's linear prediction."""
from __future__ import annotations

import json

import numpy as np
import pytest
from batch_cases import hears_ctrl_c

from platkit.batch import engine
from platkit.batch.montecarlo import draw, draw_seed
from platkit.calibrate import plan as pl
from platkit.cli import main
from platkit.plugins import get_platform

pytest.importorskip("dask.distributed", reason="platkit[batch] (dask.distributed) is part of the dev extra")

N_DRAWS = 3


@pytest.fixture(scope="module")
def client():
    with engine.cluster(workers=2) as c:
        yield c


def test_monte_carlo_compares_plans_on_the_same_true_stands(tmp_path, client, capsys):
    small = tmp_path / "grid2.csv"
    assert main(["plan", "--platform", "rotary", "--grid", "2", "--out", str(small)]) == 0
    out = tmp_path / "grid4.csv"
    argv = ["plan", "--platform", "rotary", "--grid", "4", "--out", str(out), "--monte-carlo", str(N_DRAWS),
            "--compare", str(small), "--scheduler", client.scheduler.address]
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert "Monte Carlo, 3 true stands" in said and "grid2" in said
    report = json.loads(out.with_suffix(".json").read_text())
    mc = report["monte_carlo"]
    assert list(mc["plans"]) == ["grid4", "grid2"]
    seeds = [[d["seed"] for d in p["draws"]] for p in mc["plans"].values()]
    assert seeds[0] == seeds[1] == [draw_seed(0, d) for d in range(N_DRAWS)]
    grid4 = mc["plans"]["grid4"]
    assert grid4["n_draws"] == N_DRAWS and grid4["n_poses"] == report["n_poses"]
    # each draw is the library's draw(), whatever worker ran it
    spec = get_platform("rotary")
    markers = np.array(report["marker_layout_m"])
    first = draw("rotary", None, (), pl.grid_plan(spec, 4).controls, markers, draw_seed(0, 0), 0.1)
    assert grid4["draws"][0]["heldout_rms_mm"] == pytest.approx(first["heldout_rms_m"] * 1e3, rel=1e-9)
    # the linear prediction (per coordinate, so x sqrt(3) for the 3-D distance) is the right size
    predicted = report["plan"]["predicted_marker_rms_m"] * 1e3 * np.sqrt(3)
    assert 0.5 * predicted < grid4["heldout_rms_mm"]["median"] < 2.0 * predicted
    assert all(v["rms"] is None or np.isfinite(v["rms"]) for v in grid4["parameter_error"].values())
    # a re-run finds every draw done
    folder = tmp_path / "grid4.montecarlo" / "draws"
    stamps = sorted((p.name, p.stat().st_mtime_ns) for p in folder.iterdir())
    assert len(stamps) == 2 * N_DRAWS
    assert main(argv) == 0
    assert sorted((p.name, p.stat().st_mtime_ns) for p in folder.iterdir()) == stamps
    assert json.loads(out.with_suffix(".json").read_text())["monte_carlo"]["plans"] == mc["plans"]


def test_monte_carlo_options_are_checked_before_any_work(tmp_path, capsys):
    out = str(tmp_path / "p.csv")
    assert main(["plan", "--platform", "rotary", "--grid", "3", "--out", out, "--compare", "x.csv"]) == 2
    assert "--monte-carlo N" in capsys.readouterr().err
    assert main(["plan", "--platform", "rotary", "--grid", "3", "--out", out, "--monte-carlo", "1"]) == 2
    assert main(["plan", "--platform", "rotary", "--grid", "3", "--out", out, "--monte-carlo", "5",
                 "--compare", str(tmp_path / "missing.csv")]) == 2
    assert "not found" in capsys.readouterr().err
    assert not (tmp_path / "p.csv").exists()


def test_a_monte_carlo_interrupted_says_so_once(tmp_path):
    """Ctrl-C to the process group of `platkit plan --monte-carlo` (its workers ignore it; platkit
    stops them): 'interrupted' once, exit 130."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "g.csv"
    proc = subprocess.Popen([sys.executable, "-m", "platkit.cli", "plan", "--platform", "rotary", "--grid", "3", "--out",
                             str(out), "--monte-carlo", "2000", "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=hears_ctrl_c)
    try:
        deadline = time.monotonic() + 180
        draws = tmp_path / "g.montecarlo" / "draws"
        while not (draws.is_dir() and any(draws.iterdir())):  # draws are being written
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err.splitlines().count("platkit: interrupted") == 1 and "Traceback" not in err, err
    assert sum("interrupt" in line.replace(str(tmp_path), "").lower() for line in err.splitlines()) == 1, err
