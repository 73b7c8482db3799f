"""The observation function of a stand, built once in CasADi and evaluated over many poses.

For M points (markers, then rigid bodies' origins) and the unknowns of
:class:`platkit.calibrate.problem.CalibrationProblem`, the function gives each point's position
in the motion-capture frame (and, with rigid bodies, the mocap_from_link rotation), its exact
Jacobian in td, the transform and the points, and its Jacobian in the terms' offsets. A stand with
a closed-form ``forward`` is differentiated directly; otherwise the Newton solution is
differentiated by the implicit-function theorem inside the function. It is evaluated over poses
by CasADi maps on preallocated buffers, interpreted first and compiled to C once it has been
evaluated often enough (the policy below). Built once per (stand, point count, thread) and shared
by every problem of them (:func:`observation_for`).
"""
from __future__ import annotations

import threading

import casadi as ca
import numpy as np

from platkit.errors import BadInput
from platkit.geometry import ca_matrix_from_quat, ca_matrix_from_rotvec
from platkit.io.cache import c_compiler
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.native import compiled_library

#: poses per call of the observation map (building a map costs in proportion to its length)
CHUNK = 256
#: (id(stand), points, with bodies, thread, point links) -> (stand, ObservationFunctions, PlatformModel)
_BUILT: dict = {}


_compile_lock = threading.Lock()
#: pose evaluations of one function (in one process) after which its compiled library is looked
#: for in the cache (before the call that would pass the count: a session of 300 poses looks
#: before its first), and after which it is compiled there. Compiling costs about as much as
#: interpreting some 35,000 pose evaluations at -O1 (4.4 s for the TIAGo arm's 52,000 instructions,
#: 120 us a pose interpreted; 0.6 s for the stewart stand's 7,900), at -O2 (:data:`COMPILE_FLAGS`)
#: up to three times that, once per machine: a calibration
#: of 10,000 poses compiles at its first evaluation, a diagnosis of the 37 TIAGo postures
#: (1,700 evaluations) after a fifth of its refits, and every later run finds the library; a
#: test of 40 poses never waits for the compiler. The library is named by the function's
#: serialization (which, with CasADi's version, determines its C source); looking costs that
#: serialization, about as much as interpreting 200 poses (0.16-0.23 s for the Talos tree's
#: 82,000 instructions, 0.93 ms a pose interpreted; the C source's generation, written only to
#: compile, 0.41-0.50 s)
LOOK_AFTER, COMPILE_AFTER = 200, 10_000
#: compiler flags of every observation function: -O2, whose code gives the same numbers as -O1's
#: and the interpreter's bit for bit (no contraction, no reassociation), and evaluates faster: the
#: stewart stand's Jacobians 1.6x (22 against 36 ms for 10,000 poses), the Talos tree's 38,672
#: instructions by a sixth (2.34 against 2.76 ms for 300 poses, best of 30), for a compile about
#: twice as long once per machine (1.2 s instead of 0.7 s; the tree's 9.8 s instead of 4.8 s; the
#: TIAGo arm's 52,000 instructions 16 s instead of 4.9 s): every later run of the stand on that
#: machine finds the library and gains at each evaluation
COMPILE_FLAGS = ["-O2", "-ffp-contract=off", "-fPIC", "-shared"]


_compiler = c_compiler  # the one lookup (platkit.io.cache); a name here that tests may patch


def compile_flags(f: ca.Function) -> list[str]:
    """The compiler flags of ``f``: :data:`COMPILE_FLAGS`, whatever its size."""
    return COMPILE_FLAGS


def _compiled(f: ca.Function, compile_now: bool) -> ca.Function | None:
    """``f`` compiled to C and loaded as an external function: from the cache, or, with
    ``compile_now``, compiled with the system compiler and kept there
    (:func:`platkit.native.compiled_library`, named by a hash of its serialization, the compiler,
    the flags and CasADi's version; its C source generated only to compile it). None where there
    is no library and ``compile_now`` is false, without a compiler, with PLATKIT_COMPILE=0, or
    when compiling fails (the caller keeps CasADi's interpreter). The same operations, no
    floating-point contraction: the interpreter's numbers to rounding (1e-15 m measured)."""
    cc = _compiler()
    if cc is None:
        return None

    def source() -> str:
        cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
        cg.add(f)
        return cg.dump()

    with _compile_lock:
        built = compiled_library(source, "observe", compile_flags(f), cc=cc, salt=ca.__version__,
                                 compile_now=compile_now, timeout=600, key=f.serialize())
        if isinstance(built, str):
            return None
        try:
            return ca.external(f.name(), str(built))
        except RuntimeError:
            return None


def _chunk_for(n: int) -> int:
    """Poses per map call for n poses: n split evenly over the fewest calls of at most CHUNK
    poses (n itself up to CHUNK; 300 poses two calls of 150), so that the last call pads at most
    one pose per call: a map evaluates its whole length, and 300 poses in calls of 256 evaluated
    512. A map of a few hundred poses is built in milliseconds, and the folds and refits of a
    session reuse a few."""
    n = max(1, n)
    calls = -(-n // CHUNK)
    return -(-n // calls)


class ObservationFunctions:
    """The CasADi observation functions of one stand and channel count and their maps.

    The outputs are transposed so that a map lays each pose's block out row-major (rows, cols):
    y, then J = [dy/dtd | dy/dw | dy/dt | dy/dm] in the unknowns' order of CalibrationProblem
    (without model terms or rigid bodies' rotations it is the problem's Jacobian as it is), then
    [dy/ddpose | dy/du] for the terms' offsets. Each function is interpreted by CasADi until it has
    been evaluated on LOOK_AFTER poses, then taken compiled from the cache if there, and
    compiled after COMPILE_AFTER poses (:func:`_compiled`). ``structure``: which entries of J are
    not structural zeros (:func:`structural_nonzeros`), or None."""

    def __init__(self, G: ca.Function, Yonly: ca.Function, shared: list[int], structure: np.ndarray | None = None):
        self.G, self.Yonly, self.shared = G, Yonly, shared
        self.structure = structure  # (rows, cols) bool of J; False: written 0 at every pose
        self._maps: dict = {}
        self._native: dict = {}  # with_jac -> compiled function, or None once compiling was tried
        self._evaluated = {True: 0, False: 0}
        self._looked = {True: False, False: False}

    def native(self, with_jac: bool, poses: int = 0) -> ca.Function:
        """The function behind the maps for a call of ``poses`` poses: compiled where the policy
        above has made it so."""
        f = self.G if with_jac else self.Yonly
        if with_jac in self._native:  # decided: compiled, or None where compiling failed
            got = self._native[with_jac]
            return f if got is None else got
        n = self._evaluated[with_jac] + poses
        if n >= COMPILE_AFTER:
            got = self._native[with_jac] = _compiled(f, compile_now=True)
            return f if got is None else got
        if n >= LOOK_AFTER and not self._looked[with_jac]:
            self._looked[with_jac] = True
            found = _compiled(f, compile_now=False)
            if found is not None:
                self._native[with_jac] = found
                return found
        return f

    def mapped(self, with_jac: bool, n: int):
        """(buffer, run, inputs, outputs, shapes, per-pose inputs, chunk) of the map for n poses."""
        f = self.native(with_jac, n)
        self._evaluated[with_jac] += n
        chunk = _chunk_for(n)
        key = (id(f), chunk)
        entry = self._maps.get(key)
        if entry is None:
            if len(self._maps) > 64:
                self._maps.clear()
            fmap = f.map(f"{f.name()}_{chunk}", "serial", chunk, self.shared, [])
            buf, run = fmap.buffer()
            ins = [np.zeros(fmap.nnz_in(i)) for i in range(fmap.n_in())]
            outs = [np.zeros(fmap.nnz_out(i)) for i in range(fmap.n_out())]
            for i, a in enumerate(ins):
                buf.set_arg(i, memoryview(a))
            for i, a in enumerate(outs):
                buf.set_res(i, memoryview(a))
            shapes = [(fmap.size_out(i)[1] // chunk, fmap.size_out(i)[0]) for i in range(fmap.n_out())]
            per_pose = [i for i in range(fmap.n_in()) if i not in self.shared]
            entry = self._maps[key] = (buf, run, ins, outs, shapes, per_pose, chunk, f)
        return entry

    def call(self, n: int, with_jac: bool, args: list[np.ndarray]) -> list[np.ndarray]:
        """Evaluate the observation function over n poses, CHUNK poses (fewer for a small n) per
        call of a CasADi map on preallocated buffers (a few maps per stand, whatever n: building
        a map costs time in proportion to its length).

        args: per-pose inputs as (n, size) C-ordered arrays, shared inputs (td, w, t, m) as 1-D
        arrays. Returns each output as an (n, rows, cols) array, row-major per pose.
        """
        buf, run, ins, outs, shapes, per_pose, chunk, _ = self.mapped(with_jac, n)
        res = [np.empty((n,) + sh) for sh in shapes]
        per = [np.ascontiguousarray(np.reshape(a, (n, -1)), dtype=float) if k in per_pose else np.ravel(a)
               for k, a in enumerate(args)]
        for k, a in enumerate(per):
            if k not in per_pose:
                ins[k][:] = a
        for start in range(0, n, chunk):
            stop = min(n, start + chunk)
            m = stop - start
            if m == chunk:  # the map reads and writes the arrays themselves: no copies
                for k in per_pose:
                    buf.set_arg(k, memoryview(per[k][start:stop].reshape(-1)))
                for i, r in enumerate(res):
                    buf.set_res(i, memoryview(r[start:stop].reshape(-1)))
                run()
                continue
            for k in per_pose:  # a short chunk: through the map's own buffers
                dst = ins[k].reshape(chunk, -1)
                dst[:m] = per[k][start:stop]
                dst[m:] = per[k][start]  # padded with the chunk's first pose: finite, and thrown away
                buf.set_arg(k, memoryview(ins[k]))
            for i, o in enumerate(outs):
                buf.set_res(i, memoryview(o))
            run()
            for o, r, sh in zip(outs, res, shapes):
                r[start:stop] = o.reshape((chunk,) + sh)[:m]
        return res


def _cross_columns(U, v):
    """Each column of the 3 x n CasADi matrix U crossed with the 3-vector v (3 x n)."""
    return ca.vertcat(U[1, :] * v[2] - U[2, :] * v[1], U[2, :] * v[0] - U[0, :] * v[2], U[0, :] * v[1] - U[1, :] * v[0])


def _motion_jacobian(qs, Xs, rows_links, z_sym, A, dpose, m, dm):
    """d y / d (td, u) of a closed-form pose: each link's motion under a change of (td, u)
    (``qs``, ``Xs``: each link's quaternion and position) taken once, its angular velocity
    from the quaternion's derivative (w = 2 vec(dq q*) / |q|^2, q of any norm), then each
    point's rows as A (dX + w x R (m + dm)) and each rotation's as (A w) x its columns.
    ``rows_links``: ('point', i, link) and ('rotation', link) in y's order; ``z_sym`` the symbols
    (td, u), A the mocap rotation, ``dpose``, ``m``, ``dm`` the pose offset's, markers' and marker
    offsets' symbols. The same derivative as CasADi's of every marker through the whole chain of
    transforms, to rounding, in fewer instructions (each link's motion differentiated once)."""
    Rd = ca_matrix_from_rotvec(dpose[3:6])
    frames: dict = {}

    def frame(k):
        if k not in frames:
            q, X = qs[k], Xs[k]
            R = ca.mtimes(Rd, ca_matrix_from_quat(q))
            Jq = ca.jacobian(q, z_sym)
            conj = ca.vertcat(-q[1], -q[2], -q[3])  # the vector part of q*
            om = (2.0 / ca.dot(q, q)) * (ca.mtimes(conj, Jq[0, :]) + q[0] * Jq[1:4, :] + _cross_columns(Jq[1:4, :], conj))
            frames[k] = (R, ca.mtimes(A, ca.jacobian(X, z_sym)), ca.mtimes(A, ca.mtimes(Rd, om)))
        return frames[k]

    rows = []
    for entry in rows_links:
        if entry[0] == "point":
            _, i, k = entry
            R, AJX, Aom = frame(k)
            rows.append(AJX + _cross_columns(Aom, ca.mtimes(A, ca.mtimes(R, m[3 * i:3 * i + 3] + dm[3 * i:3 * i + 3]))))
        else:  # a rotation's rows Q[i, j], Q = A R row by row: dQ[:, j] = (A w) x Q[:, j]
            R, _, Aom = frame(entry[1])
            Q = ca.mtimes(A, R)
            cols = [_cross_columns(Aom, Q[:, j]) for j in range(3)]
            rows += [cols[j][i, :] for i in range(3) for j in range(3)]
    return ca.vertcat(*rows)


def observation_functions(spec: PlatformSpec, M: int, with_bodies: bool,
                          point_links: tuple[int, ...] | None = None, n_bodies: int = 0) -> ObservationFunctions:
    """Build the observation function of ``spec`` for M points (markers, then bodies' origins).

    ``point_links`` (M,): on a tree, the tracked link each point rides on (the last ``n_bodies``
    are the bodies' origins; index in
    ``spec.tracked_links``; :attr:`PlatformSpec.link_poses` gives their poses); the terms' pose
    offsets act on each link's pose alike, and each body's orientation is read from its own
    link (9 numbers per body instead of one 3x3 for all)."""
    u = ca.SX.sym("u", spec.n_u)
    td = ca.SX.sym("td", spec.n_td)
    w = ca.SX.sym("w", 3)
    t = ca.SX.sym("t", 3)
    m = ca.SX.sym("m", 3 * M)
    dpose = ca.SX.sym("dpose", 6)
    dm = ca.SX.sym("dm", 3 * M)
    A = ca_matrix_from_rotvec(w)
    symbols = (ca.vertcat(td, u), A, dpose, m, dm)  # what _motion_jacobian differentiates and reads

    def observe(q, X):
        R = ca.mtimes(ca_matrix_from_rotvec(dpose[3:6]), ca_matrix_from_quat(q))
        pts = [ca.mtimes(A, X + dpose[0:3] + ca.mtimes(R, m[3 * i:3 * i + 3] + dm[3 * i:3 * i + 3])) + t
               for i in range(M)]
        if with_bodies:  # Q = mocap_from_moving rotation, row by row, for the bodies' orientations
            Q = ca.mtimes(A, R)
            pts += [Q[i, j] for i in range(3) for j in range(3)]
        return ca.vertcat(*pts)

    def observe_links(qs, Xs):
        Rs = [ca.mtimes(ca_matrix_from_rotvec(dpose[3:6]), ca_matrix_from_quat(q)) for q in qs]
        pts = []
        for i in range(M):
            k = point_links[i]
            pts.append(ca.mtimes(A, Xs[k] + dpose[0:3] + ca.mtimes(Rs[k], m[3 * i:3 * i + 3] + dm[3 * i:3 * i + 3])) + t)
        if with_bodies:  # each body's mocap_from_link rotation, row by row
            for k in point_links[M - n_bodies:]:
                Q = ca.mtimes(A, Rs[k])
                pts += [Q[i, j] for i in range(3) for j in range(3)]
        return ca.vertcat(*pts)

    def closed_form(name: str, y, Jz) -> ObservationFunctions:
        """The observation y(u, td, w, t, m, dpose, dm) of a closed-form pose: y, its Jacobian in
        (td, w, t, m) and in (dpose, u); ``Jz``: its Jacobian in (td, u) (:func:`_motion_jacobian`),
        the rest by CasADi's exact derivatives."""
        args = [u, td, w, t, m, dpose, dm]
        J = ca.horzcat(Jz[:, :spec.n_td], ca.jacobian(y, w), ca.jacobian(y, t), ca.jacobian(y, m))
        G = ca.Function(
            name, args,
            [y.T, ca.densify(J.T), ca.densify(ca.horzcat(ca.jacobian(y, dpose), Jz[:, spec.n_td:]).T)],
            ["u", "td", "w", "t", "m", "dpose", "dm"], ["y", "J", "J_offsets"])
        return ObservationFunctions(G, ca.Function(f"{name}_y", args, [y.T]), [1, 2, 3, 4], structural_nonzeros(J))

    if spec.forward is not None and point_links is not None:
        L = len(spec.tracked_links)
        q_all, X_all = spec.link_poses(u, td)
        qs, Xs = [q_all[4 * k:4 * k + 4] for k in range(L)], [X_all[3 * k:3 * k + 3] for k in range(L)]
        rows_links = [("point", i, point_links[i]) for i in range(M)]
        if with_bodies:
            rows_links += [("rotation", k) for k in point_links[M - n_bodies:]]
        return closed_form("observe_tree", observe_links(qs, Xs), _motion_jacobian(qs, Xs, rows_links, *symbols))
    if point_links is not None:
        raise BadInput(f"stand {spec.name!r}: markers on several links need a closed-form forward and link_poses")
    if spec.forward is not None:
        q, X = spec.forward(u, td)
        rows_links = [("point", i, 0) for i in range(M)] + ([("rotation", 0)] if with_bodies else [])
        return closed_form("observe_fwd", observe(q, X), _motion_jacobian([q], [X], rows_links, *symbols))
    # through the Newton solution p(u, td) of r(u, td, p) = 0: dp/d(td, u) = -F_p^+ [F_td F_u],
    # solved per pose inside the function (F_p^+ = F_p^-1, or (F_p^T F_p)^-1 F_p^T with more
    # residuals than pose coordinates)
    p = ca.SX.sym("p", spec.n_p)
    q, X = spec.pose(p)
    y = observe(q, X)
    r = spec.residual(u, td, q, X)
    F_p = ca.jacobian(r, p)
    F_rest = ca.horzcat(ca.jacobian(r, td), ca.jacobian(r, u))  # sparse: a leg's residual, its own parameters
    Y_p = ca.jacobian(y, p)
    if F_p.shape[0] == F_p.shape[1]:  # Y_p F_p^-1 first: fewer right-hand sides, then F_rest's sparsity
        Z = ca.solve(F_p.T, Y_p.T).T
    else:
        Z = ca.mtimes(ca.solve(ca.mtimes(F_p.T, F_p), Y_p.T).T, F_p.T)
    Y_rest = -ca.mtimes(Z, F_rest)
    J = ca.horzcat(Y_rest[:, :spec.n_td], ca.jacobian(y, w), ca.jacobian(y, t), ca.jacobian(y, m))
    G = ca.Function(
        "observe_ift", [u, td, p, w, t, m, dpose, dm],
        [y.T, ca.densify(J.T), ca.densify(ca.horzcat(ca.jacobian(y, dpose), Y_rest[:, spec.n_td:]).T)],
        ["u", "td", "p", "w", "t", "m", "dpose", "dm"], ["y", "J", "J_offsets"])
    return ObservationFunctions(G, ca.Function("observe_ift_y", [u, td, p, w, t, m, dpose, dm], [y.T]),
                                 [1, 3, 4, 5], structural_nonzeros(J))


def structural_nonzeros(expr) -> np.ndarray:
    """(rows, cols) bool of a CasADi matrix expression: True where an entry is stored in its
    sparsity. Every other entry is a structural zero: densified, it is written 0 whatever the
    inputs (NaN and infinity included)."""
    rows, cols = expr.sparsity().get_triplet()
    out = np.zeros(expr.shape, bool)
    out[np.asarray(rows, int), np.asarray(cols, int)] = True
    return out


def observation_for(spec: PlatformSpec, n_markers: int, n_bodies: int,
                    point_links: tuple[int, ...] | None) -> tuple[ObservationFunctions, PlatformModel]:
    """The observation functions of ``spec`` for ``n_markers`` markers and ``n_bodies`` rigid bodies
    (``point_links``: see :func:`observation_functions`), built once per (stand, M + B) and shared by
    every problem of them, and the stand's PlatformModel, once per stand (a model selection, k
    folds and a diagnosis build dozens of problems of one stand); per thread, as their buffers are
    not to be shared between threads (the model's solvers keep only scratch buffers)."""
    thread = threading.get_ident()
    key = (id(spec), n_markers + n_bodies, n_bodies > 0, thread, point_links)
    hit = _BUILT.get(key)
    if hit is None or hit[0] is not spec:
        if len(_BUILT) > 16:
            _BUILT.clear()
        model = next((h[2] for k, h in _BUILT.items() if h[0] is spec and k[3] == thread), None) \
            or PlatformModel(spec)
        hit = _BUILT[key] = (spec, observation_functions(spec, n_markers + n_bodies, n_bodies > 0, point_links,
                                                         n_bodies), model)
    return hit[1], hit[2]
