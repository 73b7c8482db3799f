"""Work around single calibrations, on a Dask cluster: fleets (platkit batch), the history of one
stand, and Monte-Carlo evaluation of command plans (platkit plan --monte-carlo).

platkit.batch.engine runs whole tasks (a session, a draw) on dask.distributed, an optional
extra; the other modules read and write plain files and work without it.
"""
