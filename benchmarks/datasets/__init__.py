"""Readers of the public data sets the benchmarks and golden tests use (not part of platkit: their
dependencies, e.g. h5py, are in the ``dev`` extra only)."""
