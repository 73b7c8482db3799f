import os

os.environ.setdefault("MPLBACKEND", "Agg")
import pytest


@pytest.fixture
def builtin_host():
    """A plugin host with platkit's built-in plugins only: no outside plugin installed on this
    machine (an entry point of the ``platkit`` group) can change what a test sees."""
    from platkit.plugins import PluginHost

    return PluginHost(builtins=True, entry_points=False)


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
