"""Every installed stand passes the conformance suite."""
import pytest

from platkit import get_platform, list_platforms
from platkit.testing import check_platform

BUILT_IN = ["stewart", "psvr", "rotary", "urdf"]


def test_built_in_stands_are_installed():
    missing = [n for n in BUILT_IN if n not in list_platforms()]
    assert not missing, f"built-in stands not registered: {missing}"


@pytest.mark.parametrize("name", BUILT_IN)
def test_conformance(name):
    report = check_platform(get_platform(name))
    assert report["round_trips"] > 0
