"""Readers of the real data sets in ``shared/data/real/`` beside the checkout (TIAGo, BROAD), shared
by the golden tests and the benchmarks: ``from real_data.tiago import convert`` (tests/ is on the
path of every test through tests/conftest.py; a benchmark puts it there). Not platkit: a user's own
robot gets no special case in the library, and these readers' dependencies (h5py) are in the
``dev`` extra only."""
from pathlib import Path

#: shared/data/real beside the checkout, as CI lays it out (tests/conftest.py stops a run without it)
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"
