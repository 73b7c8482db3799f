
/* ---- platkit: the tracking servo's one-target loop (knows no robot) ---- */
#include <math.h>
#include <string.h>

#define PK_MAXN 64
#define PK_LOG3_PREC 3.6502815398728847e-06 /* pinocchio: eps^(1/3), TaylorSeriesExpansion::precision<2> */

typedef struct {
  int n, nj, max_it, stall_it, use_rate, has_es;
  const int *active, *col, *kind;
  double gain, max_lin, max_ang, thr, max_damp, es, tol_p, tol_r;
  const double *w, *tR, *tt, *fR, *ft, *lower, *upper, *lower_act, *upper_act, *rate, *jplace, *jaxis;
} pk_chain;

static void pk_unpack(const int* ii, const double* dd, pk_chain* c) {
  c->n = ii[0]; c->nj = ii[1]; c->max_it = ii[2]; c->stall_it = ii[3]; c->use_rate = ii[4]; c->has_es = ii[5];
  c->active = ii + 6; c->col = c->active + c->n; c->kind = c->col + c->nj;
  c->gain = dd[0]; c->max_lin = dd[1]; c->max_ang = dd[2]; c->thr = dd[3]; c->max_damp = dd[4]; c->es = dd[5];
  c->tol_p = dd[6]; c->tol_r = dd[7]; c->w = dd + 8; c->tR = dd + 14; c->tt = dd + 23; c->fR = dd + 26; c->ft = dd + 35;
  c->lower = dd + 38; c->upper = c->lower + c->n; c->lower_act = c->upper + c->n; c->upper_act = c->lower_act + c->n;
  c->rate = c->upper_act + c->n; c->jplace = c->rate + c->n; c->jaxis = c->jplace + 12 * c->nj;
}

/* (R, p) <- (R, p) * (A, a): R row major */
static void pk_compose(double* R, double* p, const double* A, const double* a) {
  double T[9]; int i, j;
  for (i = 0; i < 3; ++i) {
    p[i] += R[3 * i] * a[0] + R[3 * i + 1] * a[1] + R[3 * i + 2] * a[2];
    for (j = 0; j < 3; ++j) T[3 * i + j] = R[3 * i] * A[j] + R[3 * i + 1] * A[3 + j] + R[3 * i + 2] * A[6 + j];
  }
  memcpy(R, T, sizeof T);
}

/* The link's placement (R, p) and, if J is given, its Jacobian J (6 x n, column major, rows v then omega). */
static void pk_fk(const pk_chain* c, const double* theta, double* R, double* p, double* J) {
  double org[PK_MAXN * 3], ax[PK_MAXN * 3];
  int k, i;
  static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  memcpy(R, I3, sizeof I3); p[0] = p[1] = p[2] = 0.0;
  for (k = 0; k < c->nj; ++k) {
    const double* P = c->jplace + 12 * k; const double* a = c->jaxis + 3 * k;
    double q = theta[c->col[k]], M[9], z[3] = {0.0, 0.0, 0.0};
    int kind = c->kind[k];
    pk_compose(R, p, P, P + 9);
    if (kind == 4) {
      z[0] = a[0] * q; z[1] = a[1] * q; z[2] = a[2] * q;
      pk_compose(R, p, I3, z);
    } else if (kind <= 2) {
      /* about a coordinate axis: R Rot(q) mixes the other two columns of R */
      double s = sin(q), co = cos(q);
      int u = (kind + 1) % 3, v = (kind + 2) % 3;
      for (i = 0; i < 3; ++i) {
        double ru = R[3 * i + u], rv = R[3 * i + v];
        R[3 * i + u] = co * ru + s * rv;
        R[3 * i + v] = co * rv - s * ru;
      }
    } else {
      double s = sin(q), co = cos(q);
      {
        double t = 1.0 - co, x = a[0], y = a[1], w = a[2];
        double m[9] = {co + t * x * x, t * x * y - s * w, t * x * w + s * y,
                       t * x * y + s * w, co + t * y * y, t * y * w - s * x,
                       t * x * w - s * y, t * y * w + s * x, co + t * w * w};
        memcpy(M, m, sizeof m);
      }
      pk_compose(R, p, M, z);
    }
    for (i = 0; i < 3; ++i) {
      org[3 * k + i] = p[i];
      ax[3 * k + i] = R[3 * i] * a[0] + R[3 * i + 1] * a[1] + R[3 * i + 2] * a[2];
    }
  }
  pk_compose(R, p, c->fR, c->ft);
  if (!J) return;
  memset(J, 0, sizeof(double) * 6 * c->n);
  for (k = 0; k < c->nj; ++k) {
    double* col = J + 6 * c->col[k]; const double* w = ax + 3 * k;
    if (c->kind[k] == 4) { col[0] = w[0]; col[1] = w[1]; col[2] = w[2]; continue; }
    {
      double r0 = p[0] - org[3 * k], r1 = p[1] - org[3 * k + 1], r2 = p[2] - org[3 * k + 2];
      col[0] = w[1] * r2 - w[2] * r1; col[1] = w[2] * r0 - w[0] * r2; col[2] = w[0] * r1 - w[1] * r0;
      col[3] = w[0]; col[4] = w[1]; col[5] = w[2];
    }
  }
}

/* pinocchio's log3 (spatial/log.hxx): the rotation vector of R (row major). */
static void pk_theta_axis(int i0, double val, const double* R, double* angle, double* axis) {
  const double eps = 2.220446049250313e-16;
  int i1 = (i0 + 1) % 3, i2 = (i0 + 2) % 3;
  double s = sqrt(val + eps + eps * eps) * (R[3 * i2 + i1] >= R[3 * i1 + i2] ? 1.0 : -1.0);
  double w, nrm;
  axis[i0] = s / 2.0;
  axis[i1] = 1.0 / (2.0 * s) * (R[3 * i1 + i0] + R[3 * i0 + i1]);
  axis[i2] = 1.0 / (2.0 * s) * (R[3 * i2 + i0] + R[3 * i0 + i2]);
  w = 1.0 / (2.0 * s) * (R[3 * i2 + i1] - R[3 * i1 + i2]);
  nrm = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
  *angle = 2.0 * atan2(nrm, w);
  axis[0] /= nrm; axis[1] /= nrm; axis[2] /= nrm;
}

static void pk_log3(const double* Rin, double* out) {
  const double eps = 2.220446049250313e-16, prec = PK_LOG3_PREC, PI = 3.14159265358979323846;
  double R[9], n0, n1, tr, cosv, th, t, as[3], as2;
  int i, k;
  /* renormalize_rotation_matrix: columns 0 and 1 normalised, 2 = 0 x 1, 0 = 1 x 2 */
  n0 = sqrt(Rin[0] * Rin[0] + Rin[3] * Rin[3] + Rin[6] * Rin[6]);
  n1 = sqrt(Rin[1] * Rin[1] + Rin[4] * Rin[4] + Rin[7] * Rin[7]);
  for (i = 0; i < 3; ++i) { R[3 * i] = Rin[3 * i] / n0; R[3 * i + 1] = Rin[3 * i + 1] / n1; }
  R[2] = R[3] * R[7] - R[6] * R[4]; R[5] = R[6] * R[1] - R[0] * R[7]; R[8] = R[0] * R[4] - R[3] * R[1];
  R[0] = R[4] * R[8] - R[7] * R[5]; R[3] = R[7] * R[2] - R[1] * R[8]; R[6] = R[1] * R[5] - R[4] * R[2];
  tr = R[0] + R[4] + R[8];
  cosv = (tr - 1.0) / 2.0;
  if (cosv >= -1.0 + prec) {
    double acos_exp = sqrt(2.0 * (1.0 - cosv) + eps * eps);
    th = tr <= 3.0 - prec ? (tr >= -1.0 + prec ? acos(cosv) : PI - acos_exp) : acos_exp;
    as[0] = 0.5 * (R[7] - R[5]); as[1] = 0.5 * (R[2] - R[6]); as[2] = 0.5 * (R[3] - R[1]);
    as2 = as[0] * as[0] + as[1] * as[1] + as[2] * as[2];
    t = th >= prec ? th / sin(th) : 1.0 + as2 / 6.0 + as2 * as2 * 3.0 / 40.0;
    for (k = 0; k < 3; ++k) out[k] = t * as[k];
  } else {
    double val[3], ang[3], axes[9];
    int pick;
    for (k = 0; k < 3; ++k) val[k] = 2.0 * R[4 * k] - tr + 1.0;
    for (k = 0; k < 3; ++k) pk_theta_axis(k, val[k], R, ang + k, axes + 3 * k);
    pick = val[0] >= val[1] ? (val[0] >= val[2] ? 0 : 2) : (val[1] >= val[2] ? 1 : 2);
    for (k = 0; k < 3; ++k) out[k] = ang[pick] * axes[3 * pick + k];
  }
}

/* E (6) at theta; returns the weighted merit. */
static double pk_error(const pk_chain* c, const double* theta, double* E, double* J) {
  double R[9], p[3], D[9], m = 0.0; int i, j;
  pk_fk(c, theta, R, p, J);
  for (i = 0; i < 3; ++i) {
    E[i] = c->tt[i] - p[i];
    for (j = 0; j < 3; ++j)
      D[3 * i + j] = c->tR[3 * i] * R[3 * j] + c->tR[3 * i + 1] * R[3 * j + 1] + c->tR[3 * i + 2] * R[3 * j + 2];
  }
  pk_log3(D, E + 3);
  for (i = 0; i < 6; ++i) m += c->w[i] * (E[i] * E[i]);
  return m;
}

static void pk_norms(const pk_chain* c, const double* E, double* pos, double* rot) {
  double a = 0.0, b = 0.0; int i;
  for (i = 0; i < 3; ++i) { if (c->w[i] > 0) a += E[i] * E[i]; if (c->w[3 + i] > 0) b += E[3 + i] * E[3 + i]; }
  *pos = sqrt(a); *rot = sqrt(b);
}

static double pk_damping(const pk_chain* c, double smin, double err) {
  double lam2;
  if (smin >= c->thr) return 0.0;
  lam2 = c->max_damp * c->max_damp * (1.0 - (smin / c->thr) * (smin / c->thr));
  if (c->has_es) lam2 *= fmin(1.0, err / c->es);
  return lam2;
}

/* One-sided Jacobi on M (rows x cols, cols <= rows, column major, overwritten by M R, whose
   columns are orthogonal); Q (cols x cols) becomes Q R. */
static void pk_jacobi(int rows, int cols, double* M, double* Q) {
  int sweep, a, b, i;
  const double tol = rows * 2.220446049250313e-16;
  for (sweep = 0; sweep < 60; ++sweep) {
    int rotated = 0;
    double d[6], worst = 0.0; /* squared column norms: fresh each sweep, updated by each rotation */
    for (a = 0; a < cols; ++a) { double v = 0.0; for (i = 0; i < rows; ++i) v += M[a * rows + i] * M[a * rows + i]; d[a] = v; }
    for (a = 0; a < cols - 1; ++a) for (b = a + 1; b < cols; ++b) {
      double* x = M + a * rows; double* y = M + b * rows;
      double al = d[a], be = d[b], ga = 0.0, zeta, t, cs, sn;
      for (i = 0; i < rows; ++i) ga += x[i] * y[i];
      if (ga == 0.0 || fabs(ga) <= tol * sqrt(al * be)) continue;  /* orthogonal to rounding */
      rotated = 1;
      worst = fmax(worst, fabs(ga) / sqrt(al * be));
      zeta = (be - al) / (2.0 * ga);
      t = fabs(zeta) > 1e150 ? 0.5 / zeta : (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
      cs = 1.0 / sqrt(1.0 + t * t); sn = cs * t;
      d[a] = al - t * ga; d[b] = be + t * ga;
      for (i = 0; i < rows; ++i) { double u = x[i], v = y[i]; x[i] = cs * u - sn * v; y[i] = sn * u + cs * v; }
      x = Q + a * cols; y = Q + b * cols;
      for (i = 0; i < cols; ++i) { double u = x[i], v = y[i]; x[i] = cs * u - sn * v; y[i] = sn * u + cs * v; }
    }
    /* convergence is quadratic: after cosines below 1e-10 the next sweep would find them
       below rounding, so it is not run */
    if (!rotated || worst < 1e-10) break;
  }
}

/* Cholesky of the p x p symmetric G (column major, lower part overwritten by L); 0 if G is
   positive definite, 1 if not. */
static int pk_cholesky(int p, double* G) {
  int i, j, l;
  for (j = 0; j < p; ++j) {
    double d = G[j * p + j];
    for (l = 0; l < j; ++l) d -= G[l * p + j] * G[l * p + j];
    if (!(d > 0.0)) return 1;
    d = sqrt(d); G[j * p + j] = d;
    for (i = j + 1; i < p; ++i) {
      double v = G[j * p + i];
      for (l = 0; l < j; ++l) v -= G[l * p + i] * G[l * p + j];
      G[j * p + i] = v / d;
    }
  }
  return 0;
}

static void pk_cholesky_solve(int p, const double* L, double* b) {
  int i, l;
  for (i = 0; i < p; ++i) { double v = b[i]; for (l = 0; l < i; ++l) v -= L[l * p + i] * b[l]; b[i] = v / L[i * p + i]; }
  for (i = p - 1; i >= 0; --i) { double v = b[i]; for (l = i + 1; l < p; ++l) v -= L[i * p + l] * b[l]; b[i] = v / L[i * p + i]; }
}

/* The common case without an SVD: when the smallest singular value of A is above the damping
   threshold (G - threshold^2 I positive definite, G = A A^T or A^T A), the damping is 0 and no
   singular value is cut, so the step is the plain pseudo-inverse A^T (A A^T)^-1 r (or
   (A^T A)^-1 A^T r), the SVD's numbers up to rounding. 1 if it does not apply. */
static int pk_solve_regular(const pk_chain* c, const double* Jw, int m, const int* cols, int k, const double* r,
                            double* dq) {
  double G[36], H[36], b[6], thr2 = c->thr * c->thr; /* p = min(m, k) <= 6 */
  int i, j, l, rowwise = m <= k, p = rowwise ? m : k;
  if (!(c->thr >= 1e-6)) return 1; /* a threshold near the 1e-10 rank cut: the SVD decides */
  for (i = 0; i < p; ++i) for (j = 0; j <= i; ++j) {
    double v = 0.0;
    if (rowwise) for (l = 0; l < k; ++l) v += Jw[cols[l] * 6 + i] * Jw[cols[l] * 6 + j];
    else for (l = 0; l < m; ++l) v += Jw[cols[i] * 6 + l] * Jw[cols[j] * 6 + l];
    G[j * p + i] = G[i * p + j] = v;
    H[j * p + i] = H[i * p + j] = v - (i == j ? thr2 : 0.0);
  }
  if (pk_cholesky(p, H) || pk_cholesky(p, G)) return 1;
  if (rowwise) {
    for (i = 0; i < m; ++i) b[i] = r[i];
    pk_cholesky_solve(p, G, b);
    for (l = 0; l < k; ++l) { double v = 0.0; for (i = 0; i < m; ++i) v += Jw[cols[l] * 6 + i] * b[i]; dq[cols[l]] += v; }
  } else {
    for (l = 0; l < k; ++l) { double v = 0.0; for (i = 0; i < m; ++i) v += Jw[cols[l] * 6 + i] * r[i]; b[l] = v; }
    pk_cholesky_solve(p, G, b);
    for (l = 0; l < k; ++l) dq[cols[l]] += b[l];
  }
  return 0;
}

/* dq[cols] += the damped pseudo-inverse of A = Jw[:, cols] (m x k) applied to r (m). */
static void pk_solve(const pk_chain* c, const double* Jw, int m, const int* cols, int k, const double* r, double* dq,
                     double* warm) {
  double M[6 * PK_MAXN], Q[36], sv[6], big = 0.0, smin = 0.0, rn = 0.0, lam2; /* Q: min(m, k) <= 6 square */
  int i, j, l, transposed = m <= k, ns = transposed ? m : k, nq = transposed ? m : k, any = 0;
  if (!pk_solve_regular(c, Jw, m, cols, k, r, dq)) return;
  /* Q starts from the last solve's rotations where they fit (warm[0] = their size): the
     Jacobian moved little (or lost a column to a limit), so M Q is nearly orthogonal and fewer
     sweeps remain; any orthogonal Q gives an SVD of A */
  if (warm && warm[0] == (double)nq) memcpy(Q, warm + 1, sizeof(double) * nq * nq);
  else { for (i = 0; i < nq * nq; ++i) Q[i] = 0.0; for (i = 0; i < nq; ++i) Q[i * nq + i] = 1.0; }
  if (transposed) { /* M = A^T Q (k x m) */
    for (j = 0; j < m; ++j) for (l = 0; l < k; ++l) {
      double v = 0.0; for (i = 0; i < m; ++i) v += Jw[cols[l] * 6 + i] * Q[j * m + i];
      M[j * k + l] = v;
    }
    pk_jacobi(k, m, M, Q);
  } else {          /* M = A Q (m x k) */
    for (j = 0; j < k; ++j) for (i = 0; i < m; ++i) {
      double v = 0.0; for (l = 0; l < k; ++l) v += Jw[cols[l] * 6 + i] * Q[j * k + l];
      M[j * m + i] = v;
    }
    pk_jacobi(m, k, M, Q);
  }
  if (warm) { warm[0] = nq; memcpy(warm + 1, Q, sizeof(double) * nq * nq); }
  for (j = 0; j < ns; ++j) {
    double s = 0.0; const double* y = M + j * (transposed ? k : m);
    for (i = 0; i < (transposed ? k : m); ++i) s += y[i] * y[i];
    sv[j] = sqrt(s);
    if (sv[j] > big) big = sv[j];
  }
  for (i = 0; i < m; ++i) rn += r[i] * r[i];
  rn = sqrt(rn);
  for (j = 0; j < ns; ++j) if (sv[j] > 1e-10 * fmax(1.0, big)) { if (!any || sv[j] < smin) smin = sv[j]; any = 1; }
  lam2 = pk_damping(c, any ? smin : 0.0, rn);
  for (j = 0; j < ns; ++j) {
    double f;
    if (!(sv[j] > 1e-10 * fmax(1.0, big))) continue;
    f = 1.0 / (sv[j] * sv[j] + lam2);
    if (transposed) { /* A = Q Y^T: U = Q, V_j = Y_j / s_j */
      const double* y = M + j * k; const double* u = Q + j * m; double d = 0.0;
      for (i = 0; i < m; ++i) d += u[i] * r[i];
      d *= f;
      for (l = 0; l < k; ++l) dq[cols[l]] += y[l] * d;
    } else {          /* A = Y Q^T: U_j = Y_j / s_j, V = Q */
      const double* y = M + j * m; const double* v = Q + j * k; double d = 0.0;
      for (i = 0; i < m; ++i) d += y[i] * r[i];
      d *= f;
      for (l = 0; l < k; ++l) dq[cols[l]] += v[l] * d;
    }
  }
}

/* Servo._fast_step: dq (n) at theta for the error E (6); J (6 x n) the Jacobian at theta. */
static void pk_step(const pk_chain* c, const double* theta, const double* E, const double* J, double* dq, double* warm) {
  int n = c->n, i, j, m = 0, rows[6], cols[PK_MAXN], free_[PK_MAXN], first = 1, pass, k;
  double e[6], ew[6], Jw[6 * PK_MAXN], lo[PK_MAXN], hi[PK_MAXN], fixed[PK_MAXN], r[6];
  double lin, ang, scale;
  for (i = 0; i < 6; ++i) e[i] = c->gain * E[i] * (c->w[i] > 0 ? 1.0 : 0.0);
  lin = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
  ang = sqrt(e[3] * e[3] + e[4] * e[4] + e[5] * e[5]);
  scale = 1.0;
  if (lin > 0) scale = fmin(scale, c->max_lin / lin);
  if (ang > 0) scale = fmin(scale, c->max_ang / ang);
  if (scale != 1.0) for (i = 0; i < 6; ++i) e[i] *= scale;
  for (i = 0; i < 6; ++i) if (c->w[i] > 0) {
    double s = sqrt(c->w[i]);
    for (j = 0; j < n; ++j) Jw[j * 6 + m] = J[j * 6 + i] * s;
    ew[m] = s * e[i]; rows[m] = i; ++m;
  }
  (void)rows;
  for (j = 0; j < n; ++j) {
    lo[j] = fmin(c->lower_act[j] - theta[j], 0.0);
    hi[j] = fmax(c->upper_act[j] - theta[j], 0.0);
  }
  for (pass = 0; pass <= n; ++pass) {
    int worst = -1, over = 0, viol = 0;
    double wx = 0.0;
    k = 0;
    if (first) {
      for (j = 0; j < n; ++j) { dq[j] = 0.0; if (c->active[j]) cols[k++] = j; }
      memcpy(r, ew, sizeof(double) * m);
    } else {
      for (j = 0; j < n; ++j) { dq[j] = fixed[j]; if (free_[j]) cols[k++] = j; }
      for (i = 0; i < m; ++i) { double s = 0.0; for (j = 0; j < n; ++j) s += Jw[j * 6 + i] * fixed[j]; r[i] = ew[i] - s; }
    }
    if (k) pk_solve(c, Jw, m, cols, k, r, dq, warm);
    for (j = 0; j < n; ++j) if (dq[j] > hi[j] + 1e-15 || dq[j] < lo[j] - 1e-15) viol = 1;
    if (!viol) break;
    if (first) { for (j = 0; j < n; ++j) { free_[j] = c->active[j]; fixed[j] = 0.0; } first = 0; }
    for (j = 0; j < n; ++j) if (free_[j] && (dq[j] > hi[j] + 1e-15 || dq[j] < lo[j] - 1e-15)) {
      double x = fmax(dq[j] - hi[j], lo[j] - dq[j]);
      if (!over || x > wx) { wx = x; worst = j; }
      over = 1;
    }
    if (!over) break;
    fixed[worst] = fmin(fmax(dq[worst], lo[worst]), hi[worst]);
    free_[worst] = 0;
  }
  for (j = 0; j < n; ++j) dq[j] = fmin(fmax(dq[j], lo[j]), hi[j]);
  if (c->use_rate) {
    double rs = 1.0;
    for (j = 0; j < n; ++j) rs = fmin(rs, c->rate[j] / fmax(fabs(dq[j]), 1e-300));
    if (rs < 1.0) for (j = 0; j < n; ++j) dq[j] *= rs;
    for (j = 0; j < n; ++j) dq[j] = fmin(fmax(dq[j], fmax(lo[j], -c->rate[j])), fmin(hi[j], c->rate[j]));
  }
}

/* Up to `chunk` iterations of Servo._fast_attempt. work: the task's weights (6), target R (9, row
   major) and t (3), theta (n, updated in place), state (11), out (12), path (chunk x n), history
   (chunk); dd's slots for the task are not read.
   state (in/out, 11): iterations, best merit, best E (6), stall reference, stall iteration, the
   merit at the start; `first` initialises them from theta. `time_over`: the time cap is already
   passed (checked before this chunk's first iteration, as the Python loop does before every one).
   out (12): E (6) and merit at theta, the number of accepted steps written to path (chunk x n)
   and history (chunk), the position and rotation errors at theta and at the best theta.
   Returns CONVERGED 0, LINE_SEARCH_FAILED 1, STALLED 2, ITERATION_CAP 3, TIME_CAP 4 or
   CHUNK_DONE 5. */
#ifdef _WIN32
#define PK_EXPORT __declspec(dllexport)
#else
#define PK_EXPORT
#endif
PK_EXPORT int pk_servo_chunk(const int* ii, const double* dd, double* work, int first, int time_over, int chunk) {
  pk_chain c;
  double *task = work, *theta = work + 18, *state = theta + ii[0], *out = state + 11, *path = out + 12;
  double *history = path + (long)chunk * ii[0];
  double E[6], merit, J[6 * PK_MAXN], dq[PK_MAXN], trial[PK_MAXN], tE[6], tmerit = 0.0, pos, rot, floor_;
  double warm[1 + 36], Jt[6 * PK_MAXN];
  int n, it, stall_at, steps = 0, code = CHUNK_DONE_, converged, t, i, j;
  pk_unpack(ii, dd, &c);
  c.w = task; c.tR = task + 6; c.tt = task + 15;  /* the target's part, per attempt */
  warm[0] = 0.0;
  n = c.n;
  floor_ = 1e-2 * (c.tol_p * c.tol_p + c.tol_r * c.tol_r);
  merit = pk_error(&c, theta, E, J);
  if (first) {
    state[0] = 0; state[1] = merit; memcpy(state + 2, E, sizeof E); state[8] = merit; state[9] = 0; state[10] = merit;
  }
  it = (int)state[0]; stall_at = (int)state[9];
  pk_norms(&c, E, &pos, &rot);
  converged = pos <= c.tol_p && rot <= c.tol_r;
  for (;;) {
    int accepted = 0; double alpha = 1.0, better;
    if (converged) { code = 0; break; }
    if (it >= c.max_it) { code = 3; break; }
    if (steps == 0 && time_over) { code = 4; break; }
    if (steps >= chunk) { code = CHUNK_DONE_; break; }
    pk_step(&c, theta, E, J, dq, warm);
    better = merit * (1.0 - 1e-12);
    for (t = 0; t < 12; ++t) {
      for (j = 0; j < n; ++j) trial[j] = fmin(fmax(theta[j] + alpha * dq[j], c.lower[j]), c.upper[j]);
      tmerit = pk_error(&c, trial, tE, Jt);  /* its Jacobian too: the next step's if accepted */
      if (tmerit < better) { accepted = 1; break; }
      alpha *= 0.5;
    }
    ++it;
    if (!accepted) { code = 1; break; }
    memcpy(theta, trial, sizeof(double) * n); memcpy(E, tE, sizeof E); memcpy(J, Jt, sizeof(double) * 6 * n);
    merit = tmerit;
    memcpy(path + (long)steps * n, theta, sizeof(double) * n); history[steps] = merit; ++steps;
    if (merit < state[1]) { state[1] = merit; memcpy(state + 2, E, sizeof E); }
    pk_norms(&c, E, &pos, &rot);
    converged = pos <= c.tol_p && rot <= c.tol_r;
    if (merit < (1.0 - 1e-3) * state[8] && state[8] > floor_) { state[8] = merit; stall_at = it; }
    else if (it - stall_at >= c.stall_it && !converged) { code = 2; break; }
  }
  state[0] = it; state[9] = stall_at;
  for (i = 0; i < 6; ++i) out[i] = E[i];
  out[6] = merit; out[7] = steps;
  pk_norms(&c, E, out + 8, out + 9);
  pk_norms(&c, state + 2, out + 10, out + 11);
  return code;
}
