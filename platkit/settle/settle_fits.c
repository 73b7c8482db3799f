/* Settling's kernels (platkit.settle._native, package data): the approach fits' normal
   equations (pk_settle_prepare, pk_settle_fits), and numpy's numbers bit for bit for the still
   test (pk_settle_halves, pk_settle_still) and the noise estimate (pk_settle_mad); the trend
   test's regression to rounding (pk_settle_trend).

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
   markers run over the samples with the right-hand sides in registers (y is laid out with its
   columns padded to a multiple of 16 with zeros): 16 columns in AVX vectors with fused
   multiply-adds where an x86-64 processor has them (checked at run time), else 8 in vectors of
   two; with GCC on x86-64 Linux the fits' other loops are also built for AVX and FMA and picked
   at load time. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define BLOCK 8
#define WIDTH 16 /* columns of y summed together: four vectors of four */

typedef double v4 __attribute__((vector_size(32), aligned(8)));

/* The library is compiled with -ffp-contract=off: the kernels that must give numpy's numbers
   (halves, still, trend, mad) round every product and sum on their own. The fits' sums, which
   need only agree to rounding, may fuse them (PK_FAST). */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define PK_CLONES __attribute__((target_clones("fma", "default"), optimize("fp-contract=fast")))
#elif defined(__GNUC__) && !defined(__clang__)
#define PK_CLONES __attribute__((optimize("fp-contract=fast")))
#else
#define PK_CLONES
#endif

typedef double v2 __attribute__((vector_size(16), aligned(8)));

/* The body of products_narrow and products_wide, written once: the sums over the K samples of
   e_k y_k and p_k y_k for the Jp columns of y (K, Jp), Jp a multiple of WIDTH, into bE, bP (Jp);
   4 L columns at a time in four vectors VT of L lanes each, the right-hand sides in registers. */
#define PK_PRODUCTS(VT, L)                                                                       \
    for (int g = 0; g < Jp; g += 4 * (L)) {                                                     \
        const VT zero = {0};                                                                    \
        VT e0 = zero, e1 = e0, e2 = e0, e3 = e0, p0 = e0, p1 = e0, p2 = e0, p3 = e0;            \
        const double *yg = y + g;                                                               \
        for (long long k = 0; k < K; k++) {                                                     \
            const VT *yk = (const VT *)(yg + k * Jp);                                           \
            const VT ev = zero + e[k], pv = zero + p[k]; /* e_k, p_k in every lane */           \
            const VT y0 = yk[0], y1 = yk[1], y2 = yk[2], y3 = yk[3];                            \
            e0 += ev * y0; e1 += ev * y1; e2 += ev * y2; e3 += ev * y3;                         \
            p0 += pv * y0; p1 += pv * y1; p2 += pv * y2; p3 += pv * y3;                         \
        }                                                                                       \
        for (int c = 0; c < (L); c++) {                                                         \
            bE[g + c] = e0[c]; bE[g + (L) + c] = e1[c]; bE[g + 2 * (L) + c] = e2[c];            \
            bE[g + 3 * (L) + c] = e3[c];                                                        \
            bP[g + c] = p0[c]; bP[g + (L) + c] = p1[c]; bP[g + 2 * (L) + c] = p2[c];            \
            bP[g + 3 * (L) + c] = p3[c];                                                        \
        }                                                                                       \
    }

/* PK_PRODUCTS eight columns at a time in vectors of two (sixteen registers) */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=fast")))
#endif
static void products_narrow(long long K, int Jp, const double *e, const double *p, const double *y, double *bE,
                            double *bP)
{
    PK_PRODUCTS(v2, 2)
}

#if defined(__GNUC__) && defined(__x86_64__)
#define PK_WIDE 1
/* PK_PRODUCTS sixteen columns at a time in AVX vectors of four, fused multiply-adds */
#if defined(__clang__)
__attribute__((target("avx,fma")))
#else
__attribute__((target("avx,fma"), optimize("fp-contract=fast")))
#endif
static void products_wide(long long K, int Jp, const double *e, const double *p, const double *y, double *bE,
                          double *bP)
{
    PK_PRODUCTS(v4, 4)
}
#endif

/* products_wide where the processor has AVX and FMA, else products_narrow */
static void products(long long K, int Jp, const double *e, const double *p, const double *y, double *bE, double *bP)
{
#ifdef PK_WIDE
    static int wide = -1;
    if (wide < 0) {
        __builtin_cpu_init();
        wide = __builtin_cpu_supports("avx") && __builtin_cpu_supports("fma");
    }
    if (wide) {
        products_wide(K, Jp, e, p, y, bE, bP);
        return;
    }
#endif
    products_narrow(K, Jp, e, p, y, bE, bP);
}

/* the sums over the K samples of the Jp columns of y (K, Jp), Jp a multiple of WIDTH */
PK_CLONES
static void column_sums(long long K, int Jp, const double *y, double *out)
{
    for (int g = 0; g < Jp; g += WIDTH) {
        v4 a0 = {0, 0, 0, 0}, a1 = a0, a2 = a0, a3 = a0;
        for (long long k = 0; k < K; k++) {
            const v4 *yk = (const v4 *)(y + g + k * Jp);
            a0 += yk[0]; a1 += yk[1]; a2 += yk[2]; a3 += yk[3];
        }
        for (int c = 0; c < 4; c++) {
            out[g + c] = a0[c]; out[g + 4 + c] = a1[c]; out[g + 8 + c] = a2[c]; out[g + 12 + c] = a3[c];
        }
    }
}

/* e_k = exp(-s_k / tau) and p_k = (s_k / tau) e_k of K samples whose clock deviates from even
   spacing by dev_k (|dev_k| / tau below 1e-9): exp at the first sample of each block of BLOCK,
   the others e_first tab[j] (1 - dev_k / tau), tab[j] = exp(-j dt / tau). */
PK_CLONES
static void even_blocks(long long K, const double *s, const double *dev, double inv, const double *tab, double *e,
                        double *p)
{
    const v4 t0 = {tab[0], tab[1], tab[2], tab[3]}, t1 = {tab[4], tab[5], tab[6], tab[7]};
    const v4 one = {1.0, 1.0, 1.0, 1.0}, iv = {inv, inv, inv, inv};
    long long k = 0;
    for (; k + BLOCK <= K; k += BLOCK) {
        const double first = exp(-(s[k] * inv));
        const v4 f = {first, first, first, first};
        const v4 s0 = *(const v4 *)(s + k), s1 = *(const v4 *)(s + k + 4);
        const v4 d0 = *(const v4 *)(dev + k), d1 = *(const v4 *)(dev + k + 4);
        const v4 e0 = f * t0 * (one - d0 * iv), e1 = f * t1 * (one - d1 * iv);
        *(v4 *)(e + k) = e0;
        *(v4 *)(e + k + 4) = e1;
        *(v4 *)(p + k) = s0 * iv * e0;
        *(v4 *)(p + k + 4) = s1 * iv * e1;
    }
    if (k < K) {
        const double first = exp(-(s[k] * inv));
        for (int j = 0; k + j < K; j++) {
            e[k + j] = first * tab[j] * (1.0 - dev[k + j] * inv);
            p[k + j] = s[k + j] * inv * e[k + j];
        }
    }
}

/* (sum e, sum p, sum e e, sum e p, sum p p) over K samples */
PK_CLONES
static void moments(long long K, const double *e, const double *p, double *out)
{
    v4 a = {0, 0, 0, 0}, b = a, c = a, d = a, f = a;
    long long k = 0;
    for (; k + 4 <= K; k += 4) {
        const v4 ev = *(const v4 *)(e + k), pv = *(const v4 *)(p + k);
        a += ev; b += pv; c += ev * ev; d += ev * pv; f += pv * pv;
    }
    double r[5] = {a[0] + a[1] + a[2] + a[3], b[0] + b[1] + b[2] + b[3], c[0] + c[1] + c[2] + c[3],
                   d[0] + d[1] + d[2] + d[3], f[0] + f[1] + f[2] + f[3]};
    for (; k < K; k++) {
        r[0] += e[k]; r[1] += p[k]; r[2] += e[k] * e[k]; r[3] += e[k] * p[k]; r[4] += p[k] * p[k];
    }
    for (int i = 0; i < 5; i++) out[i] = r[i];
}

/* hold h: samples [ks[2 h], ks[2 h + 1]) of s (times from its first sample), y (rows of Jp >= 3 M
   columns: centred markers, zero where occluded and past 3 M), w (rows of M: 1 visible, 0
   occluded), full (1 where every marker is visible); time constants [ts[h], ts[h+1]) of taus;
   seen and yty (H, M). mode 0: rss[ts[h] + j]; mode 1: G and B at (ts[h] + j) * 9 M. The
   sums over a marker's visible samples are those over every sample less those over the samples
   where it is occluded. Returns 0, or -1 when out of memory. */
int pk_settle_fits(int H, int M, int Jp, const long long *ks, const long long *ts, const double *s, const double *y,
                   const double *w, const unsigned char *full, const unsigned char *seen, const double *yty,
                   const double *taus, int mode, double *rss, double *G, double *B)
{
    long long Kmax = 1;
    for (int h = 0; h < H; h++)
        if (ks[2 * h + 1] - ks[2 * h] > Kmax) Kmax = ks[2 * h + 1] - ks[2 * h];
    double *work = malloc(sizeof(double) * (size_t)(3 * Jp + 6 * M + 3 * Kmax));
    long long *occ = malloc(sizeof(long long) * (size_t)Kmax);
    if (!work || !occ) {
        free(work);
        free(occ);
        return -1;
    }
    double *bE = work, *bP = work + Jp, *sy = work + 2 * Jp, *am = work + 3 * Jp, *eb = am + 6 * M, *pb = eb + Kmax;
    double *dev = pb + Kmax;
    for (int h = 0; h < H; h++) {
        const long long k0 = ks[2 * h], K = ks[2 * h + 1] - ks[2 * h];
        const double *sh = s + k0, *yh = y + k0 * Jp, *wh = w + k0 * M;
        const unsigned char *fh = full + k0;
        const double last = sh[K - 1] > 1e-9 ? sh[K - 1] : 1e-9;
        const double dt = last / (double)(K > 1 ? K - 1 : 1);
        column_sums(K, Jp, yh, sy);
        long long nocc = 0;
        double devmax = 0.0;
        for (long long k = 0; k < K; k++) {
            if (!fh[k]) occ[nocc++] = k;
            const long long b = k - k % BLOCK;
            dev[k] = sh[k] - sh[b] - (double)(k - b) * dt;
            devmax = fmax(devmax, fabs(dev[k]));
        }
        for (long long q = ts[h]; q < ts[h + 1]; q++) {
            const double tau = taus[q], inv = 1.0 / tau;
            double tab[BLOCK];
            for (int j = 0; j < BLOCK; j++) tab[j] = exp(-(j * dt) * inv);
            if (devmax * inv < 1e-9) {
                even_blocks(K, sh, dev, inv, tab, eb, pb);
            } else {
                double e0 = 0;
                for (long long k = 0; k < K; k++) {
                    const int j = (int)(k % BLOCK);
                    const double x = sh[k] * inv;
                    if (j == 0) e0 = exp(-x);
                    const double d = dev[k] * inv;
                    eb[k] = j == 0 ? e0 : fabs(d) < 1e-9 ? e0 * tab[j] * (1.0 - d) : exp(-x);
                    pb[k] = x * eb[k];
                }
            }
            double mom[5];
            moments(K, eb, pb, mom);
            memset(am, 0, sizeof(double) * (size_t)(6 * M));
            for (long long i = 0; i < nocc; i++) {
                const long long k = occ[i];
                const double e = eb[k], p = pb[k], *wk = wh + k * M;
                for (int m = 0; m < M; m++) {
                    const double v = 1.0 - wk[m];
                    double *r = am + 6 * m;
                    r[0] += v;
                    r[1] += v * e;
                    r[2] += v * p;
                    r[3] += v * (e * e);
                    r[4] += v * (e * p);
                    r[5] += v * (p * p);
                }
            }
            const double n0 = (double)K, sE = mom[0], sP = mom[1], sEE = mom[2], sEP = mom[3], sPP = mom[4];
            products(K, Jp, eb, pb, yh, bE, bP);
            double total = 0.0;
            for (int m = 0; m < M; m++) {
                const double *r = am + 6 * m;
                double a00, a01, a02, a11, a12, a22;
                if (seen[h * M + m]) {
                    a00 = n0 - r[0]; a01 = sE - r[1]; a02 = sP - r[2];
                    a11 = sEE - r[3]; a12 = sEP - r[4]; a22 = sPP - r[5];
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
    free(occ);
    return 0;
}

/* numpy.linalg.lstsq of the n x 2 system A c = b from its normal equations N = A^T A (n00, n01,
   n11) and r = A^T b: the singular values below eps max(n, 2) of the largest are dropped (the
   minimum-norm solution), as lstsq's default rcond does. */
static void lstsq2(double n00, double n01, double n11, double r0, double r1, long long n, double *c)
{
    const double tr = n00 + n11, det = n00 * n11 - n01 * n01;
    const double half = 0.5 * tr, disc = sqrt(fmax(half * half - det, 0.0));
    const double l1 = half + disc, l2 = fmax(half - disc, 0.0); /* eigenvalues: squared singular values */
    const double rcond = 2.220446049250313e-16 * (double)(n > 2 ? n : 2);
    c[0] = c[1] = 0.0;
    if (!(l1 > 0.0)) return;
    if (sqrt(l2) > rcond * sqrt(l1)) {
        c[0] = (n11 * r0 - n01 * r1) / det;
        c[1] = (n00 * r1 - n01 * r0) / det;
        return;
    }
    /* rank one: along the eigenvector of l1 */
    double v0 = n01, v1 = l1 - n00;
    if (fabs(v0) + fabs(v1) == 0.0) { v0 = l1 - n11; v1 = n01; }
    if (fabs(v0) + fabs(v1) == 0.0) { v0 = 1.0; v1 = 0.0; }
    const double nv = sqrt(v0 * v0 + v1 * v1);
    v0 /= nv; v1 /= nv;
    const double a = (v0 * r0 + v1 * r1) / l1;
    c[0] = a * v0;
    c[1] = a * v1;
}

/* Each hold prepared for the fits, as platkit.settle._fits._prepare and _prony_tau do it: hold h
   is rows [ks[2 h], ks[2 h + 1]) of t and X (rows of 3 M: markers, NaN where occluded); written
   at the same rows: s (times from the hold's first), y (Jp columns: markers centred per marker
   over its visible samples, zero where occluded and past 3 M), w (M: 1 visible, 0 occluded),
   full (every marker visible); per hold: nok (M, visible samples), mean (M, 3), yty (M), and
   Prony's time constant tp (NaN: none). Returns 0, or -1 when out of memory. */
int pk_settle_prepare(int H, int M, int Jp, const long long *ks, const double *t, const double *X, double *s,
                      double *y, double *w, unsigned char *full, double *nok, double *mean, double *yty, double *tp)
{
    const int J = 3 * M;
    for (int h = 0; h < H; h++) {
        const long long k0 = ks[2 * h], K = ks[2 * h + 1] - ks[2 * h];
        double *nh = nok + (long long)h * M, *mh = mean + (long long)h * J;
        for (int c = 0; c < J; c++) mh[c] = 0.0;
        for (int m = 0; m < M; m++) nh[m] = 0.0;
        for (long long k = k0; k < k0 + K; k++) {
            const double *x = X + k * J;
            int all = 1;
            for (int m = 0; m < M; m++) {
                const int ok = isfinite(x[3 * m]) && isfinite(x[3 * m + 1]) && isfinite(x[3 * m + 2]);
                w[k * M + m] = ok ? 1.0 : 0.0;
                all &= ok;
                if (ok) {
                    nh[m] += 1.0;
                    for (int c = 0; c < 3; c++) mh[3 * m + c] += x[3 * m + c];
                }
            }
            full[k] = (unsigned char)all;
            s[k] = t[k] - t[k0];
        }
        for (int m = 0; m < M; m++)
            for (int c = 0; c < 3; c++) mh[3 * m + c] /= (nh[m] > 1.0 ? nh[m] : 1.0);
        double *qh = yty + (long long)h * M;
        for (int m = 0; m < M; m++) qh[m] = 0.0;
        for (long long k = k0; k < k0 + K; k++) {
            const double *x = X + k * J;
            double *yk = y + k * Jp;
            for (int m = 0; m < M; m++) {
                const int ok = w[k * M + m] > 0.0;
                for (int c = 0; c < 3; c++) {
                    const double v = ok ? x[3 * m + c] - mh[3 * m + c] : 0.0;
                    yk[3 * m + c] = v;
                    qh[m] += v * v;
                }
            }
            for (int c = J; c < Jp; c++) yk[c] = 0.0;
        }
        /* Prony: block means of L = max(1, K / 30) samples, their differences over the markers
           seen in every block, the second-order recurrence d[i+2] = c0 d[i+1] + c1 d[i] */
        tp[h] = NAN;
        const long long L = K / 30 > 1 ? K / 30 : 1, nb = K / L;
        if (nb < 8) continue;
        double *blocks = malloc(sizeof(double) * (size_t)(nb * J + nb * M));
        if (!blocks) return -1;
        double *cnt = blocks + nb * J;
        for (long long b = 0; b < nb; b++) {
            for (int m = 0; m < M; m++) {
                double n = 0.0, acc[3] = {0.0, 0.0, 0.0};
                for (long long k = k0 + b * L; k < k0 + (b + 1) * L; k++) {
                    const double v = w[k * M + m];
                    n += v;
                    for (int c = 0; c < 3; c++) acc[c] += y[k * Jp + 3 * m + c] * v;
                }
                cnt[b * M + m] = n;
                for (int c = 0; c < 3; c++) blocks[b * J + 3 * m + c] = acc[c] / (n > 1.0 ? n : 1.0);
            }
        }
        int any = 0;
        double n00 = 0, n01 = 0, n11 = 0, r0 = 0, r1 = 0;
        long long rows = 0;
        for (int m = 0; m < M; m++) {
            int seen = 1;
            for (long long b = 0; b < nb; b++) seen &= cnt[b * M + m] > 0.0;
            if (!seen) continue;
            any = 1;
            for (int c = 0; c < 3; c++) {
                const int col = 3 * m + c;
                for (long long i = 0; i + 3 < nb; i++) {
                    const double d0 = blocks[(i + 1) * J + col] - blocks[i * J + col];
                    const double d1 = blocks[(i + 2) * J + col] - blocks[(i + 1) * J + col];
                    const double d2 = blocks[(i + 3) * J + col] - blocks[(i + 2) * J + col];
                    n00 += d1 * d1; n01 += d1 * d0; n11 += d0 * d0;
                    r0 += d1 * d2; r1 += d0 * d2;
                    rows++;
                }
            }
        }
        free(blocks);
        if (!any) continue;
        double coef[2];
        lstsq2(n00, n01, n11, r0, r1, rows, coef);
        const double c0 = coef[0], c1 = coef[1], disc = c0 * c0 + 4.0 * c1;
        const double r = disc >= 0 ? (fabs(c0) + sqrt(disc)) / 2.0 : sqrt(-c1);
        if (!(0 < r && r < 1)) continue;
        const double last = s[k0 + K - 1] > 1e-9 ? s[k0 + K - 1] : 1e-9;
        const double dt = last / (double)(K > 1 ? K - 1 : 1);
        tp[h] = -(double)L * dt / log(r);
    }
    return 0;
}

/* The still test's halves of one stretch, number for number as platkit.settle._still._halves
   computes them with numpy (elementwise operations and running sums in sample order: the same
   roundings): X (K, 3 M) markers (NaN: occluded; rows ld apart); for each sample k the means of each marker over
   the visible samples among the n before k (mb) and the n from k on (ma), both (K, M, 3), and
   their counts nb, na (K, M); windows clipped to the stretch. Returns 0, or -1 when out of
   memory. */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=off")))
#endif
int pk_settle_halves(long long K, int M, int n, const double *X, long long ld, double *mb, double *ma, double *nb,
                     double *na)
{
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    const int J = 3 * M;
    double *S = malloc(sizeof(double) * (size_t)((K + 1) * J));
    double *C = malloc(sizeof(double) * (size_t)((K + 1) * M));
    if (!S || !C) {
        free(S);
        free(C);
        return -1;
    }
    for (int c = 0; c < J; c++) S[c] = 0.0;
    for (int m = 0; m < M; m++) C[m] = 0.0;
    for (long long k = 0; k < K; k++) {
        const double *x = X + k * ld;
        for (int m = 0; m < M; m++) {
            const int ok = isfinite(x[3 * m]) && isfinite(x[3 * m + 1]) && isfinite(x[3 * m + 2]);
            C[(k + 1) * M + m] = C[k * M + m] + (ok ? 1.0 : 0.0);
            for (int c = 3 * m; c < 3 * m + 3; c++) {
                const double v = ok ? x[c] : 0.0;
                S[(k + 1) * J + c] = k == 0 ? v : S[k * J + c] + v; /* cumsum's first is the value itself */
            }
        }
    }
    for (long long k = 0; k < K; k++) {
        const long long a = k - n > 0 ? k - n : 0, b = k + n < K ? k + n : K;
        for (int m = 0; m < M; m++) {
            const double cb = C[k * M + m] - C[a * M + m], ca = C[b * M + m] - C[k * M + m];
            nb[k * M + m] = cb;
            na[k * M + m] = ca;
            const double db = cb > 1.0 ? cb : 1.0, da = ca > 1.0 ? ca : 1.0;
            for (int c = 3 * m; c < 3 * m + 3; c++) {
                mb[k * J + c] = (S[k * J + c] - S[a * J + c]) / db;
                ma[k * J + c] = (S[b * J + c] - S[k * J + c]) / da;
            }
        }
    }
    free(S);
    free(C);
    return 0;
}

/* numpy's sum of n contiguous doubles (its reduction: 0 plus the pairwise sum, eight
   accumulators in blocks of at most 128), the same roundings */
static double np_pairwise(const double *a, long long n)
{
    if (n < 8) {
        double r = 0.0;
        for (long long i = 0; i < n; i++) r += a[i];
        return r;
    }
    if (n <= 128) {
        double r[8];
        long long i;
        for (int j = 0; j < 8; j++) r[j] = a[j];
        for (i = 8; i < n - (n % 8); i += 8)
            for (int j = 0; j < 8; j++) r[j] += a[i + j];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++) res += a[i];
        return res;
    }
    long long n2 = n / 2;
    n2 -= n2 % 8;
    return np_pairwise(a, n2) + np_pairwise(a + n2, n - n2);
}

/* The still test's statistic and the approach's speed of one stretch, number for number as
   platkit.settle._still.still_mask and approach_start compute them with numpy from the halves
   (pk_settle_halves): per sample k, m[k] the markers visible in both halves, stat[k] the mean
   over them of |ma - mb|^2 / (sigma2 (1 / nb + 1 / na)), num[k] the sum of |ma - mb|^2 over them.
   Returns 0, or -1 when out of memory. */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=off")))
#endif
int pk_settle_still(long long K, int M, int n, const double *X, long long ld, double sigma2, double *stat, double *num,
                    double *m)
{
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    const int J = 3 * M;
    double *mb = malloc(sizeof(double) * (size_t)(K * J)), *ma = malloc(sizeof(double) * (size_t)(K * J));
    double *nb = malloc(sizeof(double) * (size_t)(K * M)), *na = malloc(sizeof(double) * (size_t)(K * M));
    double *z = malloc(sizeof(double) * (size_t)(J + M));
    int code = -1;
    if (mb && ma && nb && na && z && pk_settle_halves(K, M, n, X, ld, mb, ma, nb, na) == 0) {
        double *sq = z + M;
        for (long long k = 0; k < K; k++) {
            int seen = 0;
            for (int j = 0; j < M; j++) {
                const double cb = nb[k * M + j], ca = na[k * M + j];
                const int vis = cb > 0 && ca > 0;
                double d2 = 0.0;
                for (int c = 3 * j; c < 3 * j + 3; c++) {
                    const double d = ma[k * J + c] - mb[k * J + c];
                    sq[c] = vis ? d * d : 0.0;
                    d2 += d * d;
                }
                const double scale2 = sigma2 * (1.0 / (cb > 1.0 ? cb : 1.0) + 1.0 / (ca > 1.0 ? ca : 1.0));
                z[j] = vis ? d2 / scale2 : 0.0;
                seen += vis;
            }
            m[k] = seen;
            stat[k] = (0.0 + np_pairwise(z, M)) / (seen > 1 ? seen : 1);
            num[k] = 0.0 + np_pairwise(sq, J);
        }
        code = 0;
    }
    free(mb);
    free(ma);
    free(nb);
    free(na);
    free(z);
    return code;
}

/* The trend test of a window (platkit.settle._still.trend_test): t (K) times, X (K, 3 M)
   markers (NaN: occluded; rows ld apart); per marker seen in at least 4 samples whose times spread, the
   regression of each coordinate on time over those samples: *stat the chi-square of the slopes
   against sigma2 (sum of slope^2 sxx / sigma2), *dof 3 per such marker, *vmax the largest speed
   |slope|. The means and the sum of squares of the times are numpy's (pairwise) sums; the
   products with the markers are summed in sample order (numpy's are BLAS's): the statistic
   agrees to rounding. Returns 0, or -1 when out of memory. */
int pk_settle_trend(long long K, int M, const double *t, const double *X, long long ld, double sigma2, double *stat,
                    double *dof, double *vmax)
{
    double *tt = malloc(sizeof(double) * (size_t)(K > 0 ? 4 * K : 1));
    if (!tt) return -1;
    double *xs = tt + K;
    *stat = 0.0;
    *dof = 0.0;
    *vmax = 0.0;
    for (int m = 0; m < M; m++) {
        long long n = 0;
        for (long long k = 0; k < K; k++) {
            const double *x = X + k * ld + 3 * m;
            if (isfinite(x[0]) && isfinite(x[1]) && isfinite(x[2])) {
                tt[n] = t[k];
                for (int c = 0; c < 3; c++) xs[c * K + n] = x[c];
                n++;
            }
        }
        if (n < 4) continue;
        const double tm = np_pairwise(tt, n) / (double)n;
        for (long long i = 0; i < n; i++) tt[i] -= tm;
        double sxx = 0.0, slope[3];
        {
            double *sq = malloc(sizeof(double) * (size_t)n);
            if (!sq) { free(tt); return -1; }
            for (long long i = 0; i < n; i++) sq[i] = tt[i] * tt[i];
            sxx = np_pairwise(sq, n);
            free(sq);
        }
        if (!(sxx > 0)) continue;
        for (int c = 0; c < 3; c++) {
            const double *col = xs + c * K;
            const double mean = np_pairwise(col, n) / (double)n;
            double acc = 0.0;
            for (long long i = 0; i < n; i++) acc += tt[i] * (col[i] - mean);
            slope[c] = acc / sxx;
        }
        *stat += (slope[0] * slope[0] + slope[1] * slope[1] + slope[2] * slope[2]) * sxx / sigma2;
        *dof += 3.0;
        const double v = sqrt(slope[0] * slope[0] + slope[1] * slope[1] + slope[2] * slope[2]);
        *vmax = v > *vmax ? v : *vmax;
    }
    free(tt);
    return 0;
}

/* the k-th smallest of x[0..n) (x reordered: none larger before k, none smaller after) */
static double select_kth(double *x, long long n, long long k)
{
    long long lo = 0, hi = n - 1;
    while (hi > lo) {
        const long long mid = lo + (hi - lo) / 2;
        const double a = x[lo], b = x[mid], c = x[hi];
        const double pivot = a < b ? (b < c ? b : (a < c ? c : a)) : (a < c ? a : (b < c ? c : b));
        long long i = lo, j = hi;
        while (i <= j) {
            while (x[i] < pivot) i++;
            while (x[j] > pivot) j--;
            if (i <= j) {
                const double t = x[i];
                x[i] = x[j];
                x[j] = t;
                i++;
                j--;
            }
        }
        if (k <= j) hi = j;
        else if (k >= i) lo = i;
        else return x[k];
    }
    return x[k];
}

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* the second difference at row k (1 <= k < K - 1), column c of X (K, J), as numpy takes it:
   x[k] (-2), plus x[k+1], plus x[k-1] */
#define SECOND_DIFF(k, c) (((X[(k) * ld + (c)] * -2.0) + X[((k) + 1) * ld + (c)]) + X[((k) - 1) * ld + (c)])

/* numpy.median of the n finite values v of the second differences of X (absolute: of |v - shift|):
   the middle order statistic, or the two middle ones' sum over 2. The order statistics are found
   among the values between two quantiles of the sample (ns sorted values of the same kind), one
   pass counting those below and gathering those between into buf (room for cap); 0 when they
   fall outside (the caller then selects over every value). */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=off")))
#endif
static int median_between(long long K, int J, const double *X, long long ld, long long n, double shift, int absolute,
                          const double *sample, int ns, double *buf, long long cap, double *out)
{
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    const long long h = n / 2, first = n % 2 ? h : h - 1;
    const int margin = 64 + ns / 16;
    const long long q = (long long)((double)h / (double)n * ns);
    const double lo = sample[q - margin > 0 ? q - margin : 0], hi = sample[q + margin < ns - 1 ? q + margin : ns - 1];
    long long below = 0, m = 0;
    for (long long k = 1; k + 1 < K; k++)
        for (int c = 0; c < J; c++) {
            double v = SECOND_DIFF(k, c);
            if (!isfinite(v)) continue;
            if (absolute) v = fabs(v - shift);
            if (v < lo) below++;
            else if (v <= hi) {
                if (m == cap) return 0;
                buf[m++] = v;
            }
        }
    if (!(below <= first && h < below + m)) return 0;
    const double upper = select_kth(buf, m, h - below);
    if (n % 2) {
        *out = upper;
        return 1;
    }
    double lower = buf[0];
    for (long long i = 1; i < h - below; i++) lower = buf[i] > lower ? buf[i] : lower;
    *out = (lower + upper) / 2.0;
    return 1;
}

/* numpy.median over every finite value (absolute: of |v - shift|), by selection (x: room for n) */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=off")))
#endif
static double median_all(long long K, int J, const double *X, long long ld, long long n, double shift, int absolute,
                         double *x)
{
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    long long m = 0;
    for (long long k = 1; k + 1 < K; k++)
        for (int c = 0; c < J; c++) {
            const double v = SECOND_DIFF(k, c);
            if (isfinite(v)) x[m++] = absolute ? fabs(v - shift) : v;
        }
    const long long h = n / 2;
    const double upper = select_kth(x, n, h);
    if (n % 2) return upper;
    double lower = x[0];
    for (long long i = 1; i < h; i++) lower = x[i] > lower ? x[i] : lower;
    return (lower + upper) / 2.0;
}

/* The median absolute deviation of the second differences of a stream X (K rows of J values,
   ld apart; NaN: occluded) over every finite one, as platkit.settle._still.estimate_noise takes it with
   numpy (the same differences, medians being order statistics): *mad (NaN under 10 values) and
   the count of finite differences. The differences are computed in each pass, not kept.
   Returns 0, or -1 when out of memory. */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=off")))
#endif
int pk_settle_mad(long long K, int J, const double *X, long long ld, double *mad, long long *count)
{
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    enum { SAMPLE = 4096 };
    double sample[SAMPLE];
    *count = 0;
    *mad = NAN;
    if (K < 3) return 0;
    const long long total = (K - 2) * J, step = total / SAMPLE > 1 ? total / SAMPLE : 1;
    long long n = 0, next = 0, at = 0;
    int ns = 0;
    for (long long k = 1; k + 1 < K; k++)
        for (int c = 0; c < J; c++, at++) {
            const double v = SECOND_DIFF(k, c);
            if (!isfinite(v)) continue;
            if (at >= next && ns < SAMPLE) {
                sample[ns++] = v;
                next = at + step;
            }
            n++;
        }
    *count = n;
    if (n < 10) return 0;
    const long long cap = n / 4 + 1024 < n ? n / 4 + 1024 : n;
    double *buf = malloc(sizeof(double) * (size_t)cap), *all = NULL;
    if (!buf) return -1;
    double med, out;
    qsort(sample, (size_t)ns, sizeof(double), cmp_double);
    if (ns >= 256 && median_between(K, J, X, ld, n, 0.0, 0, sample, ns, buf, cap, &out)) {
        med = out;
    } else {
        if (!(all = malloc(sizeof(double) * (size_t)n))) { free(buf); return -1; }
        med = median_all(K, J, X, ld, n, 0.0, 0, all);
    }
    for (int i = 0; i < ns; i++) sample[i] = fabs(sample[i] - med);
    qsort(sample, (size_t)ns, sizeof(double), cmp_double);
    if (ns >= 256 && median_between(K, J, X, ld, n, med, 1, sample, ns, buf, cap, &out)) {
        *mad = out;
    } else {
        if (!all && !(all = malloc(sizeof(double) * (size_t)n))) { free(buf); return -1; }
        *mad = median_all(K, J, X, ld, n, med, 1, all);
    }
    free(buf);
    free(all);
    return 0;
}
#undef SECOND_DIFF
