
/* ---- platkit generic Newton driver: knows nothing about any stand ---- */
#include <string.h>
#include <math.h>

static int pk_eval_rj(const double* u, const double* td, const double* p, double* r, double* J) {
  const casadi_real* arg[PK_SZ_ARG_RJ + 1]; casadi_real* res[PK_SZ_RES_RJ + 1];
  casadi_int iw[PK_SZ_IW_RJ + 1]; casadi_real w[PK_SZ_W_RJ + 1];
  arg[0] = u; arg[1] = td; arg[2] = p; res[0] = r; res[1] = J;
  return pk_rj(arg, res, iw, w, 0);
}

static int pk_eval_post(const double* u, const double* td, const double* p, double* q, double* X, double* g) {
  const casadi_real* arg[PK_SZ_ARG_POST + 1]; casadi_real* res[PK_SZ_RES_POST + 1];
  casadi_int iw[PK_SZ_IW_POST + 1]; casadi_real w[PK_SZ_W_POST + 1];
  arg[0] = u; arg[1] = td; arg[2] = p; res[0] = q; res[1] = X; res[2] = g;
  return pk_post(arg, res, iw, w, 0);
}

/* Solve A x = b in place (A n-by-n column major, destroyed; b becomes x). 0 ok, 1 singular. */
static int pk_lu_solve(int n, double* A, double* b, double scale) {
  int i, j, k, piv;
  for (k = 0; k < n; ++k) {
    double best = fabs(A[k + k * n]); piv = k;
    for (i = k + 1; i < n; ++i) { double v = fabs(A[i + k * n]); if (v > best) { best = v; piv = i; } }
    if (!(best > 1e-14 * scale)) return 1;
    if (piv != k) {
      for (j = 0; j < n; ++j) { double t = A[k + j * n]; A[k + j * n] = A[piv + j * n]; A[piv + j * n] = t; }
      { double t = b[k]; b[k] = b[piv]; b[piv] = t; }
    }
    for (i = k + 1; i < n; ++i) {
      double f = A[i + k * n] / A[k + k * n];
      if (f != 0.0) { for (j = k + 1; j < n; ++j) A[i + j * n] -= f * A[k + j * n]; b[i] -= f * b[k]; }
    }
  }
  for (k = n - 1; k >= 0; --k) {
    double s = b[k];
    for (j = k + 1; j < n; ++j) s -= A[k + j * n] * b[j];
    b[k] = s / A[k + k * n];
  }
  return 0;
}

/* The normal equations of the rows: A = J^T J (NP x NP, column-major), g = J^T r. */
static void pk_normal(const double* J, const double* r, double* A, double* g) {
  int i, j, l;
  for (i = 0; i < PK_NP; ++i) {
    double gi = 0.0;
    for (l = 0; l < PK_NR; ++l) gi += J[l + i * PK_NR] * r[l];
    g[i] = gi;
    for (j = 0; j < PK_NP; ++j) {
      double a = 0.0;
      for (l = 0; l < PK_NR; ++l) a += J[l + i * PK_NR] * J[l + j * PK_NR];
      A[i + j * PK_NP] = a;
    }
  }
}

/* The Newton step: solve J dp = r (Gauss-Newton J^T J dp = J^T r when NR > NP) into b. */
static int pk_step(const double* J, const double* r, double* A, double* b) {
  int i; double scale = 0.0;
  if (PK_NR == PK_NP) {
    memcpy(A, J, sizeof(double) * PK_NP * PK_NP); memcpy(b, r, sizeof(double) * PK_NP);
  } else {
    pk_normal(J, r, A, b);
  }
  for (i = 0; i < PK_NP * PK_NP; ++i) { double v = fabs(A[i]); if (v > scale) scale = v; }
  return pk_lu_solve(PK_NP, A, b, scale);
}

static double pk_norm(const double* r) {
  double s = 0.0; int i;
  for (i = 0; i < PK_NR; ++i) s += r[i] * r[i];
  return sqrt(s);
}

#if PK_NR > PK_NP
/* More rows than pose coordinates: Levenberg-Marquardt on the (weighted) rows r(p), the
   least-squares pose. Steps solve (J^T J + lam diag(J^T J)) dp = J^T r; a step is kept only when
   it lowers |r| (lam / 3), else lam x 4 and the step is tried again. Stops converged when
   |r| <= tol (the rows close; one Gauss-Newton step then polishes the pose, kept only if it does
   not raise |r|, as Newton's below), when the step is below 1e-11 (1 + |p|_inf), or when no step
   lowers |r| (a minimum to machine precision); status 1 after max_iter steps. out as pk_newton
   below. */
CASADI_SYMBOL_EXPORT void pk_newton(const double* u, const double* td, const double* p0,
                                    double tol, int max_iter, double* out) {
  double r[PK_NR + 1], J[PK_NR * PK_NP + 1], rt[PK_NR + 1], Jt[PK_NR * PK_NP + 1];
  double N[PK_NP * PK_NP + 1], A[PK_NP * PK_NP + 1], gr[PK_NP + 1], b[PK_NP + 1], pt[PK_NP + 1];
  double* p = out; double* q = out + PK_NP; double* X = q + 4; double* g = X + 3;
  double* info = g + PK_NG;
  double nrm, nt, lam = 1e-4; int k, i, tries, status = 0;
  memcpy(p, p0, sizeof(double) * PK_NP);
  pk_eval_rj(u, td, p, r, J);
  nrm = pk_norm(r);
  for (k = 0;; ++k) {
    double scale = 0.0, step = 0.0, pmax = 0.0; int kept = 0;
    if (!isfinite(nrm)) { status = 3; break; }
    if (nrm <= tol) {
      if (nrm > 0.0 && !pk_step(J, r, A, b)) {
        for (i = 0; i < PK_NP; ++i) pt[i] = p[i] - b[i];
        pk_eval_rj(u, td, pt, rt, Jt);
        nt = pk_norm(rt);
        if (nt <= nrm) { memcpy(p, pt, sizeof(double) * PK_NP); nrm = nt; }
      }
      status = 0; break;
    }
    if (k >= max_iter) { status = 1; break; }
    pk_normal(J, r, N, gr);
    for (i = 0; i < PK_NP * PK_NP; ++i) { double v = fabs(N[i]); if (v > scale) scale = v; }
    for (tries = 0; tries < 40 && !kept; ++tries) {
      memcpy(A, N, sizeof(double) * PK_NP * PK_NP);
      memcpy(b, gr, sizeof(double) * PK_NP);
      for (i = 0; i < PK_NP; ++i) {
        double d = N[i + i * PK_NP];
        A[i + i * PK_NP] += lam * (d > 1e-12 * scale ? d : 1e-12 * scale + 1e-300);
      }
      if (pk_lu_solve(PK_NP, A, b, scale)) { lam *= 4.0; continue; }
      for (i = 0; i < PK_NP; ++i) pt[i] = p[i] - b[i];
      pk_eval_rj(u, td, pt, rt, Jt);
      nt = pk_norm(rt);
      if (isfinite(nt) && nt < nrm) {
        kept = 1;
        for (i = 0; i < PK_NP; ++i) {
          double s = fabs(b[i]), v = fabs(pt[i]);
          if (s > step) step = s;
          if (v > pmax) pmax = v;
        }
        memcpy(p, pt, sizeof(double) * PK_NP);
        memcpy(r, rt, sizeof(double) * PK_NR);
        memcpy(J, Jt, sizeof(double) * PK_NR * PK_NP);
        nrm = nt;
        lam = lam / 3.0 > 1e-12 ? lam / 3.0 : 1e-12;
      } else {
        lam *= 4.0;
      }
    }
    if (!kept) { status = 0; ++k; break; }
    if (step <= 1e-11 * (1.0 + pmax)) { status = 0; ++k; break; }
  }
  pk_eval_post(u, td, p, q, X, g);
  {
    double qn = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    double sgn = q[0] < 0 ? -1.0 : 1.0;
    int on = 1;
    for (i = 0; i < 4; ++i) q[i] *= sgn / qn;
    for (i = 0; i < PK_NG; ++i) if (!(g[i] > 0)) on = 0;
    info[0] = k; info[1] = nrm; info[2] = status; info[3] = on;
  }
}
#else
/* Newton on r(p) = F(u, td, pose(p)) = 0 from p0. out: p (NP), q (4, unit, w >= 0), X (3),
   g (NG), then iterations, |r|, status, on_branch. Once |r| <= tol one more step polishes the
   solution (kept only if it lowers |r|); it is not counted as an iteration. */
CASADI_SYMBOL_EXPORT void pk_newton(const double* u, const double* td, const double* p0,
                                    double tol, int max_iter, double* out) {
  double r[PK_NR + 1], J[PK_NR * PK_NP + 1], A[PK_NP * PK_NP + 1], b[PK_NP + 1], pt[PK_NP + 1];
  double* p = out; double* q = out + PK_NP; double* X = q + 4; double* g = X + 3;
  double* info = g + PK_NG;
  double nrm = 0.0; int k, i, status = 0;
  memcpy(p, p0, sizeof(double) * PK_NP);
  for (k = 0;; ++k) {
    pk_eval_rj(u, td, p, r, J);
    nrm = pk_norm(r);
    if (!isfinite(nrm)) { status = 3; break; }
    if (nrm <= tol) {
      if (nrm > 0.0 && !pk_step(J, r, A, b)) {
        double nt;
        for (i = 0; i < PK_NP; ++i) pt[i] = p[i] - b[i];
        pk_eval_rj(u, td, pt, r, J);
        nt = pk_norm(r);
        if (nt <= nrm) { memcpy(p, pt, sizeof(double) * PK_NP); nrm = nt; }
      }
      status = 0; break;
    }
    if (k >= max_iter) { status = 1; break; }
    if (pk_step(J, r, A, b)) { status = 2; break; }
    for (i = 0; i < PK_NP; ++i) p[i] -= b[i];
  }
  pk_eval_post(u, td, p, q, X, g);
  {
    double qn = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    double sgn = q[0] < 0 ? -1.0 : 1.0;
    int on = 1;
    for (i = 0; i < 4; ++i) q[i] *= sgn / qn;
    for (i = 0; i < PK_NG; ++i) if (!(g[i] > 0)) on = 0;
    info[0] = k; info[1] = nrm; info[2] = status; info[3] = on;
  }
}

#endif

/* pk_newton for one control vector inside [lo, hi] (NaN is outside); 1 and nothing solved when
   outside (the caller words the error), 0 otherwise. The check costs nothing here and a
   microsecond in Python, a fifth of a warm forward call. */
CASADI_SYMBOL_EXPORT int pk_newton_checked(const double* u, const double* lo, const double* hi, const double* td,
                                           const double* p0, double tol, int max_iter, double* out) {
  int i;
  for (i = 0; i < PK_NU; ++i) if (!(u[i] >= lo[i] && u[i] <= hi[i])) return 1;
  pk_newton(u, td, p0, tol, max_iter, out);
  return 0;
}

/* n problems: U (n, NU) row major, P0 (n, NP) or one row when p0_stride = 0, out (n, NOUT). */
CASADI_SYMBOL_EXPORT void pk_newton_batch(int n, const double* U, const double* td, const double* P0,
                                          int p0_stride, double tol, int max_iter, double* out) {
  int i;
  for (i = 0; i < n; ++i)
    pk_newton(U + (long)i * PK_NU, td, P0 + (long)i * p0_stride, tol, max_iter, out + (long)i * PK_NOUT);
}
