"""The compiled Newton solver behind PlatformModel.forward: generic, built per stand.

The stand's residual and its Jacobian are generated with CasADi's code generator, a Newton
driver that knows no stand is appended (newton_driver.c, package data), and the result is
compiled once with the system C compiler into a cache directory (``$PLATKIT_CACHE_DIR``, default
``~/.cache/platkit``) keyed by a hash of the source (:func:`compiled_library`, the one
compile-and-cache of platkit's native code; :func:`cache_dir`, platkit/io/cache.py);
``PLATKIT_COMPILE=0`` switches it off. Loaded through ctypes.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import sys
import threading
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path

import casadi as ca

from platkit.io.cache import c_compiler, cache_dir
from platkit.model import PlatformSpec

__all__ = ["c_source", "compiled_library", "library_path", "native_for", "newton_functions", "NativeNewton", "CONVERGED", "MAX_ITERATIONS", "SINGULAR", "NOT_FINITE"]

#: status codes of the Newton driver (C and numpy alike)
CONVERGED, MAX_ITERATIONS, SINGULAR, NOT_FINITE = 0, 1, 2, 3

#: compiler flags of the Newton solver
NEWTON_FLAGS = ("-O2", "-fPIC", "-shared")


def c_source(package: str, name: str) -> str:
    """The text of the C source file ``name`` shipped in ``package`` (package data: setup.py's
    package_data lists ``*.c``), found with importlib.resources as from a wheel."""
    return resources.files(package).joinpath(name).read_text(encoding="utf-8")


def library_path(source: str, name: str, flags: Sequence[str], cc: str, salt: str = "") -> Path:
    """Where :func:`compiled_library` keeps the library of ``source`` (or of the source a text
    determines): ``<name>_<key>.so`` in the cache folder (:func:`cache_dir`), the key a hash of that
    text, the compiler, the flags, the platform and ``salt`` (what else the library depends on,
    e.g. a code generator's version)."""
    key = hashlib.sha256((source + cc + " ".join(flags) + sys.platform + salt).encode()).hexdigest()[:24]
    return cache_dir() / f"{name}_{key}.so"


def compiled_library(source: str | Callable[[], str], name: str, flags: Sequence[str], *, cc: str | None = None,
                     salt: str = "", compile_now: bool = True, timeout: float = 600,
                     key: str | None = None) -> Path | str:
    """The shared library compiled from the C ``source``: from the cache folder
    (:func:`library_path`), else compiled there with the C compiler ``cc`` (default: the system
    one, :func:`platkit.io.cache.c_compiler`) and ``flags`` (and ``-lm``), atomically: other
    processes see the whole library or none. Returns its path, or why there is none: no compiler
    (or ``PLATKIT_COMPILE=0``), not in the cache and ``compile_now`` false, or the compiler
    failed (its last line). ``key``: a text that determines the source (with ``salt``), named by
    instead of the source, which may then be a function that writes it, called on a cache miss
    only. subprocess and tempfile are imported on a cache miss only, not by every start-up that
    loads a cached library."""
    cc = c_compiler() if cc is None else cc
    if cc is None:
        return "no C compiler (or PLATKIT_COMPILE=0)"
    named_by = source if key is None else key
    if not isinstance(named_by, str):
        raise TypeError("compiled_library: a source given as a function needs a key")
    lib = library_path(named_by, name, flags, cc, salt)
    if lib.is_file():
        return lib
    if not compile_now:
        return f"{lib.name} is not compiled yet"
    if not isinstance(source, str):
        source = source()
    import subprocess
    import tempfile

    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=lib.parent, prefix=".build-") as tmp:
            src = Path(tmp) / f"platkit_{name}.c"
            src.write_text(source)
            out = Path(tmp) / lib.name
            proc = subprocess.run([cc, *flags, "-o", str(out), str(src), "-lm"], capture_output=True, text=True,
                                  timeout=timeout)
            if proc.returncode != 0:
                return f"the C compiler failed on {name} ({(proc.stderr.strip().splitlines() or ['?'])[-1]})"
            os.replace(out, lib)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"compiling {name} failed ({exc.__class__.__name__}: {exc})"
    return lib


_native_lock = threading.Lock()
_native_by_functions: dict = {}  # id-key -> (functions kept alive, NativeNewton or failure reason)
_native_by_hash: dict = {}


_find_compiler = c_compiler  # the one lookup (platkit.io.cache); a name here that tests may patch


class NativeNewton:
    """ctypes handle on a compiled Newton solver for one stand's (residual, pose, branch)."""

    def __init__(self, lib_path: Path, n_u: int, n_p: int, n_g: int):
        self.path = lib_path
        self.lib = ctypes.CDLL(str(lib_path))
        self.n_out = n_p + 7 + n_g + 4
        self.single = self.lib.pk_newton
        self.single.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double, ctypes.c_int, ctypes.c_void_p]
        self.single.restype = None
        self.checked = self.lib.pk_newton_checked
        self.checked.argtypes = [ctypes.c_void_p] * 5 + [ctypes.c_double, ctypes.c_int, ctypes.c_void_p]
        self.checked.restype = ctypes.c_int
        self.batch = self.lib.pk_newton_batch
        self.batch.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                               ctypes.c_double, ctypes.c_int, ctypes.c_void_p]
        self.batch.restype = None


def newton_functions(spec: PlatformSpec) -> tuple[ca.Function, ca.Function, int]:
    """(rj, post, n_g): rj(u, td, p) -> (r, dense J_p); post(u, td, p) -> (q, X, g). Where the
    stand declares its rows' plausible misfit, r is row i over its plausible misfit (the rows
    the least-squares pose weighs)."""
    u = ca.SX.sym("u", spec.n_u)
    td = ca.SX.sym("td", spec.n_td)
    p = ca.SX.sym("p", spec.n_p)
    q, X = spec.pose(p)
    r = spec.residual(u, td, q, X)
    plausible = spec.plausible_misfit()
    if plausible is not None:  # least squares weighted by the rows' plausible misfit
        r = r / ca.DM(plausible)
    rj = ca.Function("pk_rj", [u, td, p], [r, ca.densify(ca.jacobian(r, p))], ["u", "td", "p"], ["r", "J"])
    if spec.branch is not None:
        g = spec.branch(u, td, q, X)
    else:
        g = ca.SX(0, 1)
    post = ca.Function("pk_post", [u, td, p], [q, X, ca.densify(g)], ["u", "td", "p"], ["q", "X", "g"])
    return rj, post, int(g.shape[0])


def _build_native(spec: PlatformSpec, rj: ca.Function, post: ca.Function, n_g: int):
    """Compile (or find in the cache) the C Newton solver; return NativeNewton or a reason string."""
    cc = _find_compiler()
    if cc is None:
        return "no C compiler (or PLATKIT_COMPILE=0)"
    cg = ca.CodeGenerator("platkit_newton.c", {"with_header": False, "casadi_int": "int", "prefix": "pk_"})
    cg.add(rj)
    cg.add(post)
    n_r = rj.size_out(0)[0]
    defs = {
        "PK_NU": spec.n_u, "PK_NP": spec.n_p, "PK_NR": n_r, "PK_NG": n_g, "PK_NOUT": spec.n_p + 7 + n_g + 4,
        "PK_SZ_ARG_RJ": rj.sz_arg(), "PK_SZ_RES_RJ": rj.sz_res(), "PK_SZ_IW_RJ": rj.sz_iw(), "PK_SZ_W_RJ": rj.sz_w(),
        "PK_SZ_ARG_POST": post.sz_arg(), "PK_SZ_RES_POST": post.sz_res(), "PK_SZ_IW_POST": post.sz_iw(),
        "PK_SZ_W_POST": post.sz_w(),
    }
    # the Newton driver (newton_driver.c, package data beside this module) knows no stand
    source = (cg.dump() + "\n" + "".join(f"#define {k} {v}\n" for k, v in defs.items())
              + c_source("platkit", "newton_driver.c"))
    with _native_lock:
        lib = library_path(source, "newton", NEWTON_FLAGS, cc)
        if lib.name in _native_by_hash:
            return _native_by_hash[lib.name]
        built = compiled_library(source, "newton", NEWTON_FLAGS, cc=cc, timeout=300)
        if isinstance(built, str):
            return built
        try:
            native = NativeNewton(built, spec.n_u, spec.n_p, n_g)
        except OSError as exc:
            return f"compiling the solver failed ({exc.__class__.__name__}: {exc})"
        _native_by_hash[lib.name] = native
        return native


def native_for(spec: PlatformSpec, rj, post, n_g):
    plausible = spec.plausible_misfit()
    key = (id(spec.residual), id(spec.pose), id(spec.branch), spec.n_td,
           None if plausible is None else tuple(plausible.tolist()))
    hit = _native_by_functions.get(key)
    if hit is not None:
        return hit[1]
    native = _build_native(spec, rj, post, n_g)
    _native_by_functions[key] = ((spec.residual, spec.pose, spec.branch), native)
    return native
