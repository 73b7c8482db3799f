"""platkit batch on a local Dask cluster of 2 worker processes (one for the whole module): the
same results as the single verbs one by one (calibrate in the batch's parameterisation, diagnose,
orient), a re-run that skips what is done and redoes what changed, a failed session that stops
nothing, a worker killed in the middle, a task past its time limit, dask missing; and the proof
benchmarks' runner (tests/batch_cases.py): the same rows on the engine as in a loop, written
as they finish, a re-run that skips the cases its file holds."""
from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from batch_cases import hears_ctrl_c, run_cases

from platkit.batch import engine
from platkit.batch.store import find_sessions, match_sessions
from platkit.cli import main
from platkit.commands.batch import default_options, run_verb
from platkit.errors import BadInput
from platkit.simulate import simulate_session

pytest.importorskip("dask.distributed", reason="platkit[batch] (dask.distributed) is part of the dev extra")

N_SESSIONS = 2


@pytest.fixture(scope="module")
def client():
    with engine.cluster(workers=2) as c:
        yield c


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """N_SESSIONS simulated rotary sessions (settled poses) and each one's single-verb calibration."""
    root = tmp_path_factory.mktemp("fleet")
    singles = {}
    for i in range(N_SESSIONS):
        folder = simulate_session("rotary", root / "fleet" / f"unit{i + 1}", seed=10 + i, n_poses=20, poses_only=True)
        out = root / "single" / f"unit{i + 1}"
        # compared on calibration.yaml and report.json alone (same_as_single): no report.html
        assert main(["calibrate", str(folder), "--out", str(out), "--quiet", "--no-report"]) == 0
        singles[f"unit{i + 1}"] = out
    return root, singles


def untimed(obj):
    """``obj`` without its ``time_s`` entries (how long a step took differs from run to run)."""
    if isinstance(obj, dict):
        return {k: untimed(v) for k, v in obj.items() if k != "time_s"}
    if isinstance(obj, list):
        return [untimed(v) for v in obj]
    return obj


def same_as_single(batch_session: Path, single: Path) -> None:
    """calibration.yaml and report.json identical to the single verb's, but for the times taken."""
    for name, read in (("calibration.yaml", yaml.safe_load), ("report.json", json.loads)):
        a = read((batch_session / name).read_text())
        b = read((single / name).read_text())
        assert untimed(a) == untimed(b), name


def test_batch_equals_single_verbs_then_rerun_skips(fleet, client, capsys):
    root, singles = fleet
    out = root / "batch"
    argv = ["batch", "calibrate", str(root / "fleet" / "*"), "--out", str(out), "--scheduler", client.scheduler.address]
    assert main(argv) == 0
    # one parameterisation: the groups held-out selection chose in any session, less the stand's gauge
    param = json.loads((out / "parameterisation.json").read_text())
    assert param["decided_by"].startswith("the union of the groups held-out selection chose")
    assert json.loads((out / "selection.json").read_text()).keys() == singles.keys()
    for name in singles:  # what platkit calibrate gives with that free list
        single = root / "single_free" / name
        assert main(["calibrate", str(root / "fleet" / name), "--free", ",".join(param["free"]) or "none", "--out",
                     str(single), "--quiet", "--no-report"]) == 0
        same_as_single(out / "sessions" / name, single)
    summary = json.loads((out / "summary.json").read_text())
    assert [r["session"] for r in summary["sessions"]] == sorted(singles)
    assert summary["counts"] == {"ok": N_SESSIONS, "failed": 0, "missing": 0}
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 1 + N_SESSIONS and all(",ok," in r for r in rows[1:])
    assert "<img" in (out / "summary.html").read_text()
    capsys.readouterr()
    before = {n: (out / "sessions" / n / "task.json").stat().st_mtime_ns for n in singles}
    assert main(argv) == 0
    said = capsys.readouterr()
    assert f"{N_SESSIONS} done before with these inputs and options, 0 to run" in said.err
    assert f"({N_SESSIONS} from before)" in said.out
    assert {n: (out / "sessions" / n / "task.json").stat().st_mtime_ns for n in singles} == before
    # other options in the same folder would mix two settings: refused
    assert main(argv + ["--folds", "3"]) == 2
    assert "other options" in capsys.readouterr().err


def test_a_rerun_redoes_the_session_whose_file_changed_alone_and_redo_redoes_all(tmp_path, client, capsys):
    for i in (1, 2, 3):
        simulate_session("rotary", tmp_path / "fleet" / f"u{i}", seed=30 + i, n_poses=12, poses_only=True)
    out = tmp_path / "out"
    argv = ["batch", "calibrate", str(tmp_path / "fleet" / "*"), "--free", "origin", "--no-report", "--out", str(out),
            "--scheduler", client.scheduler.address]
    assert main(argv) == 0
    stamp = {n: (out / "sessions" / n / "task.json").stat().st_mtime_ns for n in ("u1", "u2", "u3")}
    capsys.readouterr()
    yml = tmp_path / "fleet" / "u2" / "session.yaml"
    yml.write_text(yml.read_text() + "notes: re-exported\n")
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert "(2 from before, 1 run: 1 its files changed)" in said
    now = {n: (out / "sessions" / n / "task.json").stat().st_mtime_ns for n in ("u1", "u2", "u3")}
    assert [n for n in now if now[n] != stamp[n]] == ["u2"]
    assert json.loads((out / "sessions" / "u2" / "task.json").read_text())["ran_because"] == "its files changed"
    assert not [p for p in (out / "sessions").iterdir() if p.name.startswith(".")]  # no partial folder left
    assert main(argv + ["--redo"]) == 0
    assert "(0 from before, 3 run: 3 --redo)" in capsys.readouterr().out


def test_a_task_past_its_time_limit_is_stopped_and_the_worker_goes_on(client):
    def slow(x):
        deadline = time.monotonic() + (30 if x == 1 else 0.01)
        while time.monotonic() < deadline:  # Python steps: the limit takes effect at once
            time.sleep(0.001)
        return x

    outcomes = {o.key: o for o in engine.run_tasks(client, slow, [engine.Task(f"t{x}", (x,)) for x in (0, 1, 2)],
                                                   timeout=1.0)}
    assert outcomes["t0"].ok and outcomes["t2"].ok
    assert not outcomes["t1"].ok and outcomes["t1"].kind == "timed out" and outcomes["t1"].seconds < 10
    assert engine.run_tasks(client, slow, [engine.Task("again", (0,))])[0].ok


def test_a_task_stopped_inside_an_import_leaves_the_worker_no_half_package(tmp_path, monkeypatch):
    """The limit may fall while a task imports a package (matplotlib, the first report on a worker):
    the package's submodules imported so far must not outlive it, or the next task on the worker
    imports the package again over them and fails on the stale half (matplotlib: "module
    'matplotlib' has no attribute 'get_data_path'")."""
    package = tmp_path / "halfpkg"
    package.mkdir()
    (package / "__init__.py").write_text("import os, time\nfrom halfpkg import part\n"
                                         "while os.environ.get('HALFPKG_WAIT'):\n    time.sleep(0.001)\nanswer = 42\n")
    (package / "part.py").write_text("import halfpkg\n\n\ndef answer():\n    return halfpkg.answer\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("HALFPKG_WAIT", "1")

    def use():
        import halfpkg.part
        return halfpkg.part.answer()

    try:
        assert engine.guarded(use, timeout=0.3)["kind"] == "timed out"
        monkeypatch.delenv("HALFPKG_WAIT")
        again = engine.guarded(use)
        assert again["ok"] and again["value"] == 42, again
    finally:
        for name in [n for n in sys.modules if n == "halfpkg" or n.startswith("halfpkg.")]:
            del sys.modules[name]


def test_workers_are_capped_at_the_cores_and_said():
    cores = engine.default_workers()
    assert engine.capped_workers(None) == (cores, "")
    assert engine.capped_workers(1) == (1, "")
    n, said = engine.capped_workers(cores + 5)
    assert n == cores and said == f"--workers {cores + 5}: this process may use {cores} cores; running {cores} workers"
    with pytest.raises(BadInput, match="--workers 0"):
        engine.capped_workers(0)


def test_failed_session_is_reported_and_the_others_stand(fleet, client, capsys):
    root, singles = fleet
    broken = root / "fleet" / "unit9"
    broken.mkdir()
    (broken / "session.yaml").write_text(yaml.safe_dump({"platform": "rotary", "units": {"length": "cm"}}))
    try:
        out = root / "batch"  # the folder of the test above: its sessions are done, only unit9 runs
        code = main(["batch", "calibrate", str(root / "fleet" / "unit*"), "--out", str(out), "--scheduler",
                     client.scheduler.address])
        assert code == 1
        err = capsys.readouterr().err
        assert "unit9" in err and "units.length" in err
        failure = json.loads((out / "failed" / "unit9.json").read_text())
        assert not failure["ok"] and failure["kind"] == "bad input"
        assert not (out / "sessions" / "unit9").exists()
        for name in singles:  # untouched: as the test above left them
            same_as_single(out / "sessions" / name, root / "single_free" / name)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["counts"] == {"ok": N_SESSIONS, "failed": 1, "missing": 0}
    finally:
        (broken / "session.yaml").unlink()
        broken.rmdir()


def test_a_worker_killed_in_the_middle_still_gives_every_result_once(fleet, client):
    root, singles = fleet
    sessions = find_sessions(str(root / "fleet" / "*"))
    pids = client.run(os.getpid)  # worker address -> pid
    killed: list[tuple[str, tuple]] = []

    def kill_one_busy_worker():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            busy = {w: keys for w, keys in client.processing().items() if keys}
            if busy:
                worker, keys = next(iter(busy.items()))
                time.sleep(0.15)  # inside the task (a calibration here takes 0.5 s or more), not before it
                os.kill(pids[worker], signal.SIGKILL)
                killed.append((worker, keys))
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one_busy_worker)
    killer.start()
    options = default_options("calibrate")
    outcomes = engine.run_tasks(client, run_verb, [engine.Task(r.name, ("calibrate", options, str(r.path), r.name))
                                                   for r in sessions])
    killer.join()
    assert killed, "no worker was busy to kill"
    victim = f":{pids[killed[0][0]]}"
    # the kill hit a task in the middle: none came back from the killed process (it ran again on another)
    assert not [o.key for o in outcomes if o.worker.endswith(victim)]
    assert sorted(o.key for o in outcomes) == sorted(singles)  # every session, once
    assert all(o.ok for o in outcomes), [o.error for o in outcomes if not o.ok]
    for o in outcomes:
        out = root / "killed" / o.key
        out.mkdir(parents=True)
        for rel, data in o.value["files"].items():
            (out / rel).write_bytes(data)
        same_as_single(out, singles[o.key])
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it, for the tests after this one


def test_without_dask_batch_says_how_to_install(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(engine, "Client", None)
    assert main(["batch", "calibrate", str(tmp_path / "*"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "platkit[batch]"' in err[0]


def test_pattern_matching_nothing_is_bad_input(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["batch", "calibrate", str(tmp_path / "*"), "--out", str(tmp_path / "out")]) == 2
    assert "no session folder" in capsys.readouterr().err


def test_bad_options_are_bad_input_before_any_work(tmp_path, monkeypatch, capsys):
    simulate_session("rotary", tmp_path / "fleet" / "a", seed=1, n_poses=10, poses_only=True)
    out = tmp_path / "out"
    pattern = str(tmp_path / "fleet" / "*")
    assert main(["batch", "diagnose", pattern, "--calibration", "cal/{nam}/calibration.yaml", "--out", str(out)]) == 2
    assert "{name}, {folder} or {session}" in capsys.readouterr().err
    monkeypatch.setenv(engine.SCHEDULER_ENV, "tcp://127.0.0.1:1")
    assert main(["batch", "calibrate", pattern, "--workers", "2", "--out", str(out)]) == 2
    assert "--workers applies to the embedded cluster" in capsys.readouterr().err
    assert main(["batch", "calibrate", pattern, "--workers", "0", "--out", str(out)]) == 2
    assert not out.exists()


def test_folders_without_session_yaml_are_counted_not_dropped_silently(tmp_path):
    for name in ("month9", "month10", "notes"):
        (tmp_path / name).mkdir()
    for name in ("month9", "month10"):
        (tmp_path / name / "session.yaml").write_text("platform: rotary\n")
    refs, skipped = match_sessions(str(tmp_path / "*"))
    assert [r.name for r in refs] == ["month9", "month10"]  # natural order
    assert skipped == [tmp_path / "notes"]


def same_files(batch_session: Path, single: Path) -> None:
    """Every file the single verb wrote is in the batch's session folder, the same: JSON but for
    the times taken, HTML by name only (it holds the plots' bytes), the rest byte for byte."""
    names = sorted(str(p.relative_to(single)) for p in single.rglob("*") if p.is_file())
    assert names and all((batch_session / n).is_file() for n in names), names
    for n in names:
        a, b = batch_session / n, single / n
        if n.endswith(".json"):
            assert untimed(json.loads(a.read_text())) == untimed(json.loads(b.read_text())), n
        elif not n.endswith(".html"):
            assert a.read_bytes() == b.read_bytes(), n


def test_batch_diagnose_equals_single_verbs(fleet, client):
    """Each session diagnosed from its own calibration ({name} in the path), with the verb's own
    options passed through, gives what platkit diagnose gives it."""
    root, singles = fleet
    names = sorted(singles)[:2]
    options = ["--folds", "3", "--max-effects", "1"]
    for name in names:
        assert main(["diagnose", str(root / "fleet" / name), "--calibration", str(singles[name] / "calibration.yaml"),
                     "--out", str(root / "diag_single" / name), "--quiet", *options]) == 0
    out = root / "diag_batch"
    assert main(["batch", "diagnose", str(root / "fleet" / "unit[12]"), "--calibration",
                 str(root / "single" / "{name}" / "calibration.yaml"), "--out", str(out), "--quiet",
                 "--scheduler", client.scheduler.address, *options]) == 0
    for name in names:
        same_files(out / "sessions" / name, root / "diag_single" / name)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"ok": 2, "failed": 0, "missing": 0}


def imu_session(folder: Path, seed: int) -> Path:
    """An IMU-only session (platform: null), 20 s at 100 Hz, with its true orientation."""
    from platkit.geometry import quat_from_rpy
    from platkit.inertial.simulate import imu_from_motion
    from platkit.io.imu import write_imu_csv

    t = np.arange(0, 20, 0.01)
    on = t > 5
    q = quat_from_rpy(0.2 * np.sin(0.9 * t) * on, 0.15 * np.sin(0.7 * t) * on, 0.3 * t * on)
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=[0.01, 0.0, -0.01, 0, 0, 0], noise=[0.002, 0.02],
                          rng=np.random.default_rng(seed))
    folder.mkdir(parents=True)
    (folder / "session.yaml").write_text("platform: null\nunits: {length: m, time: s}\nimu: {rate_hz: 100}\n")
    write_imu_csv(folder / "imu.csv", t, sim["gyr"], sim["acc"])
    (folder / "truth_orientation.csv").write_text(
        "t,qw,qx,qy,qz\n" + "\n".join(f"{ti:.6f},{a:.10f},{b:.10f},{c:.10f},{d:.10f}" for ti, (a, b, c, d) in zip(t, q))
        + "\n")
    return folder


def test_batch_orient_equals_single_verbs(tmp_path, client):
    for i in (1, 2):
        session = imu_session(tmp_path / "imu" / f"rig{i}", seed=i)
        assert main(["orient", str(session), "--out", str(tmp_path / "single" / f"rig{i}")]) == 0
    out = tmp_path / "batch"
    assert main(["batch", "orient", str(tmp_path / "imu" / "*"), "--out", str(out), "--quiet",
                 "--scheduler", client.scheduler.address]) == 0
    for i in (1, 2):
        same_files(out / "sessions" / f"rig{i}", tmp_path / "single" / f"rig{i}")
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 3 and all(",ok," in r for r in rows[1:])


def test_proof_cases_on_the_engine_equal_the_loop_and_a_rerun_skips_them(tmp_path, client):
    def square(case):  # a local function: sent to the workers by value
        if case["x"] == 3:
            raise RuntimeError("three is refused")
        return {**case, "y": float(np.sqrt(case["x"]))}

    def failed(case, error, seconds):
        return {**case, "error": error}

    cases = [{"x": x, "effects": [("backlash", "clear")]} for x in range(6)]
    serial = run_cases(square, cases, serial=True, json_path=tmp_path / "serial.jsonl", failed_row=failed)
    on_engine = run_cases(square, cases, scheduler=client.scheduler.address, json_path=tmp_path / "engine.jsonl",
                          failed_row=failed)
    # in the order of the cases, whatever order they finished in; a function sent by value (this local one, or
    # a benchmark script's) names its file <dynamic-code> in the line of an error it raised on a worker
    assert serial[3]["error"] == on_engine[3]["error"].replace("<dynamic-code>", "test_batch.py")
    assert serial[3]["error"].startswith("RuntimeError: three is refused (at test_batch.py:")
    assert serial[:3] + serial[4:] == on_engine[:3] + on_engine[4:] and len(serial) == 6
    lines = (tmp_path / "engine.jsonl").read_text().splitlines()
    assert sorted(line.replace("<dynamic-code>", "test_batch.py") for line in lines) == sorted(
        (tmp_path / "serial.jsonl").read_text().splitlines()) and len(lines) == 6

    def never(case):
        raise AssertionError("a case the file holds ran again")

    # a re-run finds every case in the file (tuples in the cases, lists in the file) and runs none
    assert run_cases(never, cases, scheduler=client.scheduler.address, json_path=tmp_path / "engine.jsonl",
                     failed_row=failed) == sorted(map(json.loads, lines), key=lambda r: r["x"])
    # two lines lost: only those two cases run again, appended
    (tmp_path / "engine.jsonl").write_text("\n".join(lines[2:]) + "\n")
    again = run_cases(square, cases, scheduler=client.scheduler.address, json_path=tmp_path / "engine.jsonl",
                      failed_row=failed)
    assert [r["x"] for r in again] == list(range(6))
    assert (tmp_path / "engine.jsonl").read_text().splitlines()[:4] == lines[2:]
    assert len((tmp_path / "engine.jsonl").read_text().splitlines()) == 6
    with pytest.raises(BadInput, match="--jobs 0: use 1 or more"):
        run_cases(square, cases, jobs=0, failed_row=failed)
    with pytest.raises(BadInput, match="--jobs applies to the embedded cluster"):
        run_cases(square, cases, jobs=2, scheduler=client.scheduler.address, failed_row=failed)
    (tmp_path / "bad.jsonl").write_text('{"x": 0}\nnot json\n')
    with pytest.raises(BadInput, match="bad.jsonl, line 2"):
        run_cases(square, cases, serial=True, json_path=tmp_path / "bad.jsonl", failed_row=failed)


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_an_interrupted_batch_ends_in_one_line_and_leaves_nothing(tmp_path, how):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) or SIGTERM to platkit
    while a session runs: one line, exit 130, the workers gone, no scratch folder, no partial output."""
    import subprocess
    import sys

    for i in (1, 2):
        simulate_session("rotary", tmp_path / "fleet" / f"u{i}", seed=50 + i, n_poses=12, poses_only=True)
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "platkit.cli", "batch", "calibrate", str(tmp_path / "fleet" / "*"),
                             "--free", "origin", "--workers", "1", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=hears_ctrl_c,
                            env={**os.environ, "TMPDIR": str(scratch)})
    try:
        deadline = time.monotonic() + 180
        while not list(scratch.glob("platkit-batch-*/platkit-batch-task-*")):  # a session is running
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
        else:
            os.kill(proc.pid, signal.SIGTERM)
        said, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "platkit: interrupted" and "Traceback" not in err, err
    assert not list(scratch.glob("platkit-batch-*"))
    assert not (out / "sessions").exists() or not [p for p in (out / "sessions").iterdir() if p.name.startswith(".")]
    deadline = time.monotonic() + 30
    while True:  # no worker of its cluster outlives it (a busy one is stopped within seconds)
        left = subprocess.run(["ps", "-o", "pid=,args=", "-g", str(proc.pid)], capture_output=True, text=True).stdout
        if not left.strip() or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert left.strip() == ""


def test_the_dashboard_without_bokeh_is_one_line(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "bokeh", None)  # as if not installed
    with pytest.raises(BadInput, match=r'--dashboard needs bokeh, which is not installed: pip install "bokeh>=3.1"'):
        with engine.cluster(workers=1, dashboard=True):
            pass
    with pytest.raises(BadInput, match="--dashboard applies to the embedded cluster"):
        with engine.cluster(scheduler="tcp://127.0.0.1:1", dashboard=True):
            pass
