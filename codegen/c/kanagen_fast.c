/* kanagen's local estimator in C: a mechanical port of the NumPy runtime (docs/fastpath.md).
 *
 * Compiled in one translation unit after CasADi's C of a family and the family's generated
 * tables (codegen/templates/c/family.c.jinja), which define:
 *   KG_N, KG_NK, KG_NCH, KG_NMODELS, KG_NDERIVED, KG_NSLACK, KG_MAXP, KG_MAXW;
 *   kg_width[], kg_ncorr[], kg_index_off[], kg_index[], kg_p0[], kg_p[], kg_derived_size[],
 *   kg_reports[],
 *   kg_slack_kind[], kg_clause_count[], kg_clause_off[], kg_clause_len[], kg_clause_start[],
 *   kg_clause[]; kg_c0(), kg_measure(), kg_derived(), kg_slack() (row-major outputs).
 * and KG_MAXP, KG_MAXK, KG_MAXW (largest equation, corrected and component counts) and
 * KG_UNIFORM_P, KG_UNIFORM_K (the counts when every channel of every model has the same,
 * else 0: then the per-measure loops have fixed sizes and unroll, report §6).
 * Every function says which Python function it ports; constants keep the Python names.
 * Matrices are row-major. "NumPy max" propagates NaN; Python's max(a, b) is b > a ? b : a.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* runtime/sqrt.py */
#define KG_EPS (10 * DBL_EPSILON)       /* EPS */
#define KG_TINY DBL_MIN                 /* _TINY = np.finfo(float).tiny */
#define KG_REDUNDANT (1e3 * DBL_EPSILON) /* REDUNDANT */
/* runtime/projector.py */
#define KG_ROUNDING (1e3 * DBL_EPSILON)  /* _ROUNDING */
/* runtime/iterate.py */
#define KG_CONVERGED 0
#define KG_MAX_ITER 1
#define KG_STALLED 2
#define KG_FAILED 3
#define KG_BOUNDARY 4
#define KG_MAX_HALVINGS 40
#define KG_RESTORATION 2
#define KG_STAGNATION 5
#define KG_MU_MIN 1e-4
#define KG_MU_MAX 1e8
#define KG_HALVINGS_PER_DAMPING 4
#define KG_SHRINK 0.25 /* _SHRINK, _GROW: the trust radius */
#define KG_GROW 0.75
/* runtime/projector.py: project_measures(tol=1e-10), _halving(halvings=4) */
#define KG_PROJECT_TOL 1e-10
#define KG_HALVINGS 4
/* runtime/projector.py: restore_parameter(iterations=3) */
#define KG_RESTORE_ITERATIONS 3
#define KG_COHERENCE_ITERATIONS 50

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

/* triangular_solve for t right-hand sides B (n × t, row-major), in place; -1: singular */
static int kg_triangular_solve(int n, const double *L, int t, double *B, int transpose)
{
    for (int i = 0; i < n; ++i)
        if (L[i * n + i] == 0.0) return -1;
    for (int c = 0; c < t; ++c) {
        if (!transpose) {
            for (int a = 0; a < n; ++a) {
                double acc = B[a * t + c];
                for (int j = 0; j < a; ++j) acc -= L[a * n + j] * B[j * t + c];
                B[a * t + c] = acc / L[a * n + a];
            }
        } else {
            for (int a = n - 1; a >= 0; --a) {
                double acc = B[a * t + c];
                for (int i = a + 1; i < n; ++i) acc -= L[i * n + a] * B[i * t + c];
                B[a * t + c] = acc / L[a * n + a];
            }
        }
    }
    return 0;
}

/* reduced_solve for one vector, in place: dropped entries are 0 */
static inline void kg_reduced_solve(int n, const double *L, const int *kept, double *y, int transpose)
{
    if (!transpose) {
        for (int a = 0; a < n; ++a) {
            double acc = y[a];
            for (int j = 0; j < a; ++j) acc -= L[a * n + j] * y[j];
            y[a] = kept[a] ? acc / L[a * n + a] : 0.0;
        }
    } else {
        for (int a = n - 1; a >= 0; --a) {
            double acc = y[a];
            for (int i = a + 1; i < n; ++i) acc -= L[i * n + a] * y[i];
            y[a] = kept[a] ? acc / L[a * n + a] : 0.0;
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
    double scale;
} kg_channel;

typedef struct { /* projector.Problem */
    int model, n, p0, nch;
    kg_channel *ch;
    const double *q0, *Q0, *k;
    double eps;
    int guard; /* the family has slacks: problem.relations is set */
    int nstrict; /* problem.strict_slacks: (component, p) pairs */
    int strict[2 * KG_NSLACK + 2];
} kg_problem;

typedef struct { /* projector.Point */
    double *q, *c0, *C0;
    double **mt, **c, **C, **D; /* per channel */
    double delta, cost;
} kg_point;

typedef struct { /* projector.Linearisation */
    kg_point *x;
    double *info, *H, *rhs;
    double **Cbar, **rbar, **E, **L; /* per channel, per measure */
    int **kept, **ranks;
    double residual;
} kg_lin;

typedef struct { /* projector.Projection */
    double *q;
    double **mt;
    int *kept0;
    int rank0;
    double residual;
} kg_proj;

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

/* point(): c0, δ = ‖c‖∞ and the cost, from equations already evaluated */
static void kg_point_finish(const kg_problem *pb, kg_point *x)
{
    const int n = KG_N;
    kg_c0(pb->model, x->q, pb->k, x->c0, x->C0);
    double delta = pb->p0 ? kg_nanmax_abs(pb->p0, x->c0) : 0.0;
    double cost = 0.0;
    for (int a = 0; a < n; ++a) {
        double row = 0.0;
        for (int b = 0; b < n; ++b) row += pb->Q0[a * n + b] * (x->q[b] - pb->q0[b]);
        cost += (x->q[a] - pb->q0[a]) * row;
    }
    cost *= 0.5;
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        if (ch->M * ch->p == 0) continue;
        double worst = kg_nanmax_abs(ch->M * ch->p, x->c[c]);
        delta = worst != worst ? INFINITY : (worst > delta ? worst : delta);
        const int k = KG_K(ch->k);
        const double *mt = x->mt[c];
        double total = 0.0;
        for (long i = 0; i < ch->M; ++i) {
            double v[KG_MAXK + 1];
            for (int j = 0; j < k; ++j) v[j] = mt[i * k + j] - ch->m[i * k + j];
            total += kg_quadratic(k, v, kg_Q(ch, i));
        }
        cost += 0.5 * total;
    }
    if (delta != delta) delta = INFINITY;
    x->delta = delta;
    x->cost = cost;
}

static int kg_finite(const kg_point *x) /* Point.finite */
{
    return isfinite(x->delta) && isfinite(x->cost);
}

/* evaluate(): equations and Jacobians at (q, m̃) */
static void kg_evaluate(const kg_problem *pb, kg_point *x)
{
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        double xi[KG_MAXW + 1];
        for (long i = 0; i < ch->M; ++i) {
            kg_measure(pb->model, ch->id, x->q,
                       kg_with_corrected(ch, i, x->mt[c] + i * ch->k, xi), pb->k, x->c[c] + i * ch->p,
                       x->C[c] + i * ch->p * pb->n, x->D[c] + i * ch->p * ch->k);
        }
    }
    kg_point_finish(pb, x);
}

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
 * eq. 18's halving per measure; writes mt, the equations at the returned point, and (when
 * not NULL) the whitened violation and the rank of each measure */
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
                /* the last whitening only gives the violation and rank: skipped when the
                 * caller does not want them (_restored) */
                if (!violation && !rank && (it == iterations - 1 || !active)) break;
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
            if (violation) violation[c][i] = viol;
            if (rank) rank[c][i] = rk;
        }
    }
}

/* linearise(): whitened linearisation at x (appendix A, Fig. 17) */
static void kg_linearise(const kg_problem *pb, kg_point *x, kg_lin *lin)
{
    const int n = KG_N;
    /* A and g accumulate in local arrays (registers when n is small): the same sums */
    double A[KG_N * KG_N + 1], g[KG_N + 1];
    memset(A, 0, sizeof(double) * n * n);
    memset(g, 0, sizeof(double) * n);
    double residual = 0.0;
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        const int k = KG_K(ch->k), p = KG_P(ch->p), t = n + 2;
        double *Cbar = lin->Cbar[c], *rbar = lin->rbar[c];
        for (long i = 0; i < ch->M; ++i) {
            const double *Ci = x->C[c] + i * p * n, *Di = x->D[c] + i * p * k;
            const double *ci = x->c[c] + i * p, *m = x->mt[c] + i * k, *mobs = ch->m + i * k;
            double B[KG_MAXP * (KG_N + 2) + 1];
            for (int a = 0; a < p; ++a) {
                for (int j = 0; j < n; ++j) B[a * t + j] = Ci[a * n + j];
                double acc = 0.0; /* r_i − C_i q• = D_i (m• − m) − c_i */
                for (int j = 0; j < k; ++j) acc += Di[a * k + j] * (m[j] - mobs[j]);
                B[a * t + n] = acc - ci[a];
                B[a * t + n + 1] = ci[a];
            }
            lin->ranks[c][i] = kg_whiten(p, k, Di, kg_G(ch, i), t, B, pb->eps,
                                         lin->E[c] + i * p * k, lin->L[c] + i * p * p,
                                         lin->kept[c] + i * p);
            for (int a = 0; a < p; ++a) {
                const double *row = B + a * t;
                for (int u = 0; u < n; ++u) {
                    for (int v = 0; v <= u; ++v) A[u * n + v] += row[u] * row[v];
                    g[u] += row[u] * row[n];
                    Cbar[(i * p + a) * n + u] = row[u];
                }
                rbar[i * p + a] = row[n];
                residual += row[n + 1] * row[n + 1];
            }
        }
    }
    for (int u = 0; u < n; ++u)
        for (int v = 0; v < u; ++v) A[v * n + u] = A[u * n + v];
    for (int u = 0; u < n * n; ++u) A[u] += pb->Q0[u]; /* info = Q0 + A */
    memcpy(lin->info, A, sizeof(double) * n * n);
    for (int u = 0; u < n; ++u) {
        double acc = 0.0;
        for (int v = 0; v < n; ++v) acc += pb->Q0[u * n + v] * (pb->q0[v] - x->q[v]);
        lin->rhs[u] = acc + g[u];
    }
    memcpy(lin->H, A, sizeof(double) * n * n);
    if (pb->p0) {
        /* augmented form of the same KKT system: ρ C0ᵀC0 (_augmentation) */
        double gram[KG_N * KG_N + 1];
        for (int u = 0; u < n; ++u)
            for (int v = 0; v < n; ++v) {
                double acc = 0.0;
                for (int r = 0; r < pb->p0; ++r) acc += x->C0[r * n + u] * x->C0[r * n + v];
                gram[u * n + v] = acc;
            }
        double top = 0.0, bottom = 0.0, rho;
        for (int u = 0; u < n; ++u) {
            double a = A[u * n + u], b = gram[u * n + u];
            if (a != a || top != top) top = NAN; else if (a > top) top = a;
            if (b != b || bottom != bottom) bottom = NAN; else if (b > bottom) bottom = b;
        }
        rho = bottom <= 0.0 ? 0.0 : (top > 0.0 ? top : 1.0) / bottom;
        for (int u = 0; u < n * n; ++u) lin->H[u] = A[u] + rho * gram[u];
        for (int u = 0; u < n; ++u) {
            double acc = 0.0;
            for (int r = 0; r < pb->p0; ++r) acc += x->C0[r * n + u] * x->c0[r];
            lin->rhs[u] -= rho * acc;
        }
    }
    lin->residual = residual;
    lin->x = x;
}

/* _seen: the components the data or the constraints see — some information on the diagonal
 * of info (NaN counts) or a C0 entry above _ROUNDING × its row's NumPy max, as it is or as
 * C0[r, u] q_u; their indices in idx, their count returned */
static int kg_seen(int n, int p0, const double *info, const double *C0, const double *q,
                   int *idx)
{
    int ns = 0;
    double bound[p0 + 1], scaled[p0 + 1], row[KG_N + 1];
    for (int r = 0; r < p0; ++r) {
        bound[r] = KG_ROUNDING * kg_nanmax_abs(n, C0 + r * n);
        for (int u = 0; u < n; ++u) row[u] = C0[r * n + u] * q[u];
        scaled[r] = KG_ROUNDING * kg_nanmax_abs(n, row);
    }
    for (int u = 0; u < n; ++u) {
        int seen = info[u * n + u] != 0.0;
        for (int r = 0; r < p0 && !seen; ++r)
            seen = fabs(C0[r * n + u]) > bound[r] || fabs(C0[r * n + u] * q[u]) > scaled[r];
        if (seen) idx[ns++] = u;
    }
    return ns;
}

/* _solve_seen: the parameter block of eq. 43 on the ns seen components idx (H, rhs already
 * restricted to them): writes dq at idx, the constraints' rank and kept rows in out, adds
 * the whitened ‖c0‖² to *residual; -1 on a singular factor */
static int kg_solve_seen(const kg_problem *pb, const kg_point *x, int ns, const int *idx,
                         const double *H, double *bbar, double *dq, double *residual,
                         kg_proj *out)
{
    const int n = KG_N, p0 = pb->p0;
    double Abar[KG_N * KG_N + 1];
    kg_closest_sqrt(ns, H, pb->eps, Abar);
    if (kg_triangular_solve(ns, Abar, 1, bbar, 0)) return -1;
    if (p0) {
        double Ct[ns * p0], G0[p0 * p0], L0[p0 * p0], v[p0], e0[p0];
        for (int u = 0; u < ns; ++u)
            for (int r = 0; r < p0; ++r) Ct[u * p0 + r] = x->C0[r * n + idx[u]];
        if (kg_triangular_solve(ns, Abar, p0, Ct, 0)) return -1; /* Ā⁻¹ C0ᵀ */
        for (int r = 0; r < p0; ++r)
            for (int s = 0; s < p0; ++s) {
                double acc = 0.0;
                for (int u = 0; u < ns; ++u) acc += Ct[u * p0 + r] * Ct[u * p0 + s];
                G0[r * p0 + s] = acc;
            }
        kg_reduced_sqrt(p0, G0, pb->eps, L0, out->kept0);
        for (int r = 0; r < p0; ++r) {
            double acc = 0.0;
            for (int u = 0; u < ns; ++u) acc += Ct[u * p0 + r] * bbar[u];
            v[r] = acc + x->c0[r];
            e0[r] = x->c0[r];
        }
        kg_reduced_solve(p0, L0, out->kept0, v, 0);
        kg_reduced_solve(p0, L0, out->kept0, v, 1); /* λ0 */
        for (int u = 0; u < ns; ++u) {
            double acc = 0.0;
            for (int r = 0; r < p0; ++r) acc += Ct[u * p0 + r] * v[r];
            bbar[u] -= acc;
        }
        kg_reduced_solve(p0, L0, out->kept0, e0, 0);
        double e2 = 0.0;
        for (int r = 0; r < p0; ++r) {
            e2 += e0[r] * e0[r];
            out->rank0 += out->kept0[r];
        }
        *residual += e2;
    }
    if (kg_triangular_solve(ns, Abar, 1, bbar, 1)) return -1;
    for (int u = 0; u < ns; ++u) dq[idx[u]] = bbar[u];
    return 0;
}

/* solve(): the projector's point (eq. 12/43), damped by μ diag(w) when μ > 0 (w the given
 * weights, else diag(H): _equilibrium_weights), solved on the
 * components seen (_seen; the others do not move, nothing seen: q stays); -1 when a
 * triangular factor is singular (the Python LinAlgError). Without measures, the corrected
 * measures (eq. 44) are not computed (fit_problem's outputs do not read them). */
static int kg_solve(const kg_problem *pb, const kg_lin *lin, double mu, kg_proj *out,
                    int measures, const double *weights)
{
    const int n = KG_N, p0 = pb->p0;
    const kg_point *x = lin->x;
    double H[KG_N * KG_N + 1], bbar[KG_N + 1], dq[KG_N + 1];
    int idx[KG_N + 1];
    memcpy(H, lin->H, sizeof(double) * n * n);
    if (mu > 0.0 && weights) {
        for (int u = 0; u < n; ++u) H[u * n + u] += mu * weights[u];
    } else if (mu > 0.0) { /* _equilibrium_weights */
        double top = 0.0;
        for (int u = 0; u < n; ++u) {
            double a = fabs(H[u * n + u]);
            if (a != a || top != top) top = NAN; else if (a > top) top = a;
        }
        for (int u = 0; u < n; ++u) {
            double a = fabs(lin->H[u * n + u]);
            H[u * n + u] += mu * (a > 0 ? a : (top > 0 ? top : 1.0));
        }
    }
    const int ns = kg_seen(n, p0, lin->info, x->C0, x->q, idx);
    if (ns < n) /* H on the seen block, in place (row-major ns × ns) */
        for (int a = 0; a < ns; ++a)
            for (int b = 0; b < ns; ++b) H[a * ns + b] = H[idx[a] * n + idx[b]];
    for (int u = 0; u < ns; ++u) bbar[u] = lin->rhs[idx[u]];
    memset(dq, 0, sizeof(double) * n);
    double residual = lin->residual;
    out->rank0 = 0;
    for (int r = 0; r < p0; ++r) out->kept0[r] = 0;
    if (ns && kg_solve_seen(pb, x, ns, idx, H, bbar, dq, &residual, out)) return -1;
    for (int u = 0; u < n; ++u) out->q[u] = x->q[u] + dq[u];
    for (int c = 0; c < pb->nch && measures; ++c) { /* eq. 44 */
        const kg_channel *ch = &pb->ch[c];
        const int k = KG_K(ch->k), p = KG_P(ch->p);
        const double *Cbar = lin->Cbar[c], *rbar = lin->rbar[c], *E = lin->E[c], *L = lin->L[c];
        const int *kept = lin->kept[c];
        double *mt = out->mt[c];
        for (long i = 0; i < ch->M; ++i) {
            double z[KG_MAXP + 1], dm[KG_MAXK + 1];
            for (int a = 0; a < p; ++a) {
                double acc = 0.0;
                for (int u = 0; u < n; ++u) acc += Cbar[(i * p + a) * n + u] * dq[u];
                z[a] = rbar[i * p + a] - acc;
            }
            kg_correct(p, k, E + i * p * k, L + i * p * p, kept + i * p, kg_G(ch, i), z, dm);
            for (int j = 0; j < k; ++j) mt[i * k + j] = ch->m[i * k + j] + dm[j];
        }
    }
    out->residual = residual;
    return 0;
}

/* restore_parameter: q back onto c0(q) = 0 with the least move in the metric Q̃ = Ā Āᵀ
 * (root), C0 re-evaluated at each of a few steps; a step that does not lower ‖c0‖∞ is not
 * taken. In place on q, with c0 (p0) and C0 (p0 × n) as work space; -1 on a singular
 * factor (the Python LinAlgError) */
static int kg_restore_parameter(const kg_problem *pb, double *q, const double *root,
                                double *c0, double *C0)
{
    const int n = KG_N, p0 = pb->p0;
    if (!p0) return 0; /* no constraint: q as it is */
    kg_c0(pb->model, q, pb->k, c0, C0);
    double worst = kg_nanmax_abs(p0, c0);
    double Ct[n * p0], G0[p0 * p0], L0[p0 * p0], y[p0], trial[n], c0_new[p0], C0_new[p0 * n];
    int kept0[p0];
    for (int it = 0; it < KG_RESTORE_ITERATIONS; ++it) {
        if (!(worst > KG_ROUNDING * (1.0 + kg_nanmax_abs(n, q)) * 1e-3)) break;
        for (int u = 0; u < n; ++u)
            for (int r = 0; r < p0; ++r) Ct[u * p0 + r] = C0[r * n + u];
        if (kg_triangular_solve(n, root, p0, Ct, 0)) return -1; /* Ā⁻¹ C0ᵀ */
        for (int r = 0; r < p0; ++r)
            for (int s = 0; s < p0; ++s) {
                double acc = 0.0;
                for (int u = 0; u < n; ++u) acc += Ct[u * p0 + r] * Ct[u * p0 + s];
                G0[r * p0 + s] = acc;
            }
        kg_reduced_sqrt(p0, G0, pb->eps, L0, kept0);
        memcpy(y, c0, sizeof(double) * p0);
        kg_reduced_solve(p0, L0, kept0, y, 0);
        kg_reduced_solve(p0, L0, kept0, y, 1);
        for (int u = 0; u < n; ++u) {
            double acc = 0.0;
            for (int r = 0; r < p0; ++r) acc += Ct[u * p0 + r] * y[r];
            trial[u] = acc;
        }
        if (kg_triangular_solve(n, root, 1, trial, 1)) return -1;
        for (int u = 0; u < n; ++u) trial[u] = q[u] - trial[u];
        kg_c0(pb->model, trial, pb->k, c0_new, C0_new);
        double new_worst = kg_nanmax_abs(p0, c0_new);
        if (!(new_worst < worst)) break;
        memcpy(q, trial, sizeof(double) * n);
        memcpy(c0, c0_new, sizeof(double) * p0);
        memcpy(C0, C0_new, sizeof(double) * p0 * n);
        worst = new_worst;
    }
    return 0;
}

/* ModelFamily.relations_hold: in each clause of inequalities of the model, one holds */
static int kg_relations(const kg_problem *pb, const double *q)
{
    int clauses = kg_clause_count[pb->model];
    if (!clauses) return 1;
    double s[KG_NSLACK > 0 ? KG_NSLACK : 1];
    kg_slack(q, pb->k, s);
    for (int cl = 0; cl < clauses; ++cl) {
        int off = kg_clause_off[pb->model] + cl, any = 0;
        for (int j = 0; j < kg_clause_len[off]; ++j) {
            int i = kg_clause[kg_clause_start[off] + j];
            double v = s[i];
            int kind = kg_slack_kind[i];
            any |= kind == 0 ? v >= 0 : kind == 1 ? v > 0 : (isfinite(v) && v != 0);
        }
        if (!any) return 0;
    }
    return 1;
}

/* -------------------------------------------------------------- runtime/iterate.py */

typedef struct {
    const kg_problem *pb;
    kg_point *pts[3]; /* x, the trial point and a spare for its second-order correction */
    kg_lin *lin;
    kg_proj *proj, *target;
    double eps_delta, delta_cap;
    double root[KG_N * KG_N + 1]; /* _line_search's closest root of the information */
    double radius; /* _TrustRegion: the radius on ‖Δq‖ (weights: ones) */
} kg_state;

/* _step_sizes */
static void kg_step_sizes(const kg_problem *pb, const kg_point *x, const kg_proj *pr,
                          double *size_q, double *size_m)
{
    const int n = KG_N;
    double top = kg_nanmax_abs(n, x->q), floor = KG_ROUNDING * top, sq = 0.0, sm = 0.0;
    if (!(floor > KG_TINY)) floor = floor != floor ? floor : KG_TINY; /* Python max() */
    for (int u = 0; u < n; ++u) {
        double v = fabs(pr->q[u] - x->q[u]) / (fabs(x->q[u]) + floor);
        if (v != v || sq != sq) sq = NAN; else if (v > sq) sq = v;
    }
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        if (!ch->M) continue;
        double worst = -INFINITY;
        for (long i = 0; i < ch->M; ++i) {
            double v[KG_MAXK + 1];
            const int k = KG_K(ch->k);
            for (int j = 0; j < k; ++j) v[j] = pr->mt[c][i * k + j] - x->mt[c][i * k + j];
            double qv = kg_quadratic(k, v, kg_Q(ch, i));
            if (qv != qv || worst != worst) worst = NAN; else if (qv > worst) worst = qv;
        }
        sm = worst > sm ? worst : sm;
    }
    *size_q = sq;
    *size_m = sqrt(sm);
}

/* _negligible */
static int kg_negligible(const kg_problem *pb, const double *q_old, const double *q_new,
                         double *const *mt_old, double *const *mt_new, double xtol)
{
    const int n = KG_N;
    double rounding = KG_ROUNDING * kg_nanmax_abs(n, q_old);
    for (int u = 0; u < n; ++u)
        if (fabs(q_new[u] - q_old[u]) > xtol * fabs(q_old[u]) + rounding) return 0;
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        if (!ch->M) continue;
        double moved = -INFINITY, bound = xtol + KG_ROUNDING * ch->scale;
        for (long i = 0; i < ch->M; ++i) {
            double v[KG_MAXK + 1];
            const int k = KG_K(ch->k);
            for (int j = 0; j < k; ++j) v[j] = mt_new[c][i * k + j] - mt_old[c][i * k + j];
            double qv = kg_quadratic(k, v, kg_Q(ch, i));
            if (qv != qv || moved != moved) moved = NAN; else if (qv > moved) moved = qv;
        }
        if (moved > bound * bound) return 0;
    }
    return 1;
}

/* _lowers_violation: eq. 18's aim, δ falls (beyond its rounding level) */
static int kg_lowers_violation(const kg_point *trial, const kg_point *x, double eps_delta)
{
    return x->delta > eps_delta && trial->delta <= (1 - 1e-4) * x->delta;
}

/* _acceptable: the small filter over (cost, violation) */
static int kg_acceptable(const kg_point *trial, const kg_point *x, double eps_delta,
                         double delta_cap)
{
    if (!kg_finite(trial)) return 0;
    if (kg_lowers_violation(trial, x, eps_delta)) return 1;
    double slack = x->delta <= eps_delta ? 1e-10 : 1e-13;
    if (trial->delta < x->delta + eps_delta && trial->cost <= x->cost * (1 + slack) + 1e-300)
        return 1;
    return trial->delta <= delta_cap && trial->cost < x->cost * (1 - 1e-10);
}

/* _restored: the point with q projected back onto the parameter constraints in the metric
 * of root (when not NULL) and its measures onto their equations (in place); -1 on a
 * singular factor */
static int kg_restored(const kg_problem *pb, kg_point *pt, const double *root)
{
    if (root && kg_restore_parameter(pb, pt->q, root, pt->c0, pt->C0)) return -1;
    kg_project_measures(pb, pt->q, pt->mt, pt, KG_RESTORATION, KG_PROJECT_TOL, NULL, NULL);
    kg_point_finish(pb, pt);
    return 0;
}

/* _diverging: a strict inequality's slack at least doubles and its relation c = 1/s^p has
 * fallen below 1e-8 of its starting value */
static int kg_diverging(const kg_problem *pb, const double *q_old, const double *q_new,
                        const double *start)
{
    for (int j = 0; j < pb->nstrict; ++j) {
        int index = pb->strict[2 * j], power = pb->strict[2 * j + 1];
        double s_old = fabs(q_old[index]), s_new = fabs(q_new[index]);
        if (s_new > 2.0 * s_old && pow(fabs(start[index]) / s_new, power) < 1e-8) return 1;
    }
    return 0;
}

static void kg_copy_measures(const kg_problem *pb, double *const *from, double **to)
{
    for (int c = 0; c < pb->nch; ++c)
        memcpy(to[c], from[c], sizeof(double) * pb->ch[c].M * pb->ch[c].k);
}

/* x + α (target − x), parameter and measures, into pt */
static void kg_step_point(const kg_problem *pb, const kg_point *x, const kg_proj *target,
                          double alpha, kg_point *pt)
{
    for (int u = 0; u < KG_N; ++u) pt->q[u] = x->q[u] + alpha * (target->q[u] - x->q[u]);
    for (int c = 0; c < pb->nch; ++c)
        for (long j = 0; j < pb->ch[c].M * pb->ch[c].k; ++j) {
            double a = x->mt[c][j], b = target->mt[c][j];
            pt->mt[c][j] = a + alpha * (b - a);
        }
}

/* _line_search: the step (or the damped one) — as it is, or with its second-order
 * correction onto the parameter constraints —, halved back as eq. 18; more damping if
 * refused. Returns 1 with the trial in st->pts[1], 0 when nothing is acceptable, -1 on a
 * singular factor (the Python exception, caught by the caller as a failure) */
static int kg_line_search(kg_state *st, double *mu_io, double *alpha_out, int guard)
{
    const kg_problem *pb = st->pb;
    kg_point *x = st->pts[0], *trial = st->pts[1];
    double mu = *mu_io;
    const int n = KG_N;
    int have_root = 0, correctable = pb->p0 > 0;
    for (;;) {
        kg_proj *target = st->proj;
        if (mu != 0.0) {
            if (kg_solve(pb, st->lin, mu, st->target, 1, NULL)) return -1;
            target = st->target;
        }
        double alpha = 1.0;
        int tries = mu >= KG_MU_MAX ? KG_MAX_HALVINGS : KG_HALVINGS_PER_DAMPING;
        for (int h = 0; h < tries; ++h) {
            kg_step_point(pb, x, target, alpha, trial);
            kg_restored(pb, trial, NULL);
            if (correctable && kg_finite(trial) && trial->cost < x->cost
                && !kg_acceptable(trial, x, st->eps_delta, st->delta_cap)) {
                if (!have_root) {
                    kg_closest_sqrt(n, st->lin->info, pb->eps, st->root);
                    have_root = 1;
                }
                /* second order: small against the step, else no Maratos effect; in the
                 * step's metric first, else (no slacks) in the Euclidean one: the first
                 * small one, or the first acceptable */
                double eye[KG_N * KG_N + 1];
                for (int u = 0; u < n * n; ++u) eye[u] = u % (n + 1) == 0;
                double plain[KG_N + 1]; /* the step's q (restoration keeps it) */
                memcpy(plain, trial->q, sizeof(double) * n);
                int chosen = 0;
                for (int pass = 0; pass < (pb->guard ? 1 : 2); ++pass) {
                    kg_point *corrected = st->pts[2];
                    kg_step_point(pb, x, target, alpha, corrected);
                    if (kg_restored(pb, corrected, pass == 0 ? st->root : eye)) return -1;
                    double moved = 0.0, step = 0.0; /* np.linalg.norm */
                    for (int u = 0; u < n; ++u) {
                        moved += (corrected->q[u] - plain[u]) * (corrected->q[u] - plain[u]);
                        step += (plain[u] - x->q[u]) * (plain[u] - x->q[u]);
                    }
                    if (!(sqrt(moved) <= 0.5 * sqrt(step))) continue;
                    int accepted = kg_acceptable(corrected, x, st->eps_delta, st->delta_cap);
                    if (!chosen || accepted) { /* corrected becomes the trial point */
                        st->pts[2] = trial;
                        st->pts[1] = trial = corrected;
                        chosen = 1;
                    }
                    if (accepted) break;
                }
            }
            if ((!guard || kg_relations(pb, trial->q))
                && kg_acceptable(trial, x, st->eps_delta, st->delta_cap)) {
                *mu_io = mu;
                *alpha_out = alpha;
                return 1;
            }
            alpha /= 2;
        }
        if (mu >= KG_MU_MAX) return 0;
        mu = 10 * mu > KG_MU_MIN ? 10 * mu : KG_MU_MIN;
    }
}

static double kg_norm(int n, const double *a, const double *b) /* np.linalg.norm(a − b) */
{
    double acc = 0.0;
    for (int u = 0; u < n; ++u) acc += (a[u] - b[u]) * (a[u] - b[u]);
    return sqrt(acc);
}

/* _damping_for: the damping μ whose step has ‖Δq‖ just within radius (bisection on log μ);
 * -1 on a singular factor */
static int kg_damping_for(kg_state *st, double radius, const double *ones, double *mu)
{
    const kg_problem *pb = st->pb;
    const double *q = st->lin->x->q;
    double lo = -12.0, hi = 12.0, size;
#define KG_SIZE(log_mu) (kg_solve(pb, st->lin, pow(10.0, (log_mu)), st->target, 0, ones) \
                         ? -1 : (size = kg_norm(KG_N, st->target->q, q), 0))
    if (KG_SIZE(hi)) return -1;
    while (size > radius && hi < 300.0) {
        lo = hi;
        hi = 2.0 * hi;
        if (KG_SIZE(hi)) return -1;
    }
    while (hi - lo > 0.02) {
        double mid = 0.5 * (lo + hi);
        if (KG_SIZE(mid)) return -1;
        if (size > radius) lo = mid; else hi = mid;
    }
#undef KG_SIZE
    *mu = pow(10.0, hi);
    return 0;
}

/* _trust_region_step: an acceptable point within the trust radius (the projector's step
 * tried first whatever its length, taken beyond the radius when predicted to 5 %; a step
 * lowering δ taken as eq. 18 takes it). Returns 1 with the trial in st->pts[1], 0 when
 * nothing is acceptable, -1 on a singular factor */
static int kg_trust_region_step(kg_state *st, double *mu_out)
{
    const kg_problem *pb = st->pb;
    const int n = KG_N;
    kg_point *x = st->pts[0], *trial = st->pts[1];
    const kg_lin *lin = st->lin;
    double ones[KG_N + 1];
    for (int u = 0; u < n; ++u) ones[u] = 1.0;
    const double length = kg_norm(n, st->proj->q, x->q);
    for (int attempt = 0; attempt < KG_MAX_HALVINGS; ++attempt) {
        double mu = 0.0;
        const int beyond = attempt == 0 && length > st->radius;
        if (attempt && length > st->radius && kg_damping_for(st, st->radius, ones, &mu))
            return -1;
        kg_proj *target = st->proj;
        if (mu != 0.0) {
            if (kg_solve(pb, lin, mu, st->target, 1, ones)) return -1;
            target = st->target;
        }
        memcpy(trial->q, target->q, sizeof(double) * n);
        kg_copy_measures(pb, target->mt, trial->mt);
        kg_restored(pb, trial, NULL);
        double s[KG_N + 1], pred = 0.0, quad = 0.0;
        for (int u = 0; u < n; ++u) s[u] = trial->q[u] - x->q[u];
        const double size = kg_norm(n, trial->q, x->q);
        for (int u = 0; u < n; ++u) {
            double acc = 0.0;
            for (int v = 0; v < n; ++v) acc += lin->info[u * n + v] * s[v];
            pred += s[u] * lin->rhs[u];
            quad += s[u] * acc;
        }
        pred -= 0.5 * quad; /* the linearised fall of L² */
        const int finite = kg_finite(trial);
        if (finite && kg_lowers_violation(trial, x, st->eps_delta)) {
            *mu_out = mu;
            return 1; /* eq. 18: the violation falls */
        }
        if (finite && kg_acceptable(trial, x, st->eps_delta, st->delta_cap)) {
            const int rounding = pred <= 1e-13 * x->cost;
            const double rho = pred > 0.0 ? (x->cost - trial->cost) / pred : 0.0;
            if (mu == 0.0 && beyond && !(fabs(rho - 1.0) <= 0.05)) continue;
            if (rounding || rho > 1e-4) {
                if (rho < KG_SHRINK && !rounding) st->radius = 0.25 * size;
                else if (rho > KG_GROW) st->radius = st->radius > 2.0 * size ? st->radius
                                                                               : 2.0 * size;
                *mu_out = mu;
                return 1;
            }
        }
        if (mu == 0.0 && beyond) continue;
        st->radius = 0.25 * (isfinite(size) ? (st->radius < size ? st->radius : size)
                                            : st->radius);
        if (!(st->radius > 0.0)) return 0;
    }
    return 0;
}

static void kg_swap(kg_state *st)
{
    kg_point *t = st->pts[0];
    st->pts[0] = st->pts[1];
    st->pts[1] = t;
}

static int kg_proj_finite(const kg_problem *pb, const kg_proj *pr)
{
    for (int u = 0; u < pb->n; ++u)
        if (!isfinite(pr->q[u])) return 0;
    for (int c = 0; c < pb->nch; ++c)
        for (long j = 0; j < pb->ch[c].M * pb->ch[c].k; ++j)
            if (!isfinite(pr->mt[c][j])) return 0;
    return 1;
}

/* _iterate: eq. 18 from (q_start, m). On return st->pts[0] is the returned point;
 * *lin_at_point says whether st->lin and st->proj were computed at it */
static int kg_iterate(kg_state *st, const double *q_start, int max_iter, double xtol,
                      int *iterations, double *start_violation, int *lin_at_point)
{
    const kg_problem *pb = st->pb;
    kg_point *x = st->pts[0];
    const int n = KG_N;
    *lin_at_point = 0;
    memcpy(x->q, q_start, sizeof(double) * n);
    for (int c = 0; c < pb->nch; ++c)
        memcpy(x->mt[c], pb->ch[c].m, sizeof(double) * pb->ch[c].M * pb->ch[c].k);
    kg_evaluate(pb, x);
    *start_violation = x->delta;
    *iterations = 0;
    if (!kg_finite(x)) return KG_FAILED;
    st->eps_delta = 1e-12 * (1.0 + x->delta);
    kg_point *restored = st->pts[1];
    memcpy(restored->q, q_start, sizeof(double) * n);
    kg_copy_measures(pb, x->mt, restored->mt);
    kg_restored(pb, restored, NULL);
    if (kg_finite(restored) && restored->delta <= x->delta) kg_swap(st);
    st->delta_cap = 1e-2 * st->pts[0]->delta;
    double mu = 0.0, best_q = INFINITY, best_m = INFINITY, last_cost = INFINITY;
    int since_best = 0;
    const int region = pb->p0 == 0; /* _TrustRegion: no parameter constraints */
    if (region) {
        double zero[KG_N + 1] = {0};
        st->radius = kg_norm(n, q_start, zero);
        if (st->radius == 0.0) st->radius = 1.0;
    }
    for (int it = 1; it <= max_iter; ++it) {
        x = st->pts[0];
        *iterations = it;
        kg_linearise(pb, x, st->lin);
        if (kg_solve(pb, st->lin, 0.0, st->proj, 1, NULL) || !kg_proj_finite(pb, st->proj))
            return KG_FAILED; /* "in the projector": no linearisation kept */
        if (kg_negligible(pb, x->q, st->proj->q, x->mt, st->proj->mt, xtol)) {
            kg_point *next = st->pts[1];
            memcpy(next->q, st->proj->q, sizeof(double) * n);
            kg_copy_measures(pb, st->proj->mt, next->mt);
            kg_evaluate(pb, next);
            if (kg_finite(next)) kg_swap(st);
            else *lin_at_point = 1;
            return KG_CONVERGED;
        }
        double size_q, size_m;
        kg_step_sizes(pb, x, st->proj, &size_q, &size_m);
        if (size_q < 0.9 * best_q || size_m < 0.9 * best_m || x->cost < (1 - 1e-12) * last_cost) {
            best_q = size_q < best_q ? size_q : best_q; /* Python min() */
            best_m = size_m < best_m ? size_m : best_m;
            since_best = 0;
        } else if (++since_best >= KG_STAGNATION) {
            *lin_at_point = 1;
            return KG_STALLED;
        }
        int guard = pb->guard && kg_relations(pb, x->q);
        double alpha = 1.0;
        int found = region ? kg_trust_region_step(st, &mu)
                           : kg_line_search(st, &mu, &alpha, guard);
        if (found < 0) return KG_FAILED;
        if (found == 0) {
            *lin_at_point = 1;
            return KG_STALLED;
        }
        kg_point *trial = st->pts[1];
        if (kg_diverging(pb, x->q, trial->q, q_start)) {
            kg_swap(st);
            return KG_BOUNDARY; /* on the boundary of the open set: no linearisation kept */
        }
        mu = mu > KG_MU_MIN ? mu / 10 : 0.0;
        if (alpha < 1 && kg_negligible(pb, x->q, trial->q, x->mt, trial->mt, xtol)) {
            kg_swap(st);
            return KG_STALLED;
        }
        last_cost = x->cost;
        kg_swap(st);
    }
    return KG_MAX_ITER;
}

/* ---------------------------------------------------------------- runtime/results.py */

/* eigh: eigenvalues w and eigenvectors V (columns, row-major) of the symmetric K (N × N,
 * overwritten), by cyclic Jacobi rotations: the small eigenvalues of the bordered
 * information keep their relative accuracy (Householder + QL loses it on ill-conditioned
 * families: the covariance of an ellipse with its slack came out 1e-8 off where LAPACK is
 * 1e-11 from the exact inverse). The order is not sorted (the covariance does not depend
 * on it). */
static void kg_eigh(int N, double *K, double *w, double *V)
{
    memset(V, 0, sizeof(double) * N * N);
    for (int i = 0; i < N; ++i) V[i * N + i] = 1.0;
    double total = 0.0;
    for (int i = 0; i < N * N; ++i) total += K[i] * K[i];
    /* an off-diagonal entry below this is rounding noise: zeroed instead of rotated */
    double negligible = 1e-3 * DBL_EPSILON * sqrt(total);
    for (int sweep = 0; sweep < 60; ++sweep) {
        int rotated = 0;
        for (int p = 0; p < N - 1; ++p)
            for (int q = p + 1; q < N; ++q) {
                double apq = K[p * N + q];
                if (fabs(apq) <= negligible) {
                    K[p * N + q] = K[q * N + p] = 0.0;
                    continue;
                }
                rotated = 1;
                double theta = (K[q * N + q] - K[p * N + p]) / (2 * apq);
                double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1 / sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < N; ++k) { /* K ← Jᵀ K J */
                    double kp = K[k * N + p], kq = K[k * N + q];
                    K[k * N + p] = c * kp - s * kq;
                    K[k * N + q] = s * kp + c * kq;
                }
                for (int k = 0; k < N; ++k) {
                    double pk = K[p * N + k], qk = K[q * N + k];
                    K[p * N + k] = c * pk - s * qk;
                    K[q * N + k] = s * pk + c * qk;
                }
                for (int k = 0; k < N; ++k) {
                    double vp = V[k * N + p], vq = V[k * N + q];
                    V[k * N + p] = c * vp - s * vq;
                    V[k * N + q] = s * vp + c * vq;
                }
            }
        if (!rotated) break;
    }
    for (int i = 0; i < N; ++i) w[i] = K[i * N + i];
}

/* One-sided Jacobi (Hestenes): the columns of A (rows × cols, row-major) rotated until
 * orthogonal, the rotations accumulated in V (cols × cols, row-major) when not NULL; the
 * singular values are then the column norms (kg_column_norms). A pair of columns one of
 * which has a squared norm at most floor is not rotated (0: every pair; the null spaces of
 * kanagen_geometry.c pass the rounding level of A, kg_jacobi_null) */
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

/* the null space of C0 (p × n): Z (n × nz, row-major) orthonormal, nz returned — the
 * np.linalg.svd of constrained_covariance: C0's singular values by one-sided Jacobi
 * rotations of the columns of C0ᵀ (rank: those > 1e-12 of the largest), then the
 * orthogonal complement of the kept columns by Householder reflections (another basis of
 * the same null space: the covariance does not depend on it) */
static int kg_null_space(int n, int p, const double *C0, double *Z)
{
    double W[n * (p > 0 ? p : 1)], sigma[p > 0 ? p : 1];
    for (int i = 0; i < n; ++i)
        for (int r = 0; r < p; ++r) W[i * p + r] = C0[r * n + i];
    kg_jacobi(n, p, W, NULL, 0.0);
    const double top = kg_column_norms(n, p, W, sigma);
    /* the kept directions, as columns of U (n × rank), reduced to R by reflections
     * H_j = I − 2 v_j v_jᵀ; Z = H_0 … H_{rank−1} [0; I] */
    double U[n * (p > 0 ? p : 1)], Vh[n * (p > 0 ? p : 1)];
    int rank = 0;
    for (int r = 0; r < p && top > 0; ++r)
        if (sigma[r] > 1e-12 * top) {
            for (int i = 0; i < n; ++i) U[i * p + rank] = W[i * p + r] / sigma[r];
            ++rank;
        }
    for (int j = 0; j < rank; ++j) {
        double norm = 0.0;
        for (int i = j; i < n; ++i) norm += U[i * p + j] * U[i * p + j];
        norm = sqrt(norm);
        double alpha = U[j * p + j] > 0 ? -norm : norm, vnorm = 0.0;
        for (int i = 0; i < n; ++i) Vh[i * p + j] = i < j ? 0.0 : U[i * p + j];
        Vh[j * p + j] -= alpha;
        for (int i = j; i < n; ++i) vnorm += Vh[i * p + j] * Vh[i * p + j];
        vnorm = sqrt(vnorm);
        for (int i = j; i < n; ++i) Vh[i * p + j] = vnorm > 0 ? Vh[i * p + j] / vnorm : 0.0;
        for (int c = j + 1; c < rank; ++c) { /* the later columns: H_j U */
            double dot = 0.0;
            for (int i = j; i < n; ++i) dot += Vh[i * p + j] * U[i * p + c];
            for (int i = j; i < n; ++i) U[i * p + c] -= 2 * dot * Vh[i * p + j];
        }
    }
    int nz = n - rank;
    for (int i = 0; i < n; ++i)
        for (int c = 0; c < nz; ++c) Z[i * nz + c] = i == rank + c ? 1.0 : 0.0;
    for (int j = rank - 1; j >= 0; --j)
        for (int c = 0; c < nz; ++c) {
            double dot = 0.0;
            for (int i = j; i < n; ++i) dot += Vh[i * p + j] * Z[i * nz + c];
            for (int i = j; i < n; ++i) Z[i * nz + c] -= 2 * dot * Vh[i * p + j];
        }
    return nz;
}

/* The inverse of the equilibrated K (nz × nz, unit-scale diagonal) by Cholesky, when it
 * certifies that eigh would find no null eigenvalue: λ_min >= 1 / tr(K⁻¹) and λ_max <=
 * tr(K), and 1 / tr(K⁻¹) > 1e-11 tr(K) (ten times the null test of constrained_covariance).
 * Then eigh's inverse is this one, up to rounding of the same order (both are accurate to
 * cond(K) ε on the equilibrated matrix). Returns 0 with Kinv, -1 when not certified. */
static int kg_certified_inverse(int nz, const double *K, double *Kinv)
{
    double L[nz * nz], Li[nz * nz], trace = 0.0, trace_inv = 0.0;
    memset(L, 0, sizeof(double) * nz * nz);
    for (int k = 0; k < nz; ++k) {
        trace += K[k * nz + k];
        double piv = K[k * nz + k];
        for (int j = 0; j < k; ++j) piv -= L[k * nz + j] * L[k * nz + j];
        if (!(piv > 0) || !isfinite(piv)) return -1;
        L[k * nz + k] = sqrt(piv);
        for (int i = k + 1; i < nz; ++i) {
            double rest = K[i * nz + k];
            for (int j = 0; j < k; ++j) rest -= L[i * nz + j] * L[k * nz + j];
            L[i * nz + k] = rest / L[k * nz + k];
        }
    }
    for (int c = 0; c < nz; ++c) /* L⁻¹, column by column */
        for (int a = 0; a < nz; ++a) {
            double acc = a == c ? 1.0 : 0.0;
            for (int j = c; j < a; ++j) acc -= L[a * nz + j] * Li[j * nz + c];
            Li[a * nz + c] = a < c ? 0.0 : acc / L[a * nz + a];
            trace_inv += Li[a * nz + c] * Li[a * nz + c];
        }
    if (!(1.0 / trace_inv > 1e-11 * trace)) return -1;
    for (int a = 0; a < nz; ++a) /* K⁻¹ = L⁻ᵀ L⁻¹ */
        for (int b = 0; b <= a; ++b) {
            double acc = 0.0;
            for (int j = a; j < nz; ++j) acc += Li[j * nz + a] * Li[j * nz + b];
            Kinv[a * nz + b] = Kinv[b * nz + a] = acc;
        }
    return 0;
}

/* constrained_covariance: Z (Zᵀ Q̃ Z)⁻¹ Zᵀ with Z an orthonormal basis of the null space of
 * C0 (the top-left block of [[Q̃, C0ᵀ], [C0, 0]]⁻¹), infinite where a direction is
 * unobservable */
static void kg_constrained_covariance(int n, const double *info, int p, const double *C0,
                                      double *cov)
{
    for (int i = 0; i < n * n; ++i)
        if (!isfinite(info[i])) {
            for (int j = 0; j < n * n; ++j) cov[j] = NAN;
            return;
        }
    for (int i = 0; i < p * n; ++i)
        if (!isfinite(C0[i])) {
            for (int j = 0; j < n * n; ++j) cov[j] = NAN;
            return;
        }
    double Z[n * n];
    int nz = n;
    if (p) {
        nz = kg_null_space(n, p, C0, Z);
    } else {
        for (int i = 0; i < n * n; ++i) Z[i] = 0.0;
        for (int i = 0; i < n; ++i) Z[i * n + i] = 1.0;
    }
    if (nz == 0) {
        for (int j = 0; j < n * n; ++j) cov[j] = 0.0;
        return;
    }
    double ZtQ[nz * n], H[nz * nz], d[nz], w[nz], V[nz * nz], ZV[n * nz];
    for (int a = 0; a < nz; ++a) /* Zᵀ Q̃ Z, symmetrised */
        for (int j = 0; j < n; ++j) {
            double acc = 0.0;
            for (int i = 0; i < n; ++i) acc += Z[i * nz + a] * info[i * n + j];
            ZtQ[a * n + j] = acc;
        }
    for (int a = 0; a < nz; ++a)
        for (int b = 0; b < nz; ++b) {
            double acc = 0.0;
            for (int j = 0; j < n; ++j) acc += ZtQ[a * n + j] * Z[j * nz + b];
            H[a * nz + b] = acc;
        }
    for (int a = 0; a < nz; ++a)
        for (int b = 0; b < a; ++b)
            H[a * nz + b] = H[b * nz + a] = 0.5 * (H[a * nz + b] + H[b * nz + a]);
    double top = 0.0; /* max(float(diag.max(initial=0.0)), 1.0) */
    for (int a = 0; a < nz; ++a) {
        double v = fabs(H[a * nz + a]);
        if (v > top) top = v;
    }
    top = 1.0 > top ? 1.0 : top;
    for (int a = 0; a < nz; ++a) {
        double v = fabs(H[a * nz + a]);
        d[a] = sqrt(v > 0 ? v : top);
    }
    for (int a = 0; a < nz; ++a)
        for (int b = 0; b < nz; ++b) H[a * nz + b] /= d[a] * d[b];
    double Kinv[nz * nz];
    if (!kg_certified_inverse(nz, H, Kinv)) { /* no null direction: Z D⁻¹ K⁻¹ D⁻¹ Zᵀ */
        for (int i = 0; i < n; ++i)
            for (int a = 0; a < nz; ++a) ZV[i * nz + a] = Z[i * nz + a] / d[a];
        double ZK[n * nz]; /* (Z D⁻¹) K⁻¹ */
        for (int i = 0; i < n; ++i)
            for (int b = 0; b < nz; ++b) {
                double acc = 0.0;
                for (int a = 0; a < nz; ++a) acc += ZV[i * nz + a] * Kinv[a * nz + b];
                ZK[i * nz + b] = acc;
            }
        for (int i = 0; i < n; ++i)
            for (int j = 0; j <= i; ++j) {
                double acc = 0.0;
                for (int b = 0; b < nz; ++b) acc += ZK[i * nz + b] * ZV[j * nz + b];
                cov[i * n + j] = cov[j * n + i] = acc;
            }
        return;
    }
    kg_eigh(nz, H, w, V);
    double scale = 0.0;
    for (int l = 0; l < nz; ++l) scale = fabs(w[l]) > scale ? fabs(w[l]) : scale;
    int null[nz], free_[n];
    for (int l = 0; l < nz; ++l) null[l] = scale > 0 ? fabs(w[l]) <= 1e-12 * scale : 1;
    for (int i = 0; i < n; ++i) { /* ZV = Z (V / d); free: |Z V[:, null]| > 1e-8 */
        free_[i] = 0;
        for (int l = 0; l < nz; ++l) {
            double acc = 0.0, raw = 0.0;
            for (int a = 0; a < nz; ++a) {
                acc += Z[i * nz + a] * (V[a * nz + l] / d[a]);
                raw += Z[i * nz + a] * V[a * nz + l];
            }
            ZV[i * nz + l] = acc;
            free_[i] |= null[l] && fabs(raw) > 1e-8;
        }
    }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j <= i; ++j) {
            double a = 0.0, b = 0.0;
            for (int l = 0; l < nz; ++l)
                if (!null[l]) {
                    a += ZV[i * nz + l] / w[l] * ZV[j * nz + l];
                    b += ZV[j * nz + l] / w[l] * ZV[i * nz + l];
                }
            double v = 0.5 * (a + b);
            cov[i * n + j] = cov[j * n + i] = (free_[i] || free_[j]) ? INFINITY : v;
        }
}

/* propagate: J Σ Jᵀ, infinite wherever J touches an unobservable component */
static void kg_propagate(int s, int n, const double *J, const double *cov, double *out)
{
    int touched[s > 0 ? s : 1];
    double SJ[n * (s > 0 ? s : 1)]; /* Σ Jᵀ, non-finite entries of Σ as 0 */
    for (int a = 0; a < s; ++a) {
        touched[a] = 0;
        for (int u = 0; u < n; ++u)
            touched[a] |= !isfinite(cov[u * n + u]) && J[a * n + u] != 0;
    }
    /* zero entries of J add exact zeros to the sums: skipped (derived quantities are
     * often sparse in q: a conic's matrix has one component per entry) */
    for (int u = 0; u < n; ++u)
        for (int b = 0; b < s; ++b) {
            double acc = 0.0;
            for (int v = 0; v < n; ++v) {
                double x = cov[u * n + v], j = J[b * n + v];
                if (j != 0) acc += (isfinite(x) ? x : 0.0) * j;
            }
            SJ[u * s + b] = acc;
        }
    for (int a = 0; a < s; ++a)
        for (int b = 0; b < s; ++b) {
            double acc = 0.0;
            for (int u = 0; u < n; ++u)
                if (J[a * n + u] != 0) acc += J[a * n + u] * SJ[u * s + b];
            out[a * s + b] = (touched[a] || touched[b]) ? INFINITY : acc;
        }
}

/* ------------------------------------------------------------------ the entry point */

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

static void kg_layout_point(kg_arena *a, const kg_problem *pb, kg_point *pt)
{
    const int n = KG_N;
    pt->q = KG_TAKE(a, double, n);
    pt->c0 = KG_TAKE(a, double, pb->p0);
    pt->C0 = KG_TAKE(a, double, pb->p0 * n);
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

static void kg_layout_proj(kg_arena *a, const kg_problem *pb, kg_proj *pr)
{
    pr->q = KG_TAKE(a, double, pb->n);
    pr->kept0 = KG_TAKE(a, int, pb->p0);
    pr->mt = KG_TAKE(a, double *, pb->nch);
    for (int c = 0; c < pb->nch; ++c) {
        double *mt = KG_TAKE(a, double, pb->ch[c].M * pb->ch[c].k);
        if (a->base) pr->mt[c] = mt;
    }
}

static void kg_layout(kg_arena *a, kg_problem *pb, kg_point *pts, kg_lin *lin, kg_proj *prs)
{
    const int n = KG_N;
    for (int c = 0; c < pb->nch; ++c) {
        double *m = KG_TAKE(a, double, pb->ch[c].M * pb->ch[c].k);
        if (a->base) pb->ch[c].m = m;
    }
    for (int j = 0; j < 3; ++j) kg_layout_point(a, pb, &pts[j]);
    kg_layout_proj(a, pb, &prs[0]);
    kg_layout_proj(a, pb, &prs[1]);
    lin->info = KG_TAKE(a, double, n * n);
    lin->H = KG_TAKE(a, double, n * n);
    lin->rhs = KG_TAKE(a, double, n);
    lin->Cbar = KG_TAKE(a, double *, pb->nch);
    lin->rbar = KG_TAKE(a, double *, pb->nch);
    lin->E = KG_TAKE(a, double *, pb->nch);
    lin->L = KG_TAKE(a, double *, pb->nch);
    lin->kept = KG_TAKE(a, int *, pb->nch);
    lin->ranks = KG_TAKE(a, int *, pb->nch);
    for (int c = 0; c < pb->nch; ++c) {
        const kg_channel *ch = &pb->ch[c];
        long M = ch->M;
        int p = ch->p, k = ch->k;
        double *Cbar = KG_TAKE(a, double, M * p * n), *rbar = KG_TAKE(a, double, M * p);
        double *E = KG_TAKE(a, double, M * p * k), *L = KG_TAKE(a, double, M * p * p);
        int *kept = KG_TAKE(a, int, M * p), *ranks = KG_TAKE(a, int, M);
        if (a->base) {
            lin->Cbar[c] = Cbar;
            lin->rbar[c] = rbar;
            lin->E[c] = E;
            lin->L[c] = L;
            lin->kept[c] = kept;
            lin->ranks[c] = ranks;
        }
    }
}

/* fit_problem's outputs: _feasible */
static int kg_feasible(const kg_problem *pb, const kg_point *x, double start_violation,
                       double residual, int *const *ranks, int have_ranks)
{
    if (x->delta == 0.0) return 1;
    int all_kept = 1;
    for (int c = 0; c < pb->nch && have_ranks; ++c)
        for (long i = 0; i < pb->ch[c].M; ++i) all_kept &= ranks[c][i] > 0;
    if (!have_ranks)
        for (int c = 0; c < pb->nch; ++c) all_kept &= pb->ch[c].M == 0;
    if (all_kept) {
        double bound = 1e-10 * (1.0 > x->cost ? 1.0 : x->cost);
        return isfinite(residual) && residual <= bound;
    }
    return x->delta <= 1e-6 * start_violation;
}

/* kg_fit: fit_problem on one model, on packed arguments (integers as doubles):
 *   in:  model, nch, max_iter, guard, eps, xtol, the number of strict slacks, prior (Q0 is
 *        given, else 0), then per channel its id, M, per_measure; per strict slack its
 *        component and power; q_start (n), q0 (n), Q0 (n × n, when prior), k (constants),
 *        then per channel X (M × w), Q and G (k × k, or M × k × k when per_measure)
 *   out: cost, δ, residual E², start violation, status, iterations, rank0, success, dof,
 *        outputs valid (10 numbers), q (n), info (n × n), covariance (n × n), per derived
 *        quantity its value, Jacobian (size × n) and covariance (size × size), then per
 *        channel the corrected measures (M × k) and the ranks (M)
 * Returns 0; 1 when an input is not finite (the caller validates and reports); 2 when out
 * of memory. */
/* The problem of kg_fit's and kg_coherence's input (layout in kg_fit): 1 when the sizes are
 * out of range or a start, prior mean or measure is not finite */
static int kg_read(const double *in, kg_problem *pb, kg_channel *channels, int *max_iter,
                   double *xtol, const double **q_start)
{
    int nch = (int)in[1], n = KG_N;
    pb->model = (int)in[0];
    pb->n = n;
    pb->p0 = kg_p0[pb->model];
    pb->nch = nch;
    pb->ch = channels;
    pb->guard = (int)in[3];
    pb->eps = in[4];
    *max_iter = (int)in[2];
    *xtol = in[5];
    pb->nstrict = (int)in[6];
    if (pb->nstrict < 0 || pb->nstrict > KG_NSLACK) return 1;
    int prior = (int)in[7];
    const double *head = in + 8, *strict = head + 3 * nch, *qs = strict + 2 * pb->nstrict;
    *q_start = qs;
    const double *at = qs + n;
    static const double zeros[KG_N * KG_N + 1];
    for (int j = 0; j < 2 * pb->nstrict; ++j) pb->strict[j] = (int)strict[j];
    pb->q0 = at;
    pb->Q0 = prior ? at + n : zeros;
    pb->k = at + n + (prior ? n * n : 0);
    at = pb->k + KG_NK;
    for (int u = 0; u < n; ++u)
        if (!isfinite(qs[u]) || !isfinite(pb->q0[u])) return 1;
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

/* ChannelData.m (the corrected components of X) and ChannelData.scale of every channel */
static void kg_channel_data(kg_problem *pb)
{
    for (int c = 0; c < pb->nch; ++c) {
        kg_channel *ch = &pb->ch[c];
        double top, qtop = 0.0;
        for (long i = 0; i < ch->M; ++i)
            for (int j = 0; j < ch->k; ++j)
                ch->m[i * ch->k + j] = ch->X[i * ch->w + ch->index[j]];
        top = kg_nanmax_abs(ch->M * ch->k, ch->m);
        for (long i = 0; i < (ch->per_measure ? ch->M : 1); ++i)
            for (int j = 0; j < ch->k; ++j) {
                double v = fabs(ch->Q[i * ch->k * ch->k + j * ch->k + j]);
                if (v != v || qtop != qtop) qtop = NAN; else if (v > qtop) qtop = v;
            }
        ch->scale = ch->M * ch->k > 0 ? top * sqrt(qtop) : 0.0;
    }
}

int kg_fit(const double *in, double *out)
{
    kg_problem pb;
    int nch = (int)in[1], n = KG_N, max_iter;
    double xtol;
    const double *q_start;
    if (nch < 0 || nch > KG_NCH) return 1;
    kg_channel channels[nch > 0 ? nch : 1];
    if (kg_read(in, &pb, channels, &max_iter, &xtol, &q_start)) return 1;
    kg_point pts[3];
    kg_lin lin;
    kg_proj prs[2];
    kg_arena arena = {NULL, 0};
    kg_layout(&arena, &pb, pts, &lin, prs);
    arena.base = malloc(arena.used + 16);
    if (!arena.base) return 2;
    arena.used = 0;
    kg_layout(&arena, &pb, pts, &lin, prs);
    kg_channel_data(&pb);
    kg_state st = {&pb, {&pts[0], &pts[1], &pts[2]}, &lin, &prs[0], &prs[1], 0.0, 0.0, {0.0}};
    int iterations, lin_at_point;
    double start_violation;
    int status = kg_iterate(&st, q_start, max_iter, xtol, &iterations, &start_violation,
                            &lin_at_point);
    kg_point *x = st.pts[0];
    if (status == KG_FAILED && iterations == 0) start_violation = 0.0;
    int valid = 1;
    if (!lin_at_point) { /* the outputs are taken at the returned point: project(x) */
        kg_linearise(&pb, x, &lin);
        valid = kg_solve(&pb, &lin, 0.0, st.proj, 0, NULL) == 0;
    }
    double *out_q = out + 10, *out_info = out_q + n, *out_cov = out_info + n * n;
    double *out_derived = out_cov + n * n, *out_ch = out_derived;
    for (int j = 0; j < KG_NDERIVED; ++j) {
        int s = kg_derived_size[j];
        out_ch += s + s * n + s * s;
    }
    int rank0 = 0;
    double residual = NAN;
    long sum_ranks = 0;
    if (valid) {
        int p0 = pb.p0, kept_rows = 0;
        double C0k[p0 * n > 0 ? p0 * n : 1];
        for (int r = 0; r < p0; ++r)
            if (st.proj->kept0[r])
                memcpy(C0k + n * kept_rows++, x->C0 + r * n, sizeof(double) * n);
        memcpy(out_info, lin.info, sizeof(double) * n * n);
        kg_constrained_covariance(n, lin.info, kept_rows, C0k, out_cov);
        rank0 = st.proj->rank0;
        residual = st.proj->residual;
    } else {
        for (int j = 0; j < n * n; ++j) out_info[j] = out_cov[j] = NAN;
    }
    for (int c = 0; c < nch; ++c) {
        long M = channels[c].M, mk = M * channels[c].k;
        memcpy(out_ch, x->mt[c], sizeof(double) * mk);
        for (long i = 0; i < M; ++i) {
            out_ch[mk + i] = valid ? lin.ranks[c][i] : 0;
            sum_ranks += valid ? lin.ranks[c][i] : 0;
        }
        out_ch += mk + M;
    }
    int success = (status == KG_CONVERGED || status == KG_STALLED)
                  && kg_feasible(&pb, x, start_violation, residual, lin.ranks, valid)
                  && status != KG_FAILED;
    memcpy(out_q, x->q, sizeof(double) * n);
    out[0] = x->cost;
    out[1] = x->delta;
    out[2] = residual;
    out[3] = start_violation;
    out[4] = status;
    out[5] = iterations;
    out[6] = rank0;
    out[7] = success;
    out[8] = n - rank0 + (double)sum_ranks;
    out[9] = valid;
    if (KG_NDERIVED) { /* derived_values */
        double *d = out_derived;
        kg_derived(x->q, pb.k, d);
        for (int j = 0; j < KG_NDERIVED; ++j) {
            int s = kg_derived_size[j];
            if (kg_reports[pb.model * KG_NDERIVED + j]) /* derived_values(model) */
                kg_propagate(s, n, d + s, out_cov, d + s + s * n);
            d += s + s * n + s * s;
        }
    }
    free(arena.base);
    return 0;
}

/* closest_sqrt of one n × n matrix S (row-major, n <= KG_N) into L: the port's square root
 * on its own, for the differential tests of the port. Returns -1 when n is too large. */
/* coherence.coherence_errors' projection: the measures of kg_fit's input (its start is the
 * q at which they are projected, its iteration cap the projector steps plus one, its xtol
 * the tolerance) projected onto c_i(q, ·) = 0 (project_measures); out per channel, per
 * measure: ‖m̃ − m‖²_Q + the whitened violation, then the equations kept. 1: bad input */
/* kg_coherence on a problem read already: per channel, M totals then M ranks in out */
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

/* solve_minimal: the q closest to the target (kg_fit's start) satisfying c0 and the
 * equations of the given measures (eq. 21, Q0 = 0), the watchdog and line search of the
 * Python; out: q (n), success, rank, iterations, violation. 1: bad input, 2: no memory */
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
