/* A hand-written Newton solver for the 6-UPS Stewart platform: the reference platkit's generic,
   generated solver is timed against (benchmarks/fk_speed.py compiles it with cc -O2).

   Pose p = (x, y, z, roll, pitch, yaw), R = Rz(yaw) Ry(pitch) Rx(roll). Leg i: l_i = X + R P_i - B_i,
   f_i = |l_i| - L_i. Jacobian rows: df/dX = n^T, df/dangle = n^T (dR/dangle) P_i. B, P are 6x3 row
   major (metres), L the six leg lengths. */
#include <math.h>
#include <string.h>

static void rot(const double* a, double R[9], double dR[3][9]) {
  double cr = cos(a[0]), sr = sin(a[0]), cp = cos(a[1]), sp = sin(a[1]), cy = cos(a[2]), sy = sin(a[2]);
  double r[9] = {cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
                 sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
                 -sp, cp * sr, cp * cr};
  /* d/droll */
  double d0[9] = {0, cy * sp * cr + sy * sr, -cy * sp * sr + sy * cr,
                  0, sy * sp * cr - cy * sr, -sy * sp * sr - cy * cr,
                  0, cp * cr, -cp * sr};
  /* d/dpitch */
  double d1[9] = {-cy * sp, cy * cp * sr, cy * cp * cr,
                  -sy * sp, sy * cp * sr, sy * cp * cr,
                  -cp, -sp * sr, -sp * cr};
  /* d/dyaw */
  double d2[9] = {-sy * cp, -sy * sp * sr - cy * cr, -sy * sp * cr + cy * sr,
                  cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
                  0, 0, 0};
  memcpy(R, r, sizeof r); memcpy(dR[0], d0, sizeof d0); memcpy(dR[1], d1, sizeof d1); memcpy(dR[2], d2, sizeof d2);
}

static int solve6(double A[36], double b[6]) {
  int i, j, k;
  for (k = 0; k < 6; ++k) {
    int piv = k; double best = fabs(A[k * 6 + k]);
    for (i = k + 1; i < 6; ++i) if (fabs(A[i * 6 + k]) > best) { best = fabs(A[i * 6 + k]); piv = i; }
    if (best < 1e-300) return 1;
    if (piv != k) {
      for (j = 0; j < 6; ++j) { double t = A[k * 6 + j]; A[k * 6 + j] = A[piv * 6 + j]; A[piv * 6 + j] = t; }
      { double t = b[k]; b[k] = b[piv]; b[piv] = t; }
    }
    for (i = k + 1; i < 6; ++i) {
      double f = A[i * 6 + k] / A[k * 6 + k];
      for (j = k + 1; j < 6; ++j) A[i * 6 + j] -= f * A[k * 6 + j];
      b[i] -= f * b[k];
    }
  }
  for (k = 5; k >= 0; --k) {
    double s = b[k];
    for (j = k + 1; j < 6; ++j) s -= A[k * 6 + j] * b[j];
    b[k] = s / A[k * 6 + k];
  }
  return 0;
}

/* Newton from p0; writes p, returns the iterations (-1 on failure); *residual = |f| at the end. */
int stewart_newton(const double* B, const double* P, const double* L, const double* p0,
                   double tol, int max_iter, double* p, double* residual) {
  int k, i, j;
  memcpy(p, p0, 6 * sizeof(double));
  for (k = 0;; ++k) {
    double R[9], dR[3][9], J[36], f[6], nrm = 0.0;
    rot(p + 3, R, dR);
    for (i = 0; i < 6; ++i) {
      const double* Pi = P + 3 * i;
      double l[3], len, n[3];
      for (j = 0; j < 3; ++j) l[j] = p[j] + R[3 * j] * Pi[0] + R[3 * j + 1] * Pi[1] + R[3 * j + 2] * Pi[2] - B[3 * i + j];
      len = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
      f[i] = len - L[i];
      nrm += f[i] * f[i];
      for (j = 0; j < 3; ++j) { n[j] = l[j] / len; J[i * 6 + j] = n[j]; }
      for (j = 0; j < 3; ++j) {
        const double* d = dR[j];
        double v0 = d[0] * Pi[0] + d[1] * Pi[1] + d[2] * Pi[2];
        double v1 = d[3] * Pi[0] + d[4] * Pi[1] + d[5] * Pi[2];
        double v2 = d[6] * Pi[0] + d[7] * Pi[1] + d[8] * Pi[2];
        J[i * 6 + 3 + j] = n[0] * v0 + n[1] * v1 + n[2] * v2;
      }
    }
    nrm = sqrt(nrm);
    *residual = nrm;
    if (nrm <= tol) return k;
    if (k >= max_iter || solve6(J, f)) return -1;
    for (i = 0; i < 6; ++i) p[i] -= f[i];
  }
}

/* n solves (L: n x 6 row major, P_out: n x 6), for timing without the ctypes call in the loop. */
int stewart_newton_many(int n, const double* B, const double* P, const double* L, const double* p0,
                        double tol, int max_iter, double* P_out) {
  int i, worst = 0; double res;
  for (i = 0; i < n; ++i) {
    int it = stewart_newton(B, P, L + 6 * i, p0, tol, max_iter, P_out + 6 * i, &res);
    if (it < 0) return -1;
    if (it > worst) worst = it;
  }
  return worst;
}
