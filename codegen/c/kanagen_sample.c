/* One random sample of the robust search in one call (runtime/robust.py: ModelSearch.step
 * on the compiled backend, docs/fastpath.md): the sample's starts (the search's start, or
 * the candidates of a closed form's compiled twin put into it: _starts, start_from), their
 * minimal solves (solve_minimal: kg_minimal_solve) and, for each solution that passes, the
 * coherence of every measure (coherence_errors at one projection step: kg_coherence_at),
 * in the Python's order and with its arithmetic. Scoring stays in Python: a scorer is any
 * callable, and relevance's np.sum adds pairwise.
 *
 * Compiled after kanagen_fast.c and kanagen_geometry.c (their static functions). The family
 * has no slacks (start_from's candidates need no with_slacks) and the model's samples are
 * not over-determined (the Python fits those). */

typedef int (*kg_twin_fn)(long, const double *, const double *, double *);
/* the compiled twins by number (1, 2, ...): runtime/fastpath.py TWINS, in its order */
static const kg_twin_fn kg_twins[] = {kg_two_view_fundamental, kg_two_view_homography,
                                       kg_two_view_rotation, kg_two_view_translation};
#define KG_NTWINS ((int)(sizeof kg_twins / sizeof kg_twins[0]))
#define KG_TWIN_WIDTH 12 /* values per candidate (initializers._TWO_VIEW_Q) */
#define KG_TWIN_MAX 4    /* candidates at most */

/* The twins' count, for the Python to check its TWINS against (runtime/fastsample.py) */
int kg_sample_twins(void) { return KG_NTWINS; }

/* in: kg_coherence's input (every measure; one projection step). sin: the sampled channel,
 * the rows' count s, the twin's number (0: none), equivalent candidates (stop at the first
 * solution), the full rank, solve_minimal's max_iter, xtol and eps, then per channel the
 * cap on the equations counted (manifold_ranks), the twin's constants (cx, cy, f0), the
 * parameter index of each of its KG_TWIN_WIDTH values (-1: not a candidate's), the start (n)
 * and the rows (s). out: the number of solutions, then per solution its q (n) and every
 * measure's error (eq. 24), channel after channel. Returns 0, -1 when the twin leaves the
 * sample to the Python (runtime/fastpath.py: a degenerate sample), 1 on bad input, 2 when
 * out of memory. */
int kg_sample(const double *in, const double *sin, double *out)
{
    kg_problem pb;
    const int n = KG_N;
    int nch = (int)in[1], iterations;
    double tol;
    const double *unused;
    if (nch < 1 || nch > KG_NCH) return 1;
    kg_channel channels[nch], sub[nch];
    if (kg_read(in, &pb, channels, &iterations, &tol, &unused)) return 1;
    const int c = (int)sin[0], twin = (int)sin[2], equivalent = (int)sin[3];
    const long s = (long)sin[1];
    const int full_rank = (int)sin[4], max_iter = (int)sin[5];
    const double xtol = sin[6], eps = sin[7];
    const double *caps = sin + 8, *k3 = caps + nch, *map = k3 + 3;
    const double *start = map + KG_TWIN_WIDTH, *rows = start + n;
    if (c < 0 || c >= nch || s < 1 || twin < 0 || twin > KG_NTWINS) return 1;
    const kg_channel *ch = &channels[c];
    if (twin && ch->w != 4) return 1;
    long total = 0;
    for (int u = 0; u < nch; ++u) total += channels[u].M;
    const long qsize = (long)ch->k * ch->k, per = ch->per_measure ? s * qsize : 0;
    double *buf = malloc(sizeof(double) * (s * ch->w + 2 * per + n + 4 + 2 * total + 1));
    if (!buf) return 2;
    double *X = buf, *Q = X + s * ch->w, *G = Q + per, *mout = G + per, *coh = mout + n + 4;
    for (long i = 0; i < s; ++i) { /* problem.subset: the sample's rows of channel c */
        long r = (long)rows[i];
        if (r < 0 || r >= ch->M) {
            free(buf);
            return 1;
        }
        memcpy(X + i * ch->w, ch->X + r * ch->w, sizeof(double) * ch->w);
        if (per) {
            memcpy(Q + i * qsize, ch->Q + r * qsize, sizeof(double) * qsize);
            memcpy(G + i * qsize, ch->G + r * qsize, sizeof(double) * qsize);
        }
    }
    for (int u = 0; u < nch; ++u) {
        sub[u] = channels[u];
        sub[u].M = u == c ? s : 0;
    }
    sub[c].X = X;
    if (per) {
        sub[c].Q = Q;
        sub[c].G = G;
    }
    kg_problem sample = pb;
    sample.ch = sub;
    sample.eps = eps;
    /* _starts: the start, or each candidate put into it (start_from; a non-finite value
     * drops the candidate) */
    double starts[KG_TWIN_MAX][KG_N + 1];
    int nstarts = 0;
    if (!twin) {
        memcpy(starts[0], start, sizeof(double) * n);
        nstarts = 1;
    } else {
        double cand[KG_TWIN_MAX * KG_TWIN_WIDTH];
        int count = kg_twins[twin - 1](s, X, k3, cand);
        if (count < 0 || count > KG_TWIN_MAX) {
            free(buf);
            return -1;
        }
        for (int j = 0; j < count; ++j) {
            int ok = 1;
            memcpy(starts[nstarts], start, sizeof(double) * n);
            for (int v = 0; v < KG_TWIN_WIDTH && ok; ++v) {
                int at = (int)map[v];
                if (at < 0) continue;
                double value = cand[j * KG_TWIN_WIDTH + v];
                if (!isfinite(value)) ok = 0; else starts[nstarts][at] = value;
            }
            nstarts += ok;
        }
    }
    /* _solutions, then coherence_errors(problem, q, iterations=1, ranks=caps) of each */
    int solutions = 0;
    double *at = out + 1;
    for (int j = 0; j < nstarts; ++j) {
        if (kg_minimal_solve(&sample, starts[j], max_iter, xtol, mout)) {
            free(buf);
            return 2;
        }
        if (!(mout[n] != 0.0 && (int)mout[n + 1] >= full_rank)) continue;
        memcpy(at, mout, sizeof(double) * n);
        if (kg_coherence_at(&pb, mout, iterations, tol, coh)) {
            free(buf);
            return 2;
        }
        double *errors = at + n;
        for (int u = 0, from = 0; u < nch; from += 2 * (int)channels[u].M, ++u) {
            const long M = channels[u].M;
            const int cap = (int)caps[u];
            for (long i = 0; i < M; ++i) {
                int rank = (int)coh[from + M + i];
                rank = rank < cap ? rank : cap;
                double e = coh[from + i] / (double)(rank > 1 ? rank : 1);
                errors[i] = isfinite(e) ? e : INFINITY;
            }
            errors += M;
        }
        at += n + total;
        ++solutions;
        if (equivalent) break; /* the other candidates are the same estimate */
    }
    out[0] = solutions;
    free(buf);
    return 0;
}
