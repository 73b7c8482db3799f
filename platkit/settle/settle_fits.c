/* The approach fits' normal equations compiled (platkit.settle._native, package data).

   For every hold h and each of its time constants tau: the normal equations of the design
   [1, e, (s / tau) e], e = exp(-s / tau), per marker over its visible samples (weights w), as
   platkit.settle._fits._normal_equations builds them: regularised by 1e-12 of their trace, the
   identity for a marker not seen. Then either the residual sum of squares over the seen markers
   (the data's sum of squares less what the equations' Cholesky factor explains, as
   _fits._residuals) or the equations themselves (G (M, 3, 3), B (M, 3, 3) [param, coord]).

   The exponentials: exp(-s_k / tau) is taken exactly at the first sample of every block of
   BLOCK samples, the others from it times exp(-j dt / tau) (a table per tau, dt the hold's
   mean spacing) times 1 - d / tau, d = s_k - s_block - j dt, where |d| / tau is below 1e-9 (the
   neglected term below 1e-18 of e); elsewhere (jitter, gaps) exp itself. The sums against the
   markers run over the samples with the right-hand sides of 16 columns in registers (y is laid
   out with its columns padded to a multiple of 16 with zeros); on x86-64 with GCC the kernel is
   also built for AVX and FMA, picked at load time where the processor has them. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define BLOCK 8
#define WIDTH 16 /* columns of y summed together: four vectors of four */

typedef double v4 __attribute__((vector_size(32), aligned(8)));

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define PK_CLONES __attribute__((target_clones("fma", "default")))
#else
#define PK_CLONES
#endif

/* sums over the K samples of e_k y_k and p_k y_k for the Jp columns of y (K, Jp), Jp a multiple
   of WIDTH: bE, bP (Jp) */
PK_CLONES
static void products(long long K, int Jp, const double *e, const double *p, const double *y, double *bE, double *bP)
{
    for (int g = 0; g < Jp; g += WIDTH) {
        v4 e0 = {0, 0, 0, 0}, e1 = e0, e2 = e0, e3 = e0, p0 = e0, p1 = e0, p2 = e0, p3 = e0;
        const double *yg = y + g;
        for (long long k = 0; k < K; k++) {
            const v4 *yk = (const v4 *)(yg + k * Jp);
            const v4 ev = {e[k], e[k], e[k], e[k]}, pv = {p[k], p[k], p[k], p[k]};
            const v4 y0 = yk[0], y1 = yk[1], y2 = yk[2], y3 = yk[3];
            e0 += ev * y0; e1 += ev * y1; e2 += ev * y2; e3 += ev * y3;
            p0 += pv * y0; p1 += pv * y1; p2 += pv * y2; p3 += pv * y3;
        }
        for (int c = 0; c < 4; c++) {
            bE[g + c] = e0[c]; bE[g + 4 + c] = e1[c]; bE[g + 8 + c] = e2[c]; bE[g + 12 + c] = e3[c];
            bP[g + c] = p0[c]; bP[g + 4 + c] = p1[c]; bP[g + 8 + c] = p2[c]; bP[g + 12 + c] = p3[c];
        }
    }
}

/* hold h: samples [ks[h], ks[h+1]) of s (times from its first sample), y (rows of Jp >= 3 M
   columns: centred markers, zero where occluded and past 3 M), w (rows of M: 1 visible, 0
   occluded), full (1 where every marker is visible); time constants [ts[h], ts[h+1]) of taus;
   seen and yty (H, M). mode 0: rss[ts[h] + j]; mode 1: G and B at (ts[h] + j) * 9 M. Returns
   0, or -1 when out of memory. */
int pk_settle_fits(int H, int M, int Jp, const long long *ks, const long long *ts, const double *s, const double *y,
                   const double *w, const unsigned char *full, const unsigned char *seen, const double *yty,
                   const double *taus, int mode, double *rss, double *G, double *B)
{
    long long Kmax = 1;
    for (int h = 0; h < H; h++)
        if (ks[h + 1] - ks[h] > Kmax) Kmax = ks[h + 1] - ks[h];
    double *work = malloc(sizeof(double) * (size_t)(3 * Jp + 6 * M + 2 * Kmax));
    if (!work) return -1;
    double *bE = work, *bP = work + Jp, *sy = work + 2 * Jp, *am = work + 3 * Jp, *eb = am + 6 * M, *pb = eb + Kmax;
    for (int h = 0; h < H; h++) {
        const long long k0 = ks[h], K = ks[h + 1] - ks[h];
        const double *sh = s + k0, *yh = y + k0 * Jp, *wh = w + k0 * M;
        const unsigned char *fh = full + k0;
        const double last = sh[K - 1] > 1e-9 ? sh[K - 1] : 1e-9;
        const double dt = last / (double)(K > 1 ? K - 1 : 1);
        memset(sy, 0, sizeof(double) * (size_t)Jp);
        for (long long k = 0; k < K; k++)
            for (int c = 0; c < Jp; c++) sy[c] += yh[k * Jp + c];
        for (long long q = ts[h]; q < ts[h + 1]; q++) {
            const double tau = taus[q], inv = 1.0 / tau;
            double tab[BLOCK];
            for (int j = 0; j < BLOCK; j++) tab[j] = exp(-(j * dt) * inv);
            double n0 = 0, sE = 0, sP = 0, sEE = 0, sEP = 0, sPP = 0;
            memset(am, 0, sizeof(double) * (size_t)(6 * M));
            double e0 = 0, s0 = 0;
            for (long long k = 0; k < K; k++) {
                const int j = (int)(k % BLOCK);
                const double x = sh[k] * inv;
                double e;
                if (j == 0) {
                    e0 = exp(-x);
                    s0 = sh[k];
                    e = e0;
                } else {
                    const double d = (sh[k] - s0 - j * dt) * inv;
                    e = fabs(d) < 1e-9 ? e0 * tab[j] * (1.0 - d) : exp(-x);
                }
                const double p = x * e;
                eb[k] = e;
                pb[k] = p;
                if (fh[k]) {
                    n0 += 1.0;
                    sE += e;
                    sP += p;
                    sEE += e * e;
                    sEP += e * p;
                    sPP += p * p;
                } else {
                    const double *wk = wh + k * M;
                    for (int m = 0; m < M; m++) {
                        const double v = wk[m];
                        double *r = am + 6 * m;
                        r[0] += v;
                        r[1] += v * e;
                        r[2] += v * p;
                        r[3] += v * e * e;
                        r[4] += v * e * p;
                        r[5] += v * p * p;
                    }
                }
            }
            products(K, Jp, eb, pb, yh, bE, bP);
            double total = 0.0;
            for (int m = 0; m < M; m++) {
                const double *r = am + 6 * m;
                double a00, a01, a02, a11, a12, a22;
                if (seen[h * M + m]) {
                    a00 = n0 + r[0]; a01 = sE + r[1]; a02 = sP + r[2];
                    a11 = sEE + r[3]; a12 = sEP + r[4]; a22 = sPP + r[5];
                } else {
                    a00 = 1.0; a01 = 0.0; a02 = 0.0; a11 = 1.0; a12 = 0.0; a22 = 1.0;
                }
                const double reg = 1e-12 * (a00 + a11 + a22);
                a00 += reg; a11 += reg; a22 += reg;
                double b0[3], b1[3], b2[3];
                for (int c = 0; c < 3; c++) {
                    b0[c] = sy[3 * m + c];
                    b1[c] = bE[3 * m + c];
                    b2[c] = bP[3 * m + c];
                }
                if (mode == 1) {
                    double *g = G + (q * M + m) * 9, *bb = B + (q * M + m) * 9;
                    g[0] = a00; g[1] = a01; g[2] = a02;
                    g[3] = a01; g[4] = a11; g[5] = a12;
                    g[6] = a02; g[7] = a12; g[8] = a22;
                    for (int c = 0; c < 3; c++) { bb[c] = b0[c]; bb[3 + c] = b1[c]; bb[6 + c] = b2[c]; }
                    continue;
                }
                if (!seen[h * M + m]) continue;
                const double l00 = sqrt(a00);
                const double l10 = a01 / l00, l20 = a02 / l00;
                const double l11 = sqrt(a11 - l10 * l10);
                const double l21 = (a12 - l20 * l10) / l11;
                const double l22 = sqrt(a22 - l20 * l20 - l21 * l21);
                double explained = 0.0;
                for (int c = 0; c < 3; c++) {
                    const double z0 = b0[c] / l00;
                    const double z1 = (b1[c] - l10 * z0) / l11;
                    const double z2 = (b2[c] - l20 * z0 - l21 * z1) / l22;
                    explained += z0 * z0 + z1 * z1 + z2 * z2;
                }
                total += yty[h * M + m] - explained;
            }
            if (mode == 0) rss[q] = total;
        }
    }
    free(work);
    return 0;
}
