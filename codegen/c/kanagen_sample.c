/* One random sample of the robust search in one call (runtime/robust.py: ModelSearch.step
 * on the compiled backend, docs/fastpath.md): the sample's starts (the search's start, or
 * the candidates of a closed form's compiled twin put into it: _starts, start_from), their
 * minimal solves (solve_minimal: kg_minimal_solve) and, for each solution that passes, the
 * coherence of every measure (coherence_errors at one projection step: kg_coherence_at),
 * in the Python's order and with its arithmetic. Scoring stays in Python: a scorer is any
 * callable, and relevance's np.sum adds pairwise.
 *
 * Compiled after kanagen_fast.c and, when the family names a two-view initializer
 * (KG_TWINS 1), kanagen_geometry.c (their static functions). The family has no slacks
 * (start_from's candidates need no with_slacks) and the model's samples are not
 * over-determined (the Python fits those). */

#include <stdint.h>

#if KG_TWINS
typedef int (*kg_twin_fn)(long, const double *, const double *, double *);
/* the compiled twins by number (1, 2, ...): runtime/fastpath.py TWINS, in its order */
static const kg_twin_fn kg_twins[] = {kg_two_view_fundamental, kg_two_view_homography,
                                       kg_two_view_rotation, kg_two_view_translation};
#define KG_NTWINS ((int)(sizeof kg_twins / sizeof kg_twins[0]))
#else
#define KG_NTWINS 0 /* no twin: kanagen_geometry.c is not compiled in */
#endif
/* values per candidate (two_view_starts._TWO_VIEW_Q; fastpath.TWIN_WIDTH): the layout of
 * kg_sample's input, with or without twins */
#define KG_TWIN_WIDTH 12
#define KG_TWIN_MAX 4    /* candidates at most */

#define KG_CHUNK 64 /* measures projected at a time while a solution may be abandoned */

/* coherence_errors(problem, q, iterations=1, ranks=caps) of every measure, channel after
 * channel, into errors — projected a chunk at a time (each measure's projection is its
 * own). With a best relevance (report eq. 29; -inf: none), the solution is abandoned as
 * soon as the measures left, each adding at most 1/M, cannot lift its relevance to it:
 * an exact bound, with a margin far above the rounding of either sum. Returns 1 when
 * every error is there, 0 when abandoned, -1 out of memory. */
static int kg_sample_errors(const kg_problem *pb, const double *q, int iterations,
                            double tol, const double *caps, double scale, double best,
                            long total, double *coh, double *errors, double *score)
{
    kg_channel view[KG_NCH > 0 ? KG_NCH : 1];
    kg_problem part = *pb;
    part.ch = view;
    for (int u = 0; u < pb->nch; ++u) {
        view[u] = pb->ch[u];
        view[u].M = 0;
    }
    double sum = 0.0;
    long seen = 0;
    for (int u = 0; u < pb->nch; ++u) {
        const kg_channel *ch = &pb->ch[u];
        const long qsize = (long)ch->k * ch->k;
        const int cap = (int)caps[u];
        for (long at = 0; at < ch->M; at += KG_CHUNK) {
            const long M = ch->M - at < KG_CHUNK ? ch->M - at : KG_CHUNK;
            view[u].M = M;
            view[u].X = ch->X + at * ch->w;
            if (ch->per_measure) {
                view[u].Q = ch->Q + at * qsize;
                view[u].G = ch->G + at * qsize;
            }
            if (kg_coherence_at(&part, q, iterations, tol, coh)) return -1;
            for (long i = 0; i < M; ++i) {
                int rank = (int)coh[M + i];
                rank = rank < cap ? rank : cap;
                double e = coh[i] / (double)(rank > 1 ? rank : 1);
                e = isfinite(e) ? e : INFINITY;
                errors[seen + i] = e;
                if (e < scale) sum += 1.0 - 2.0 * e / scale;
            }
            seen += M;
            if (seen < total && (sum + (double)(total - seen)) / (double)total
                    < best - 1e-9 * fabs(best))
                return 0;
        }
        view[u].M = 0;
    }
    *score = total ? sum / (double)total : 0.0; /* eq. 29: relevance (scoring.py) */
    return 1;
}

/* The twins' count, for the Python to check its TWINS against (runtime/fastpath.py; 0:
 * the library has none) */
int kg_sample_twins(void) { return KG_NTWINS; }

/* in: kg_coherence's input (every measure; one projection step). sin: the sampled channel,
 * the rows' count s, the twin's number (0: none), equivalent candidates (stop at the first
 * solution), the full rank, solve_minimal's max_iter, xtol and eps, L* and the best
 * relevance so far (-inf: the scorer is not relevance, no solution is abandoned), then per
 * channel the
 * cap on the equations counted (manifold_ranks), the twin's constants (cx, cy, f0), the
 * parameter index of each of its KG_TWIN_WIDTH values (-1: not a candidate's), the start (n)
 * and the rows (s). out: the number of solutions, then per solution a flag (1: its errors
 * follow; 0: abandoned, it cannot beat the best), its q (n) and every measure's error
 * (eq. 24), channel after channel. Returns 0, -1 when the twin leaves the
 * sample to the Python (runtime/fastpath.py: a degenerate sample), 1 on bad input, 2 when
 * out of memory. */
static int kg_sample_core(const kg_problem *ppb, int iterations, double tol,
                          const double *sin, const double *rows, double *out, double *scores)
{
    const kg_problem pb = *ppb;
    const kg_channel *channels = pb.ch;
    const int n = KG_N, nch = pb.nch;
    kg_channel sub[KG_NCH > 0 ? KG_NCH : 1];
    const int c = (int)sin[0], twin = (int)sin[2], equivalent = (int)sin[3];
    const long s = (long)sin[1];
    const int full_rank = (int)sin[4], max_iter = (int)sin[5];
    const double xtol = sin[6], eps = sin[7], scale = sin[8], best = sin[9];
    const double *caps = sin + 10, *k3 = caps + nch, *map = k3 + 3;
    const double *start = map + KG_TWIN_WIDTH;
    if (c < 0 || c >= nch || s < 1 || twin < 0 || twin > KG_NTWINS) return 1;
    const kg_channel *ch = &channels[c];
    if (twin && ch->w != 4) return 1;
    long total = 0;
    for (int u = 0; u < nch; ++u) total += channels[u].M;
    const long qsize = (long)ch->k * ch->k, per = ch->per_measure ? s * qsize : 0;
    double *buf = malloc(sizeof(double) * (s * ch->w + 2 * per + n + 4 + 2 * KG_CHUNK + 1));
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
    }
#if KG_TWINS
    else {
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
#endif
    /* _solutions, then coherence_errors(problem, q, iterations=1, ranks=caps) of each */
    int solutions = 0;
    double *at = out + 1;
    for (int j = 0; j < nstarts; ++j) {
        if (kg_minimal_solve(&sample, starts[j], max_iter, xtol, mout)) {
            free(buf);
            return 2;
        }
        if (!(mout[n] != 0.0 && (int)mout[n + 1] >= full_rank)) continue;
        memcpy(at + 1, mout, sizeof(double) * n);
        int done = kg_sample_errors(&pb, mout, iterations, tol, caps, scale, best, total, coh,
                                    at + 1 + n, &scores[solutions]);
        if (done < 0) {
            free(buf);
            return 2;
        }
        at[0] = done;
        at += 1 + n + total;
        ++solutions;
        if (equivalent) break; /* the other candidates are the same estimate */
    }
    out[0] = solutions;
    free(buf);
    return 0;
}

/* kg_coherence's input in read into pb (channels: room for KG_NCH), and where sin's rows
 * are; -1 on bad input */
static long kg_sample_read(const double *in, kg_problem *pb, kg_channel *channels,
                           int *iterations, double *tol)
{
    const double *unused;
    const int nch = (int)in[1];
    if (nch < 1 || nch > KG_NCH || kg_read(in, pb, channels, iterations, tol, &unused))
        return -1;
    return 10 + nch + 3 + KG_TWIN_WIDTH + KG_N;
}

int kg_sample(const double *in, const double *sin, double *out)
{
    kg_problem pb;
    kg_channel channels[KG_NCH > 0 ? KG_NCH : 1];
    int iterations;
    double tol, scores[KG_TWIN_MAX];
    const long rows = kg_sample_read(in, &pb, channels, &iterations, &tol);
    if (rows < 0) return 1;
    return kg_sample_core(&pb, iterations, tol, sin, sin + rows, out, scores);
}

/* numpy's bit generator (numpy/random/bitgen.h): a sample's draws come from the search's
 * own Generator, as runtime/robust.py draws them (_bounded, _draw_into) */
typedef struct {
    void *state;
    uint64_t (*next_uint64)(void *st);
    uint32_t (*next_uint32)(void *st);
    double (*next_double)(void *st);
    uint64_t (*next_raw)(void *st);
} kg_bitgen;

/* A uniform integer of [0, n), n >= 1: Lemire's multiply-and-reject on 64-bit raw draws
 * (robust.py _bounded) */
/* numpy's random_bounded_uint64(bitgen, 0, rng, 0, 0) for rng < 2^32 (numpy/random/src/
 * distributions/distributions.c): 0 without a draw when rng is 0, else Lemire's
 * multiply-and-reject on 32-bit words (buffered_bounded_lemire_uint32) */
static uint64_t kg_bounded(kg_bitgen *bg, uint64_t rng)
{
    if (rng == 0) return 0;
    if (rng == 0xFFFFFFFFu) return bg->next_uint32(bg->state);
    const uint32_t excl = (uint32_t)rng + 1u;
    uint64_t m = (uint64_t)bg->next_uint32(bg->state) * excl;
    uint32_t left = (uint32_t)m;
    if (left < excl) {
        const uint32_t floor = (UINT32_MAX - (uint32_t)rng) % excl;
        while (left < floor) {
            m = (uint64_t)bg->next_uint32(bg->state) * excl;
            left = (uint32_t)m;
        }
    }
    return m >> 32;
}

/* numpy's Generator.choice(size, k, replace=False) (numpy/random/_generator.pyx): Floyd's
 * algorithm, then a Fisher-Yates shuffle of the k drawn — the same draws, so a search gives
 * the same samples whichever of the Python and the C draws them. Not numpy's tail shuffle
 * (size > 10000 and k > size / 50: the Python checks) nor sizes of 2^32 or more.
 * Checked against numpy at load (runtime/fastsample.py: choice_matches). */
static void kg_choice(kg_bitgen *bg, long size, long k, int64_t *idx)
{
    for (long j = size - k; j < size; ++j) {
        const int64_t val = (int64_t)kg_bounded(bg, (uint64_t)j);
        const long t = j - size + k;
        int seen = 0;
        for (long u = 0; u < t && !seen; ++u) seen = idx[u] == val;
        idx[t] = seen ? j : val;
    }
    for (long i = k - 1; i >= 1; --i) {
        const long j = (long)kg_bounded(bg, (uint64_t)i);
        const int64_t t = idx[j];
        idx[j] = idx[i];
        idx[i] = t;
    }
}

/* One draw of kg_choice, for the check against numpy's (fastsample.py) */
void kg_choice_draw(void *bitgen, long size, long k, int64_t *idx)
{
    kg_choice(bitgen, size, k, idx);
}

/* k of the size measures of from, without replacement (Generator.choice(from, k,
 * replace=False)), into rows */
static void kg_draw(kg_bitgen *bg, const int64_t *from, long size, long k, double *rows)
{
    int64_t idx[k > 0 ? k : 1];
    kg_choice(bg, size, k, idx);
    for (long i = 0; i < k; ++i) rows[i] = (double)from[idx[i]];
}

/* Samples of a search in one call (ModelSearch.step with a limit, the relevance scorer):
 * each draws its rows (kg_draw: the pool's, then the base's, as ModelSearch._one draws
 * them), runs kg_sample_core and
 * scores its solutions, until one beats the best relevance, or the C leaves a sample to
 * the Python, or limit samples. in, sin: kg_sample's (sin's rows are the drawn ones). pool,
 * base: the measures drawn from (sizes and counts in iin); bitgen: numpy's bitgen_t.
 * iin: limit, pool size, pool draws, base size, base draws. out: samples done (scored),
 * those without a solution, the outcome (0: limit, 1: the last beat the best, 2: the last
 * is left to the Python, its rows in sin), the best relevance, its q (n) and errors.
 * work: kg_sample's out. Returns 0, 1 on bad input. */
int kg_search(const double *in, double *sin, const int64_t *pool, const int64_t *base,
              void *bitgen,
              const int64_t *iin, double *out, double *work)
{
    kg_problem pb;
    kg_channel channels[KG_NCH > 0 ? KG_NCH : 1];
    int iterations;
    double tol, scores[KG_TWIN_MAX];
    const long at = kg_sample_read(in, &pb, channels, &iterations, &tol);
    if (at < 0) return 1;
    kg_bitgen *bg = bitgen;
    const int nch = pb.nch;
    const long limit = (long)iin[0], npool = (long)iin[1], kpool = (long)iin[2],
               nbase = (long)iin[3], kbase = (long)iin[4];
    if (kpool > npool || kbase > nbase || kpool + kbase != (long)sin[1]) return 1;
    double *rows = sin + at;
    long total = 0;
    for (int u = 0; u < nch; ++u) total += channels[u].M;
    const long width = 1 + KG_N + total;
    double best = sin[9];
    long done = 0, degenerate = 0;
    int outcome = 0;
    while (done < limit) {
        kg_draw(bg, pool, npool, kpool, rows);
        kg_draw(bg, base, nbase, kbase, rows + kpool);
        sin[9] = best;
        if (kg_sample_core(&pb, iterations, tol, sin, rows, work, scores) != 0) {
            outcome = 2;
            break;
        }
        ++done;
        const int count = (int)work[0];
        degenerate += count == 0;
        for (int j = 0; j < count; ++j) {
            const double *block = work + 1 + j * width;
            if (block[0] != 0.0 && scores[j] > best) {
                best = scores[j];
                memcpy(out + 4, block + 1, sizeof(double) * (width - 1));
                outcome = 1;
            }
        }
        if (outcome) break;
    }
    out[0] = (double)done;
    out[1] = (double)degenerate;
    out[2] = outcome;
    out[3] = best;
    return 0;
}
