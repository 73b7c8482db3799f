import os
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")
import pytest

#: the real data the golden tests (and a few others) read: ``shared/`` beside the checkout, as CI lays it out
SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SHARED_DATA = SHARED / "data" / "real"


def needs_shared(path: Path) -> bool:
    """Whether a test module reads the shared real data (it names the ``shared`` folder or a
    dataset reader of tests/real_data)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError:
        return False
    return '"shared"' in text or "from real_data" in text or "/work/shared" in text


def _asked_files(config) -> list[Path]:
    """The test modules the run's arguments name (a file, or every test_*.py under a folder;
    ``file::test`` counts as its file), before any is collected or imported."""
    out: set[Path] = set()
    for arg in config.args:
        path = Path(config.invocation_params.dir, str(arg).split("::")[0])
        if path.is_dir():
            out.update(path.rglob("test_*.py"))
        elif path.suffix == ".py":
            out.add(path)
    return sorted(out)


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    """Without the shared real data, a run whose arguments name tests reading it stops before any
    test with one line that says what is missing and where it comes from (rather than failures
    and errors one by one, or tests skipped, which would pass where the data are broken). At the
    session's start, from the arguments: in a run split over processes (pytest-xdist) it is said
    once, by the process that starts the others, before any starts."""
    if SHARED_DATA.is_dir():
        return
    files = [f for f in _asked_files(session.config) if needs_shared(f)]
    if files:
        here = Path(__file__).resolve().parent
        names = ", ".join(f.resolve().relative_to(here).as_posix() for f in files[:3])
        more = f" and {len(files) - 3} more" if len(files) > 3 else ""
        raise pytest.UsageError(  # exit 4, the line alone
            f"the real data these tests read are missing: {SHARED_DATA} (TIAGo, BROAD) is not there; "
            f"{len(files)} test files need it ({names}{more}). It is the project's shared/ folder, laid "
            f"beside the checkout as CI has it: clone or link it there (ln -s /path/to/shared {SHARED})")


@pytest.fixture
def builtin_host():
    """A plugin host with platkit's built-in plugins only: no outside plugin installed on this
    machine (an entry point of the ``platkit`` group) can change what a test sees."""
    from platkit.plugins import PluginHost

    return PluginHost(builtins=True, entry_points=False)


@pytest.fixture
def proof_session(tmp_path, monkeypatch):
    """``make(stand, seed, effects)``: a session of the physical simulator in the protocol of the
    proof benchmark (benchmarks/diagnosis_proof_physical.py: 60 commands at random, coloured
    marker noise, every fifth command held out and cut from the stream: tests/proof_protocol.py),
    written to ``tmp_path/session``; returns (the session folder, the simulation). ``effects``:
    [(name, size)]; physics the library does not hold (tests/outside_plugins/outside_physics.py)
    is played by the simulator only, through a plugin host of its own, never seen by diagnosis."""
    from outside_plugins import library_with
    from outside_plugins.outside_physics import OUTSIDE_PHYSICS, OutsideEffect
    from proof_protocol import blank_held_out, held_out_rows

    from platkit.plugins import get_platform
    from platkit.simulate.physics import simulate_physics, write_physical_session

    def make(stand, seed, effects):
        outside = [OutsideEffect(name, OUTSIDE_PHYSICS[name]) for name, _ in effects if name in OUTSIDE_PHYSICS]
        # the outside physics through a plugin host of the simulation's own: diagnose never sees it
        sim = simulate_physics(get_platform(stand), seed=seed, n_poses=60, plan="random", effects=list(effects),
                               coloured=True, library=library_with(*outside))
        session = write_physical_session(sim, tmp_path / "session")
        blank_held_out(session, sim, held_out_rows(len(sim.commands)))
        return session, sim

    return make


@pytest.fixture
def calibrate_and_diagnose(tmp_path):
    """``run(session)``: `platkit calibrate` then `platkit diagnose` of that calibration, each
    through the command line into ``tmp_path`` (cal/, diag/), both asserted to exit 0; returns
    diagnosis.json as a dict."""
    import json

    from platkit.cli import main

    def run(session):
        assert main(["calibrate", str(session), "--out", str(tmp_path / "cal"), "--no-report", "--quiet"]) == 0
        assert main(["diagnose", str(session), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
                     "--out", str(tmp_path / "diag"), "--quiet"]) == 0
        return json.loads((tmp_path / "diag" / "diagnosis.json").read_text())

    return run
