"""BLAS threads while platkit computes (platkit._threads): a verb of the command line, the design
floor of a diagnosis, the estimators' blocks run on one BLAS thread unless the user chose otherwise
(PLATKIT_BLAS_THREADS; OPENBLAS_NUM_THREADS, OMP_NUM_THREADS and the like do not change it), and
the count each library had is back after.

Each test starts the libraries at 3 threads (threadpoolctl), so that a block that holds nothing
is told from one that holds one thread on any machine, a one-core one included."""
from __future__ import annotations

import ast
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (its own OpenBLAS, beside numpy's: both must be held)
from threadpoolctl import threadpool_info, threadpool_limits

import platkit.commands.fk as fk_command
from platkit import _threads
from platkit.cli import main
from platkit.diagnose import floor
from platkit.poses import PoseSet

START = 3  # the threads each library has before a block
THREAD_VARIABLES = (_threads.ENV, "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _blas_counts() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


@pytest.fixture
def env(monkeypatch):
    """No thread variable set, as on a machine where the user chose nothing; BLAS at START."""
    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    with threadpool_limits(limits=START, user_api="blas"):
        yield monkeypatch


def _counts_inside_a_verb(monkeypatch) -> tuple[int, list[int]]:
    """(exit status, BLAS thread counts) of `platkit fk` whose work is replaced by a probe."""
    seen: list[int] = []

    def probe(args):
        seen.extend(_blas_counts())
        return 0

    monkeypatch.setattr(fk_command, "run", probe)
    return main(["fk", "--platform", "stewart", "--u", "0.5,0.5,0.5,0.5,0.5,0.5"]), seen


def test_there_are_blas_libraries_to_hold():
    assert len(_blas_counts()) >= 1  # else every count below would be vacuous


def test_a_verb_runs_on_one_blas_thread_and_the_count_comes_back(env):
    rc, inside = _counts_inside_a_verb(env)
    assert rc == 0
    assert inside and set(inside) == {1}
    assert set(_blas_counts()) == {START}


def test_platkit_blas_threads_sets_the_count(env):
    env.setenv(_threads.ENV, "2")
    assert set(_counts_inside_a_verb(env)[1]) == {2}
    env.setenv(_threads.ENV, "0")  # 0: BLAS's own count, platkit holds nothing
    assert set(_counts_inside_a_verb(env)[1]) == {START}


@pytest.mark.parametrize("name", ["OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"])
def test_a_blas_variable_does_not_change_platkits_count(env, name):
    env.setenv(name, "3")
    assert set(_counts_inside_a_verb(env)[1]) == {1}
    env.setenv(_threads.ENV, "2")  # platkit's own variable does
    assert set(_counts_inside_a_verb(env)[1]) == {2}


def test_a_bad_count_is_bad_input_in_one_line(env, capsys):
    env.setenv(_threads.ENV, "two")
    rc, inside = _counts_inside_a_verb(env)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and not inside
    assert len(err) == 1 and err[0].startswith("platkit: error: PLATKIT_BLAS_THREADS: 'two'")


def test_the_design_floor_runs_on_one_blas_thread(env):
    rng = np.random.default_rng(3)
    N, M, P = 20, 3, 4
    poses = PoseSet("stewart", np.zeros((N, 6)), rng.normal(size=(N, M, 3)), [f"M{k}" for k in range(M)],
                    n_samples=np.full((N, M), 4.0), settling={"sigma_m": 1e-4})
    refit = (rng.normal(size=(N, M, 3, P)), np.ones((N, M)), np.ones((N, M)), 5)
    seen: list[int] = []
    pinv = np.linalg.pinv

    def probe(a, *args, **kwargs):
        seen.extend(_blas_counts())
        return pinv(a, *args, **kwargs)

    env.setattr(floor.np.linalg, "pinv", probe)
    assert floor.noise_floor(poses, P, refit) > 1e-4 * np.sqrt(3 * 0.25)  # the noise and the refit's error
    assert seen and set(seen) == {1}


def test_diagnose_called_as_a_library_runs_on_one_blas_thread(env):
    """platkit.diagnose.search.diagnose, called without the command line, holds BLAS itself."""
    from platkit.diagnose import search

    seen: list[int] = []

    class Stop(Exception):
        pass

    class Probe:
        def __init__(self, *args, **kwargs):
            seen.extend(_blas_counts())
            raise Stop  # the probe's end: nothing of the search runs

    env.setattr(search, "Search", Probe)
    with pytest.raises(Stop):
        search.diagnose(None, None)
    assert seen and set(seen) == {1}
    assert set(_blas_counts()) == {START}


def test_the_estimators_share_one_block():
    from platkit.calibrate import solve
    from platkit.settle import _fits

    assert solve.blas_threads is _threads.blas_threads
    assert _fits.blas_threads is _threads.blas_threads


def test_a_library_loaded_after_the_first_block_is_held_too():
    """numpy's OpenBLAS held, then scipy (its own OpenBLAS) imported: the next block holds both."""
    code = ("import numpy\nfrom threadpoolctl import threadpool_info, threadpool_limits\n"
            "from platkit._threads import blas_threads\n"
            "with blas_threads(1):\n    pass\n"
            "import scipy.linalg\n"
            "with threadpool_limits(3, user_api='blas'):\n"
            "    with blas_threads(1):\n"
            "        print(sorted(x['num_threads'] for x in threadpool_info() if x['user_api'] == 'blas'))\n")
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    counts = ast.literal_eval(out.strip())
    assert len(counts) >= 2 and set(counts) == {1}
