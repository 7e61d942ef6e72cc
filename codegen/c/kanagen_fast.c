/* kanagen's compiled fast path in C: a mechanical port of the NumPy runtime's measure
 * projection (coherence_errors, eq. 22–24), closest square root and minimal solve (eq. 21),
 * and the evaluations of a family's functions (docs/fastpath.md). The entry points are
 * kg_coherence, kg_minimal, kg_closest_root, kg_sizes, kg_equations and kg_eval (the local
 * fit's restorations run in the engine's kernels, runtime/engine, since 2026-11-26); the robust
 * search's sample (kanagen_sample.c) calls kg_read, kg_coherence_at and kg_minimal_solve,
 * the closed forms (kanagen_geometry.c) kg_jacobi and kg_column_norms. (The compiled local
 * fit, kg_fit, was removed on 2026-11-25, issue 17: the local fit runs runtime/iterate.py.)
 *
 * Compiled in one translation unit after CasADi's C of a family and the family's generated
 * tables (codegen/templates/c/family.c.jinja), which define:
 *   KG_N, KG_NK, KG_NCH, KG_NMODELS, KG_NDERIVED, KG_NSLACK, KG_MAXP, KG_MAXW;
 *   kg_width[], kg_ncorr[], kg_index_off[], kg_index[], kg_p0[], kg_p[]; kg_c0(),
 *   kg_measure() (row-major outputs);
 * and KG_MAXP, KG_MAXK, KG_MAXW (largest equation, corrected and component counts) and
 * KG_UNIFORM_P, KG_UNIFORM_K (the counts when every channel of every model has the same,
 * else 0: then the per-measure loops have fixed sizes and unroll, report §6). (The derived
 * and slack tables, kg_derived() and kg_slack() went with kg_fit, their only reader.)
 * Every function says which Python function it ports; constants keep the Python names.
 * Matrices are row-major. "NumPy max" propagates NaN; Python's max(a, b) is b > a ? b : a.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* runtime/sqrt.py */
#define KG_TINY DBL_MIN                 /* _TINY = np.finfo(float).tiny */
#define KG_REDUNDANT (1e3 * DBL_EPSILON) /* REDUNDANT */
/* runtime/projector.py */
#define KG_ROUNDING (1e3 * DBL_EPSILON)  /* _ROUNDING */
/* runtime/projector.py: _halving(halvings=4) */
#define KG_HALVINGS 4

#define KG_P(p) (KG_UNIFORM_P > 0 ? KG_UNIFORM_P : (p))
#define KG_K(k) (KG_UNIFORM_K > 0 ? KG_UNIFORM_K : (k))

static double kg_nanmax_abs(long count, const double *v) /* np.abs(v).max() (NaN wins) */
{
    double top = 0.0;
    for (long i = 0; i < count; ++i) {
        double a = fabs(v[i]);
        if (a != a) return a;
        if (a > top) top = a;
    }
    return top;
}

/* ------------------------------------------------------------------ runtime/sqrt.py */

/* _equilibrium for one matrix */
static inline void kg_equilibrium(int n, const double *S, double *d)
{
    double scale = 0.0; /* diag.max(initial=0.0), NaN propagates */
    for (int i = 0; i < n; ++i) {
        double v = S[i * n + i];
        if (v != v || scale != scale) scale = NAN;
        else if (v > scale) scale = v;
    }
    if (!(scale > KG_TINY)) scale = 1.0;
    for (int i = 0; i < n; ++i) {
        double v = S[i * n + i];
        d[i] = sqrt(v > KG_TINY * scale ? v : scale);
    }
}

/* closest_sqrt (one matrix): Cholesky of the equilibrated matrix with the pivot fix */
static void kg_closest_sqrt(int n, const double *S, double eps, double *L)
{
    double d[KG_N + 1];
    if (eps < KG_REDUNDANT) eps = KG_REDUNDANT;
    kg_equilibrium(n, S, d);
    memset(L, 0, sizeof(double) * n * n);
    for (int k = 0; k < n; ++k) {
        double piv = S[k * n + k] / (d[k] * d[k]);
        for (int j = 0; j < k; ++j) piv -= L[k * n + j] * L[k * n + j];
        int fixed = !(piv > eps);
        L[k * n + k] = sqrt(fixed ? eps : piv);
        for (int i = k + 1; i < n; ++i) {
            double rest = S[i * n + k] / (d[i] * d[k]);
            for (int j = 0; j < k; ++j) rest -= L[i * n + j] * L[k * n + j];
            /* below a vanishing pivot a PSD matrix has a vanishing column: rounding noise */
            L[i * n + k] = fixed ? 0.0 : rest / L[k * n + k];
        }
    }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j <= i; ++j) L[i * n + j] *= d[i];
}

/* reduced_sqrt (one matrix): a row whose pivot is too small is dropped */
static inline void kg_reduced_sqrt(int n, const double *S, double eps, double *L, int *kept)
{
    double scale = 0.0;
    for (int i = 0; i < n; ++i) {
        double v = S[i * n + i];
        if (v != v || scale != scale) scale = NAN;
        else if (v > scale) scale = v;
    }
    double tol = eps * (scale > KG_TINY || scale != scale ? scale : KG_TINY);
    memset(L, 0, sizeof(double) * n * n);
    for (int k = 0; k < n; ++k) {
        double piv = S[k * n + k];
        for (int j = 0; j < k; ++j) piv -= L[k * n + j] * L[k * n + j];
        int keep = (piv > tol) && (piv > KG_REDUNDANT * S[k * n + k]);
        kept[k] = keep;
        double root = sqrt(keep ? piv : 1.0);
        if (!keep)
            for (int j = 0; j < k; ++j) L[k * n + j] = 0.0;
        L[k * n + k] = keep ? root : 0.0;
        for (int i = k + 1; i < n; ++i) {
            double rest = S[i * n + k];
            for (int j = 0; j < k; ++j) rest -= L[i * n + j] * L[k * n + j];
            L[i * n + k] = keep ? rest / root : 0.0;
        }
    }
}

/* ------------------------------------------------------------- runtime/kernels.py */

/* whiten for one measure: E = D Gᵀ (p × k), L the reduced root of E Eᵀ, B ← L⁻¹ B (t
 * columns); returns the number of kept equations */
static inline int kg_whiten(int p, int k, const double *D, const double *G, int t, double *B,
                     double eps, double *E, double *L, int *kept)
{
    double S[KG_MAXP * KG_MAXP + 1];
    for (int a = 0; a < p; ++a)
        for (int j = 0; j < k; ++j) {
            double acc = 0.0;
            for (int l = 0; l <= j; ++l) acc += D[a * k + l] * G[j * k + l];
            E[a * k + j] = acc;
        }
    for (int a = 0; a < p; ++a)
        for (int b = 0; b <= a; ++b) {
            double acc = 0.0;
            for (int j = 0; j < k; ++j) acc += E[a * k + j] * E[b * k + j];
            S[a * p + b] = S[b * p + a] = acc;
        }
    kg_reduced_sqrt(p, S, eps, L, kept);
    int rank = 0;
    for (int a = 0; a < p; ++a) { /* reduced_solve (batched): multiply by inverse pivots */
        double inv = kept[a] ? 1.0 / L[a * p + a] : 0.0;
        rank += kept[a];
        for (int c = 0; c < t; ++c) {
            double acc = B[a * t + c];
            for (int j = 0; j < a; ++j) acc -= L[a * p + j] * B[j * t + c];
            B[a * t + c] = acc * inv;
        }
    }
    return rank;
}

/* correct for one measure: dm = Gᵀ Eᵀ L⁻ᵀ z */
static inline void kg_correct(int p, int k, const double *E, const double *L, const int *kept,
                       const double *G, const double *z, double *dm)
{
    double y[KG_MAXP + 1], t[KG_MAXK + 1];
    for (int a = p - 1; a >= 0; --a) { /* reduced_solve (batched), transposed */
        double acc = z[a];
        for (int i = a + 1; i < p; ++i) acc -= L[i * p + a] * y[i];
        y[a] = acc * (kept[a] ? 1.0 / L[a * p + a] : 0.0);
    }
    for (int j = 0; j < k; ++j) {
        double acc = 0.0;
        for (int a = 0; a < p; ++a) acc += E[a * k + j] * y[a];
        t[j] = acc;
    }
    for (int l = 0; l < k; ++l) {
        double acc = 0.0;
        for (int j = l; j < k; ++j) acc += G[j * k + l] * t[j];
        dm[l] = acc;
    }
}

/* --------------------------------------------------------------- the problem */

typedef struct { /* inputs.ChannelData */
    int id, w, k, p;
    long M;
    const int *index;
    const double *X, *Q, *G;
    int per_measure;
    double *m; /* observed corrected components, M × k */
} kg_channel;

typedef struct { /* projector.Problem: what the projection and the minimal solve read */
    int model, p0, nch;
    kg_channel *ch;
    const double *k;
    double eps;
} kg_problem;

typedef struct { /* projector.Point's measures: per channel m̃ and the equations at it */
    double **mt, **c, **C, **D;
} kg_point;

static const double *kg_Q(const kg_channel *ch, long i)
{
    return ch->per_measure ? ch->Q + i * ch->k * ch->k : ch->Q;
}

static const double *kg_G(const kg_channel *ch, long i)
{
    return ch->per_measure ? ch->G + i * ch->k * ch->k : ch->G;
}

/* ChannelData.with_corrected for one measure: the measure itself when every component
 * is corrected (in order), else the data row with the corrected components replaced */
static inline const double *kg_with_corrected(const kg_channel *ch, long i, const double *m,
                                              double *x)
{
    if (ch->k == ch->w) return m;
    for (int j = 0; j < ch->w; ++j) x[j] = ch->X[i * ch->w + j];
    for (int j = 0; j < ch->k; ++j) x[ch->index[j]] = m[j];
    return x;
}

/* quadratic for one measure: vᵀ Q v */
static inline double kg_quadratic(int k, const double *v, const double *Q)
{
    double acc = 0.0;
    for (int a = 0; a < k; ++a) {
        double row = 0.0;
        for (int b = 0; b < k; ++b) row += Q[a * k + b] * v[b];
        acc += v[a] * row;
    }
    return acc;
}

/* ------------------------------------------------------------ runtime/projector.py */

/* _halving() for one measure: m + α step, α halved while the violation grows */
static void kg_halving(const kg_problem *pb, const kg_channel *ch, long i, const double *q,
                       double *m, double *c, double *C, double *D, const double *step,
                       double *moved)
{
    const int k = KG_K(ch->k), p = KG_P(ch->p), n = KG_N;
    double worst = p ? kg_nanmax_abs(p, c) : 0.0;
    double alpha = 1.0, cand[KG_MAXK + 1], xi[KG_MAXW + 1];
    int grew = 0;
    for (int h = 0; h < KG_HALVINGS; ++h) {
        for (int j = 0; j < k; ++j) cand[j] = m[j] + alpha * step[j];
        kg_measure(pb->model, ch->id, q, kg_with_corrected(ch, i, cand, xi), pb->k, c, C, D);
        double new_worst = p ? kg_nanmax_abs(p, c) : worst;
        grew = !(new_worst <= worst + 1e-9 * (1.0 + worst));
        if (!grew) break;
        alpha /= 2;
    }
    if (grew) { /* the for-else: a measure still growing stays where it is */
        alpha = 0.0;
        for (int j = 0; j < k; ++j) cand[j] = m[j] + alpha * step[j];
        kg_measure(pb->model, ch->id, q, kg_with_corrected(ch, i, cand, xi), pb->k, c, C, D);
    }
    (void)n;
    for (int j = 0; j < k; ++j) {
        moved[j] = cand[j] - m[j];
        m[j] = cand[j];
    }
}

/* project_measures(): each measure onto c_i(q, ·) = 0 in its Q_i metric (eq. 22), with
 * eq. 18's halving per measure; writes mt, the equations at the returned point, and the
 * whitened violation and the rank of each measure */
static void kg_project_measures(const kg_problem *pb, const double *q, double *const *mt_in,
                                kg_point *out, int iterations, double tol, double **violation,
                                int **rank)
{
    const int n = KG_N;
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        const int k = KG_K(ch->k), p = KG_P(ch->p);
        double *mt = out->mt[c], *cc = out->c[c], *CC = out->C[c], *DD = out->D[c];
        for (long i = 0; i < ch->M; ++i) {
            double *m = mt + i * k, *ci = cc + i * p;
            double *Ci = CC + i * p * n, *Di = DD + i * p * k;
            const double *mobs = ch->m + i * k, *G = kg_G(ch, i);
            double xi[KG_MAXW + 1], B[2 * KG_MAXP + 1];
            double E[KG_MAXP * KG_MAXK + 1], L[KG_MAXP * KG_MAXP + 1];
            int kept[KG_MAXP + 1], active = 1, rk = 0;
            double viol = 0.0;
            if (m != mt_in[c] + i * k) memcpy(m, mt_in[c] + i * k, sizeof(double) * k);
            kg_measure(pb->model, ch->id, q, kg_with_corrected(ch, i, m, xi), pb->k, ci, Ci, Di);
            for (int it = 0; it < iterations; ++it) {
                for (int a = 0; a < p; ++a) { /* r − C q with q fixed */
                    double acc = 0.0;
                    for (int j = 0; j < k; ++j) acc += Di[a * k + j] * (m[j] - mobs[j]);
                    B[a * 2] = acc - ci[a];
                    B[a * 2 + 1] = ci[a];
                }
                rk = kg_whiten(p, k, Di, G, 2, B, pb->eps, E, L, kept);
                viol = 0.0;
                for (int a = 0; a < p; ++a) viol += B[a * 2 + 1] * B[a * 2 + 1];
                if (it == iterations - 1 || !active) break;
                double z[KG_MAXP + 1], dm[KG_MAXK + 1], step[KG_MAXK + 1];
                double moved[KG_MAXK + 1];
                for (int a = 0; a < p; ++a) z[a] = B[a * 2];
                kg_correct(p, k, E, L, kept, G, z, dm);
                int finite = 1;
                for (int j = 0; j < k; ++j) {
                    step[j] = mobs[j] + dm[j] - m[j];
                    finite &= isfinite(step[j]) != 0;
                }
                if (!finite)
                    for (int j = 0; j < k; ++j) step[j] = 0.0;
                kg_halving(pb, ch, i, q, m, ci, Ci, Di, step, moved);
                int seen = kg_quadratic(k, moved, kg_Q(ch, i)) > tol * tol, unseen = 0;
                for (int j = 0; j < k; ++j)
                    unseen |= fabs(moved[j]) > KG_ROUNDING * (1.0 + fabs(m[j]));
                active = active && (seen || unseen);
            }
            violation[c][i] = viol;
            rank[c][i] = rk;
        }
    }
}

/* -------------------------------------------- the SVD by one-sided Jacobi rotations */

/* One-sided Jacobi (Hestenes): the columns of A (rows × cols, row-major) rotated until
 * orthogonal, the rotations accumulated in V (cols × cols, row-major) when not NULL; the
 * singular values are then the column norms (kg_column_norms). A pair of columns one of
 * which has a squared norm at most floor is not rotated (0: every pair, kg_minimal_step;
 * the null spaces of kanagen_geometry.c pass the rounding level of A, kg_jacobi_null) */
static void kg_jacobi(long rows, int cols, double *A, double *V, double floor)
{
    for (int sweep = 0; sweep < 60; ++sweep) {
        int rotated = 0;
        for (int a = 0; a < cols - 1; ++a)
            for (int b = a + 1; b < cols; ++b) {
                double aa = 0.0, bb = 0.0, ab = 0.0;
                for (long i = 0; i < rows; ++i) {
                    aa += A[i * cols + a] * A[i * cols + a];
                    bb += A[i * cols + b] * A[i * cols + b];
                    ab += A[i * cols + a] * A[i * cols + b];
                }
                if (aa <= floor || bb <= floor || fabs(ab) <= DBL_EPSILON * sqrt(aa * bb))
                    continue;
                rotated = 1;
                double zeta = (bb - aa) / (2 * ab);
                double t = (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(zeta * zeta + 1));
                double cs = 1 / sqrt(t * t + 1), sn = t * cs;
                for (long i = 0; i < rows; ++i) {
                    double va = A[i * cols + a], vb = A[i * cols + b];
                    A[i * cols + a] = cs * va - sn * vb;
                    A[i * cols + b] = sn * va + cs * vb;
                }
                for (int i = 0; V && i < cols; ++i) {
                    double va = V[i * cols + a], vb = V[i * cols + b];
                    V[i * cols + a] = cs * va - sn * vb;
                    V[i * cols + b] = sn * va + cs * vb;
                }
            }
        if (!rotated) break;
    }
}

/* The norms of the columns of A (rows × cols, row-major) into S; their largest returned */
static double kg_column_norms(long rows, int cols, const double *A, double *S)
{
    double top = 0.0;
    for (int j = 0; j < cols; ++j) {
        double acc = 0.0;
        for (long i = 0; i < rows; ++i) acc += A[i * cols + j] * A[i * cols + j];
        S[j] = sqrt(acc);
        top = S[j] > top ? S[j] : top;
    }
    return top;
}

/* ---------------------------------------------------- the input of the entry points */

typedef struct { /* a bump allocator: a first pass counts, the second hands out memory */
    char *base;
    size_t used;
} kg_arena;

static void *kg_take(kg_arena *a, size_t bytes)
{
    size_t at = (a->used + 15) & ~(size_t)15;
    a->used = at + bytes;
    return a->base ? a->base + at : NULL;
}

#define KG_TAKE(a, type, count) ((type *)kg_take((a), sizeof(type) * (size_t)(count)))

/* room for a point's measures and equations (kg_coherence_at) */
static void kg_layout_point(kg_arena *a, const kg_problem *pb, kg_point *pt)
{
    const int n = KG_N;
    pt->mt = KG_TAKE(a, double *, pb->nch);
    pt->c = KG_TAKE(a, double *, pb->nch);
    pt->C = KG_TAKE(a, double *, pb->nch);
    pt->D = KG_TAKE(a, double *, pb->nch);
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        double *mt = KG_TAKE(a, double, ch->M * ch->k), *cc = KG_TAKE(a, double, ch->M * ch->p);
        double *C = KG_TAKE(a, double, ch->M * ch->p * n);
        double *D = KG_TAKE(a, double, ch->M * ch->p * ch->k);
        if (a->base) {
            pt->mt[c] = mt;
            pt->c[c] = cc;
            pt->C[c] = C;
            pt->D[c] = D;
        }
    }
}

/* The problem of kg_coherence's and kg_minimal's input (kanagen_sample.c's kg_sample and
 * kg_search read theirs with it), packed by runtime/fastpath.py (FastPath._layout), integers
 * as doubles:
 *   model, nch, max_iter, guard, eps, xtol, the number of strict slacks, prior (Q0 is
 *   given, else 0), then per channel its id, M, per_measure; per strict slack its
 *   component and power; start (n), q0 (n), Q0 (n × n, when prior), k (constants), then
 *   per channel X (M × w), Q and G (k × k, or M × k × k when per_measure).
 * max_iter, xtol and start are the caller's (kg_coherence: the projector steps plus one,
 * the tolerance and the q at which the measures are projected; kg_minimal: solve_minimal's
 * max_iter, xtol and target). guard, the strict slacks, q0 and Q0 are the slots of the
 * input of the compiled local fit (kg_fit, removed on 2026-11-25, issue 17): read past,
 * not used (the Python packs no strict slack and no prior, and the start as q0). Returns 1
 * when the sizes are out of range or the start, q0 or a measure is not finite. The caller
 * checks nch (0 <= nch <= KG_NCH, the room in channels). */
static int kg_read(const double *in, kg_problem *pb, kg_channel *channels, int *max_iter,
                   double *xtol, const double **q_start)
{
    int nch = (int)in[1], n = KG_N;
    pb->model = (int)in[0];
    pb->p0 = kg_p0[pb->model];
    pb->nch = nch;
    pb->ch = channels;
    pb->eps = in[4];
    *max_iter = (int)in[2];
    *xtol = in[5];
    const int nstrict = (int)in[6], prior = (int)in[7];
    if (nstrict < 0 || nstrict > KG_NSLACK) return 1;
    const double *head = in + 8, *qs = head + 3 * nch + 2 * nstrict, *q0 = qs + n;
    *q_start = qs;
    pb->k = q0 + n + (prior ? n * n : 0);
    const double *at = pb->k + KG_NK;
    for (int u = 0; u < n; ++u)
        if (!isfinite(qs[u]) || !isfinite(q0[u])) return 1;
    for (int c = 0; c < nch; ++c) {
        kg_channel *ch = &channels[c];
        ch->id = (int)head[3 * c];
        ch->M = (long)head[3 * c + 1];
        ch->per_measure = (int)head[3 * c + 2];
        ch->w = kg_width[ch->id];
        ch->k = kg_ncorr[ch->id];
        ch->p = kg_p[pb->model * (KG_NCH > 0 ? KG_NCH : 1) + ch->id];
        ch->index = kg_index + kg_index_off[ch->id];
        long qsize = (ch->per_measure ? ch->M : 1) * ch->k * ch->k;
        ch->X = at;
        ch->Q = at + ch->M * ch->w;
        ch->G = ch->Q + qsize;
        at = ch->G + qsize;
        for (long j = 0; j < ch->M * ch->w; ++j)
            if (!isfinite(ch->X[j])) return 1;
    }
    return 0;
}

/* ChannelData.m (the corrected components of X) of every channel */
static void kg_channel_data(kg_problem *pb)
{
    for (int c = 0; c < pb->nch; ++c) {
        kg_channel *ch = &pb->ch[c];
        for (long i = 0; i < ch->M; ++i)
            for (int j = 0; j < ch->k; ++j)
                ch->m[i * ch->k + j] = ch->X[i * ch->w + ch->index[j]];
    }
}

/* ------------------------------------------- runtime/coherence.py: coherence_errors */

/* kg_coherence on a problem read already (kg_read; kanagen_sample.c calls it a chunk of
 * measures at a time): per channel, M totals then M ranks in out; 2 when out of memory */
static int kg_coherence_at(kg_problem *pb, const double *q, int iterations, double tol,
                           double *out)
{
    const int nch = pb->nch;
    kg_channel *channels = pb->ch;
    kg_point projected;
    kg_arena arena = {NULL, 0};
    for (int pass = 0; pass < 2; ++pass) { /* sizes, then places: ChannelData.m, one point */
        for (int c = 0; c < nch; ++c) {
            double *m = KG_TAKE(&arena, double, channels[c].M * channels[c].k);
            if (arena.base) channels[c].m = m;
        }
        kg_layout_point(&arena, pb, &projected);
        if (pass == 0) {
            arena.base = malloc(arena.used + 16);
            if (!arena.base) return 2;
            arena.used = 0;
        }
    }
    kg_channel_data(pb);
    long total = 0;
    for (int c = 0; c < nch; ++c) total += channels[c].M;
    double *work = malloc(sizeof(double) * (total + 1) + sizeof(int) * (total + 1));
    if (!work) {
        free(arena.base);
        return 2;
    }
    double *violation[nch > 0 ? nch : 1], *observed[nch > 0 ? nch : 1];
    int *rank[nch > 0 ? nch : 1], *ranks = (int *)(work + total + 1);
    for (long c = 0, at = 0; c < nch; at += channels[c].M, ++c) {
        violation[c] = work + at;
        rank[c] = ranks + at;
        observed[c] = channels[c].m; /* the projection starts at the observed measures */
    }
    kg_project_measures(pb, q, observed, &projected, iterations, tol, violation, rank);
    for (int c = 0; c < nch; ++c) {
        const kg_channel *ch = &channels[c];
        const int k = ch->k;
        for (long i = 0; i < ch->M; ++i) {
            double v[KG_MAXK + 1];
            for (int j = 0; j < k; ++j) v[j] = projected.mt[c][i * k + j] - ch->m[i * k + j];
            out[i] = kg_quadratic(k, v, kg_Q(ch, i)) + violation[c][i];
            out[ch->M + i] = rank[c][i];
        }
        out += 2 * ch->M;
    }
    free(work);
    free(arena.base);
    return 0;
}

/* coherence.coherence_errors' projection: the measures of kg_read's input (its start is
 * the q at which they are projected, its iteration cap the projector steps plus one, its
 * xtol the tolerance) projected onto c_i(q, ·) = 0 (project_measures); out per channel, per
 * measure: ‖m̃ − m‖²_Q + the whitened violation, then the equations kept. 1: bad input,
 * 2: out of memory */
int kg_coherence(const double *in, double *out)
{
    kg_problem pb;
    int nch = (int)in[1], iterations;
    double tol;
    const double *q;
    if (nch < 0 || nch > KG_NCH) return 1;
    kg_channel channels[nch > 0 ? nch : 1];
    if (kg_read(in, &pb, channels, &iterations, &tol, &q)) return 1;
    return kg_coherence_at(&pb, q, iterations, tol, out);
}

/* ---------------------------------------------------- runtime/coherence.py: solve_minimal */
#define KG_FREE_STEPS 3  /* _FREE_STEPS */
#define KG_WATCHDOG 1e8  /* _WATCHDOG */
#define KG_SLOW 4        /* _SLOW */

/* solve_minimal's equations(q): c0 then every measure's equations (R rows), their Jacobian
 * (R × n), each row times w (scaled); returns max |w c| (NumPy max: NaN wins, 0 if none) */
static double kg_minimal_equations(const kg_problem *pb, const double *q, const double *w,
                                   double *c, double *J)
{
    const int n = KG_N;
    kg_c0(pb->model, q, pb->k, c, J);
    long row = pb->p0;
    for (int ch = 0; ch < pb->nch; ++ch) {
        const kg_channel *C = &pb->ch[ch];
        double D[KG_MAXP * KG_MAXK + 1];
        for (long i = 0; i < C->M; ++i) {
            kg_measure(pb->model, C->id, q, C->X + i * C->w, pb->k, c + row, J + row * n, D);
            row += C->p;
        }
    }
    if (!w) return 0.0;
    for (long r = 0; r < row; ++r) {
        c[r] *= w[r];
        for (int u = 0; u < n; ++u) J[r * n + u] *= w[r];
    }
    return row ? kg_nanmax_abs(row, c) : 0.0;
}

static int kg_solved(double delta, const double *q) /* _solved */
{
    return isfinite(delta) && delta <= 1e-8 * (1 + kg_nanmax_abs(KG_N, q));
}

/* The SVD step of solve_minimal: r − V_k (V_kᵀ r + U_kᵀ c / S_k) over the singular values
 * above √eps × the largest (J = U S Vᵀ by one-sided Jacobi rotations of J's columns; the
 * step does not depend on the basis). Returns the rank, -1 when J has a NaN (LAPACK does
 * not converge: the Python LinAlgError) */
static int kg_minimal_step(long R, const double *J, const double *c, const double *r,
                           double eps, double *step)
{
    const int n = KG_N;
    for (long j = 0; j < R * n; ++j)
        if (J[j] != J[j]) return -1;
    double *A = malloc(sizeof(double) * (R * n + 1));
    double V[KG_N * KG_N + 1], S[KG_N + 1], y[KG_N + 1];
    if (!A) return -1;
    memcpy(A, J, sizeof(double) * R * n);
    for (int a = 0; a < n * n; ++a) V[a] = a % (n + 1) == 0 ? 1.0 : 0.0;
    int finite = 1;
    for (long j = 0; j < R * n; ++j) finite &= isfinite(A[j]) != 0;
    if (finite) kg_jacobi(R, n, A, V, 0.0);
    double top = kg_column_norms(R, n, A, S);
    int rank = 0;
    for (int j = 0; j < n; ++j) {
        /* an infinite J: LAPACK's singular values are NaN, nothing kept */
        y[j] = 0.0;
        if (!(finite && R > 0 && top > 0 && S[j] > sqrt(eps) * top)) continue;
        ++rank;
        double vr = 0.0, uc = 0.0;
        for (int u = 0; u < n; ++u) vr += V[u * n + j] * r[u];
        for (long i = 0; i < R; ++i) uc += A[i * n + j] / S[j] * c[i];
        y[j] = vr + uc / S[j];
    }
    for (int u = 0; u < n; ++u) {
        double acc = 0.0;
        for (int j = 0; j < n; ++j) acc += V[u * n + j] * y[j];
        step[u] = r[u] - acc;
    }
    free(A);
    return rank;
}

/* kg_minimal on a problem read already (its measures the sample): out = q, success, rank,
 * iterations, violation */
static int kg_minimal_solve(const kg_problem *pb, const double *target, int max_iter,
                            double xtol, double *out)
{
    const int n = KG_N;
    long R = pb->p0;
    for (int c = 0; c < pb->nch; ++c) R += pb->ch[c].M * pb->ch[c].p;
    /* c, J, their trial and best copies, the weights */
    double *work = malloc(sizeof(double) * (3 * (R + R * n) + R + 1));
    if (!work) return 2;
    double *c = work, *J = c + R, *c_new = J + R * n, *J_new = c_new + R;
    double *c_best = J_new + R * n, *J_best = c_best + R, *w = J_best + R * n;
    double q[KG_N + 1], trial[KG_N + 1], step[KG_N + 1], r[KG_N + 1], q_best[KG_N + 1];
    memcpy(q, target, sizeof(double) * n);
    int rank = 0, it, success = -1;
    kg_minimal_equations(pb, q, NULL, c, J); /* raw: the rows' weights */
    for (long i = 0; i < R; ++i) {
        double acc = 0.0;
        for (int u = 0; u < n; ++u) acc += J[i * n + u] * J[i * n + u];
        double norm = sqrt(acc);
        w[i] = isfinite(norm) && norm > 0 ? 1.0 / norm : 1.0;
        c[i] *= w[i];
        for (int u = 0; u < n; ++u) J[i * n + u] *= w[i];
    }
    double delta = R ? kg_nanmax_abs(R, c) : 0.0, best = delta, d_new = 0.0;
    memcpy(q_best, q, sizeof(double) * n);
    memcpy(c_best, c, sizeof(double) * R);
    memcpy(J_best, J, sizeof(double) * R * n);
    int free_steps = KG_FREE_STEPS, slow = 0;
    for (it = 1; it <= max_iter; ++it) {
        for (int u = 0; u < n; ++u) r[u] = target[u] - q[u];
        int got = kg_minimal_step(R, J, c, r, pb->eps, step);
        if (got < 0) {
            success = 0;
            break;
        }
        rank = got;
        int finite = 1;
        for (int u = 0; u < n; ++u) finite &= isfinite(step[u]) != 0;
        if (!finite) {
            success = 0;
            break;
        }
        for (int u = 0; u < n; ++u) trial[u] = q[u] + step[u];
        d_new = kg_minimal_equations(pb, trial, w, c_new, J_new);
        double moved = 0.0;
        if (free_steps > 0 && isfinite(d_new) && d_new < KG_WATCHDOG * (1 + best)) {
            free_steps -= d_new >= delta;
            for (int u = 0; u < n; ++u) moved = fabs(step[u]) > moved ? fabs(step[u]) : moved;
        } else {
            if (delta > best) { /* the watchdog's steps did not pay: back to the best */
                delta = best;
                memcpy(q, q_best, sizeof(double) * n);
                memcpy(c, c_best, sizeof(double) * R);
                memcpy(J, J_best, sizeof(double) * R * n);
                free_steps = 0;
                continue;
            }
            free_steps = 0;
            double alpha = 1.0;
            int found = 0;
            while (alpha > 0x1p-30) {
                for (int u = 0; u < n; ++u) trial[u] = q[u] + alpha * step[u];
                d_new = kg_minimal_equations(pb, trial, w, c_new, J_new);
                if (isfinite(d_new) && d_new < delta + 1e-12 * (1 + delta)) {
                    found = 1;
                    break;
                }
                alpha /= 2;
            }
            if (!found) {
                success = kg_solved(delta, q);
                break;
            }
            for (int u = 0; u < n; ++u) {
                double a = fabs(alpha * step[u]);
                moved = a > moved ? a : moved;
            }
        }
        slow = free_steps == 0 && d_new > 0.9 * delta ? slow + 1 : 0;
        memcpy(q, trial, sizeof(double) * n);
        memcpy(c, c_new, sizeof(double) * R);
        memcpy(J, J_new, sizeof(double) * R * n);
        delta = d_new;
        if (delta < best) {
            best = delta;
            memcpy(q_best, q, sizeof(double) * n);
            memcpy(c_best, c, sizeof(double) * R);
            memcpy(J_best, J, sizeof(double) * R * n);
        }
        if (slow >= KG_SLOW) {
            success = kg_solved(delta, q);
            break;
        }
        double size = kg_nanmax_abs(n, q);
        if (moved <= xtol * (1 + size) || (kg_solved(delta, q) && moved <= 1e-8 * (1 + size))) {
            success = kg_solved(delta, q);
            break;
        }
    }
    if (success < 0) { /* the iteration cap */
        success = kg_solved(delta, q);
        it = max_iter;
    }
    memcpy(out, q, sizeof(double) * n);
    out[n] = success;
    out[n + 1] = rank;
    out[n + 2] = it;
    out[n + 3] = delta;
    free(work);
    return 0;
}

/* solve_minimal: the q closest to the target (the start of kg_read's input) satisfying c0
 * and the equations of the given measures (eq. 21, Q0 = 0), the watchdog and line search
 * of the Python; out: q (n), success, rank, iterations, violation. 1: bad input, 2: no
 * memory */
int kg_minimal(const double *in, double *out)
{
    kg_problem pb;
    int nch = (int)in[1], max_iter;
    double xtol;
    const double *target;
    if (nch < 0 || nch > KG_NCH) return 1;
    kg_channel channels[nch > 0 ? nch : 1];
    if (kg_read(in, &pb, channels, &max_iter, &xtol, &target)) return 1;
    return kg_minimal_solve(&pb, target, max_iter, xtol, out);
}

/* closest_sqrt of one n × n matrix S (row-major, n <= KG_N) into L: the port's square root
 * on its own, for the differential tests of the port. Returns -1 when n is too large. */
int kg_closest_root(long n, const double *S, double eps, double *L)
{
    if (n < 0 || n > KG_N) return -1;
    kg_closest_sqrt((int)n, S, eps, L);
    return 0;
}

/* Sizes the Python side checks against the family it loaded: n, constants, channels,
 * models, derived quantities, slacks. */
void kg_sizes(long long *out)
{
    out[0] = KG_N;
    out[1] = KG_NK;
    out[2] = KG_NCH;
    out[3] = KG_NMODELS;
    out[4] = KG_NDERIVED;
    out[5] = KG_NSLACK;
}

/* The number of equations of a model's channel (channel -1: its constraints). */
int kg_equations(int model, int channel)
{
    return channel < 0 ? kg_p0[model] : kg_p[model * (KG_NCH > 0 ? KG_NCH : 1) + channel];
}

/* kg_eval: the family's functions on NumPy's layouts, for the runtime's own calls.
 *   in:  what (0: c0(q), 1: a channel's equations), model, channel, M, q (n), k, X (M × w)
 *   out: c0 (p0) and C0 (p0 × n); or c (M × p), C (M × p × n), D (M × p × k) */
int kg_eval(const double *in, double *out)
{
    int what = (int)in[0], model = (int)in[1], channel = (int)in[2];
    long M = (long)in[3];
    const double *q = in + 4, *k = q + KG_N, *X = k + KG_NK;
    if (what == 0) {
        kg_c0(model, q, k, out, out + kg_p0[model]);
        return 0;
    }
    int p = kg_equations(model, channel), w = kg_width[channel], kc = kg_ncorr[channel];
    double *c = out, *C = c + M * p, *D = C + M * p * KG_N;
    for (long i = 0; i < M; ++i)
        kg_measure(model, channel, q, X + i * w, k, c + i * p, C + i * p * KG_N, D + i * p * kc);
    return 0;
}
