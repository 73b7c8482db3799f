"""The part of a PlatformModel every solver uses: the stand's residual F(u, td, p) as CasADi
functions, its strokes, control checks, pose coordinates -> (q, X) and back."""
from __future__ import annotations

import casadi as ca
import numpy as np

from platkit.errors import BadInput, OutOfWorkspace
from platkit.geometry import quat_normalize
from platkit.limits import check_strokes
from platkit.model import PlatformSpec, controls_from_si, length_scale
from platkit.notices import warn


class ModelCore:
    """The stand's residual and its Jacobians as CasADi functions, its strokes and nominal values."""

    def __init__(self, spec: PlatformSpec, tol: float = 1e-10, max_iter: int = 30, length_unit: str = "mm",
                 compile: bool = True):
        self.spec = spec
        self.tol = tol
        self.max_iter = max_iter
        self.length_unit = length_unit
        self._display_scale = length_scale(length_unit)
        self._compile = compile
        u = ca.SX.sym("u", spec.n_u)
        td = ca.SX.sym("td", spec.n_td)
        p = ca.SX.sym("p", spec.n_p)
        q, X = spec.pose(p)
        r = spec.residual(u, td, q, X)
        self.n_r = r.shape[0]
        Jp = ca.jacobian(r, p)
        self.F = ca.Function("F", [u, td, p], [r], ["u", "td", "p"], ["r"])
        self.F_jac = ca.Function(
            "F_jac", [u, td, p], [r, Jp, ca.jacobian(r, u), ca.jacobian(r, td)],
            ["u", "td", "p"], ["r", "F_p", "F_u", "F_td"],
        )
        self.pose_fn = spec.pose
        self._branch = spec.branch
        self._td0 = spec.nominal_td()
        self._p0 = spec.neutral_p()
        self._lo, self._hi = spec.control_bounds()
        self._lo_tol = self._lo - 1e-12
        self._hi_tol = self._hi + 1e-12
        # the same bounds as Python floats: one control vector is checked faster without numpy
        self._strokes = tuple(zip(self._lo_tol.tolist(), self._hi_tol.tolist()))

    def _td(self, td) -> np.ndarray:
        return self._td0 if td is None else np.asarray(td, float)

    def _show(self, value: float, unit: str) -> tuple[float, str]:
        """A value in the unit a person reads: 'm' quantities in ``length_unit``."""
        if unit == "m":
            return value / self._display_scale, self.length_unit
        return value, unit

    def check_controls(self, u, strict: bool = True) -> np.ndarray:
        """Controls as an array (n_u,) or (N, n_u); BadInput for a wrong length or a non-finite
        value; ``strict``: a value past its stroke under platkit.limits' policy (within the
        recording tolerance a warning, further out OutOfWorkspace). Messages show lengths in
        the model's ``length_unit``."""
        u = np.asarray(u, dtype=float)
        if u.shape[-1:] != (self.spec.n_u,):
            got = u.shape[-1] if u.ndim else 1
            raise BadInput(
                f"{self.spec.name} takes {self.spec.n_u} controls ({', '.join(self.spec.control_names)}), got {got}"
            )
        # fast path: every value finite and inside its stroke (NaN fails every comparison)
        if strict:
            if u.ndim == 1:
                if all(lo <= v <= hi for (lo, hi), v in zip(self._strokes, u.tolist())):
                    return u
            elif bool(((u >= self._lo_tol) & (u <= self._hi_tol)).all()):
                return u
        finite = np.isfinite(u)
        if not finite.all():
            i = int(np.argwhere(~finite)[0][-1])
            raise BadInput(f"{self.spec.name}: control {self.spec.controls[i].name} is not a finite number")
        if strict:
            # past a limit: platkit.limits' policy (a reading within the recording tolerance is
            # kept with a warning, further out is OutOfWorkspace)
            U = np.atleast_2d(u)
            name = self.spec.name

            def where(r: int, control: str) -> str:
                return f"{name}: control {control}" + (f" (row {r})" if u.ndim > 1 else "")

            check_strokes(self.spec, U, controls_from_si(self.spec, U, self.length_unit), self.length_unit, where,
                          OutOfWorkspace, f"the lengths are in {self.length_unit}", warn)
        return u

    def pose(self, p) -> tuple[np.ndarray, np.ndarray]:
        q, X = self.pose_fn(np.asarray(p, float))
        return quat_normalize(np.asarray(q).ravel()), np.asarray(X).ravel()

    def coordinates(self, q, X) -> np.ndarray:
        """Pose coordinates p of a pose (q, X); needs the stand's coordinates_from_pose."""
        if self.spec.coordinates_from_pose is None:
            raise BadInput(f"stand {self.spec.name!r} cannot convert a pose to its coordinates")
        return np.asarray(self.spec.coordinates_from_pose(quat_normalize(np.asarray(q, float)), np.asarray(X, float))).ravel()

    def on_branch(self, u, td, q, X) -> bool:
        if self._branch is None:
            return True
        g = np.asarray(self._branch(u, self._td(td), q, X)).ravel()
        return bool(np.all(g > 0))

    def residual(self, u, p, td=None) -> np.ndarray:
        return np.asarray(self.F(np.asarray(u, float), self._td(td), np.asarray(p, float))).ravel()

    @staticmethod
    def _lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
        if A.shape[0] == A.shape[1]:
            return np.linalg.solve(A, b)
        return np.linalg.lstsq(A, b, rcond=None)[0]
