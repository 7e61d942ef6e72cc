/* The closed-form initialisers of the two-view family in C: a mechanical port of
 * runtime/two_view_starts.py (two_view_fundamental, two_view_homography, two_view_rotation,
 * two_view_translation) and of the functions
 * of runtime/geometry.py they call (docs/fastpath.md). Compiled in the translation unit of
 * kanagen_fast.c, after it (kg_column_norms), when a model of the family names one of them
 * (KG_TWINS 1, codegen/compile.py: uses_twins).
 *
 * Null spaces come from Householder reflections (a minimal sample: the complement of
 * its rows) or one-sided Jacobi rotations (over-determined: after a QR of the tall
 * system), 3 × 3 SVDs from Jacobi rotations; their signs, and the basis of a degenerate
 * singular subspace, differ from LAPACK's. Where the Python's outcome depends on that
 * arbitrary choice — a null space larger than the algorithm expects — the functions
 * return -1 ("not covered") and the caller runs the Python: the outcomes are the Python's
 * (best_pose breaks its ties by a rule the basis does not change). Every other outcome is the same up to rounding; the
 * order of the candidates is the order of the roots of the seven-point cubic and of the
 * two decompositions of a homography, which in the Python too follows the arbitrary
 * basis. Matrices are row-major. */

/* runtime/two_view_starts.py */
#define KG_FOCAL_MIN 0.1 /* _FOCAL_RANGE */
#define KG_FOCAL_MAX 10.0
#define KG_TWO_VIEW_Q 12 /* len(_TWO_VIEW_Q): f1 f2 qw qx qy qz tx ty tz wx wy wz */
/* a singular value of a null-space system below this fraction of the largest is taken as
 * zero: the null space is larger than the algorithm expects, its basis arbitrary */
#define KG_DEGENERATE 1e-6

/* runtime/geometry.py: _CUBIC_FROM_VALUES = inv(vander(_ALPHAS, 4)), _ALPHAS = 0, 1, -1, 2 */
static const double kg_alphas[4] = {0.0, 1.0, -1.0, 2.0};
static const double kg_cubic_from_values[16] = {
    0.5, -0.5, -0.16666666666666669, 0.16666666666666666,
    -1, 0.5, 0.5, 0,
    -0.5, 1, -0.33333333333333331, -0.16666666666666666,
    1, 0, 0, 0};

static void kg3_mul(const double *A, const double *B, double *C) /* C = A B (3 × 3) */
{
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            C[i * 3 + j] = A[i * 3] * B[j] + A[i * 3 + 1] * B[3 + j] + A[i * 3 + 2] * B[6 + j];
}

static void kg3_mul_t(const double *A, const double *B, double *C) /* C = A Bᵀ */
{
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            C[i * 3 + j] = A[i * 3] * B[j * 3] + A[i * 3 + 1] * B[j * 3 + 1]
                           + A[i * 3 + 2] * B[j * 3 + 2];
}

static double kg3_det(const double *A)
{
    return A[0] * (A[4] * A[8] - A[5] * A[7]) - A[1] * (A[3] * A[8] - A[5] * A[6])
           + A[2] * (A[3] * A[7] - A[4] * A[6]);
}

static void kg_cross(const double *a, const double *b, double *c) /* cross */
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

static double kg_dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static int kg_unit(int size, double *M) /* _unit; 0 when not finite */
{
    double norm = 0.0;
    for (int i = 0; i < size; ++i) norm += M[i] * M[i];
    norm = sqrt(norm);
    if (!isfinite(norm)) return 0;
    if (norm > 0)
        for (int i = 0; i < size; ++i) M[i] /= norm;
    return 1;
}

/* normalising_transform of the columns (c, c + 1) of X (m × 4): T = [[s, 0, −s x̄],
 * [0, s, −s ȳ], [0, 0, 1]] as (s, x̄, ȳ) */
static void kg_normalising_transform(long m, const double *X, int c, double *T)
{
    double cx = 0.0, cy = 0.0, spread = 0.0;
    for (long i = 0; i < m; ++i) {
        cx += X[i * 4 + c];
        cy += X[i * 4 + c + 1];
    }
    cx /= m;
    cy /= m;
    for (long i = 0; i < m; ++i) {
        double dx = X[i * 4 + c] - cx, dy = X[i * 4 + c + 1] - cy;
        spread += sqrt(dx * dx + dy * dy);
    }
    spread /= m;
    T[0] = spread > 0 ? sqrt(2.0) / spread : 1.0;
    T[1] = cx;
    T[2] = cy;
}

/* _normalised: row i of view v (c = 2v) as homogeneous(x) @ Tᵀ */
static void kg_normalised(const double *X, long i, int c, const double *T, double *p)
{
    p[0] = T[0] * X[i * 4 + c] - T[0] * T[1];
    p[1] = T[0] * X[i * 4 + c + 1] - T[0] * T[2];
    p[2] = 1.0;
}

/* The order of the columns by decreasing norm (an insertion sort: stable, as few as 9) */
static void kg_by_norm(int k, const double *norms, int *order)
{
    for (int j = 0; j < k; ++j) order[j] = j;
    for (int a = 1; a < k; ++a)
        for (int b = a; b > 0 && norms[order[b]] > norms[order[b - 1]]; --b) {
            int t = order[b];
            order[b] = order[b - 1];
            order[b - 1] = t;
        }
}

/* kg_jacobi (kanagen_fast.c) for the null spaces here: a pair of columns of which one is
 * at the rounding level of A (norm <= ε ‖A‖_F) is not rotated — two such columns, the null
 * space of a minimal sample, would be rotated at random for every sweep; rotating one
 * against a large column would move it by less than rounding. V (when not NULL) is
 * accumulated. */
static void kg_jacobi_null(int rows, int cols, double *A, double *V)
{
    double total = 0.0;
    for (int i = 0; i < rows * cols; ++i) total += A[i] * A[i];
    kg_jacobi(rows, cols, A, V, DBL_EPSILON * DBL_EPSILON * total);
}

/* The SVD of a square B (k × k, k <= 9, overwritten) by one-sided Jacobi: S decreasing,
 * V's columns the right vectors, U's (when not NULL) the left ones (b_j / σ_j; a null σ_j
 * leaves a zero column) */
static void kg_svd_square(int k, double *B, double *S, double *V, double *U)
{
    double Vj[81], norms[9];
    int order[9];
    for (int i = 0; i < k * k; ++i) Vj[i] = i % (k + 1) == 0 ? 1.0 : 0.0;
    kg_jacobi_null(k, k, B, Vj);
    kg_column_norms(k, k, B, norms);
    kg_by_norm(k, norms, order);
    for (int j = 0; j < k; ++j) {
        S[j] = norms[order[j]];
        for (int i = 0; i < k; ++i) {
            V[i * k + j] = Vj[i * k + order[j]];
            if (U) U[i * k + j] = norms[order[j]] > 0 ? B[i * k + order[j]] / norms[order[j]] : 0.0;
        }
    }
}

/* The right singular vectors of A (rows × 9, overwritten) as the columns of V (9 × 9) and
 * the singular values S, by decreasing S (np.linalg.svd(A)[2] = Vᵀ): a tall A is first
 * reduced to its triangular factor by Householder reflections (the same singular values
 * and right vectors), then one-sided Jacobi rotations. */
static void kg_svd_right9(long rows, double *A, double *V, double *S)
{
    long r = rows;
    if (rows > 9) {
        for (int j = 0; j < 9; ++j) {
            double norm = 0.0;
            for (long i = j; i < rows; ++i) norm += A[i * 9 + j] * A[i * 9 + j];
            norm = sqrt(norm);
            if (norm == 0) continue;
            double alpha = A[j * 9 + j] > 0 ? -norm : norm;
            double v0 = A[j * 9 + j] - alpha, vv = v0 * v0 + (norm * norm - A[j * 9 + j]
                                                               * A[j * 9 + j]);
            A[j * 9 + j] = v0; /* the reflector's vector in column j, rows j.. */
            if (vv > 0)
                for (int c = j + 1; c < 9; ++c) {
                    double dot = 0.0;
                    for (long i = j; i < rows; ++i) dot += A[i * 9 + j] * A[i * 9 + c];
                    dot *= 2 / vv;
                    for (long i = j; i < rows; ++i) A[i * 9 + c] -= dot * A[i * 9 + j];
                }
            A[j * 9 + j] = alpha;
            for (long i = j + 1; i < rows; ++i) A[i * 9 + j] = 0.0;
        }
        r = 9;
    }
    double W[81];
    for (int i = 0; i < 81; ++i) W[i] = 0.0;
    for (long i = 0; i < r * 9; ++i) W[i] = A[i];
    kg_svd_square(9, W, S, V, NULL);
}

/* The SVD of a 3 × 3 A by one-sided Jacobi: singular values S decreasing, V's columns the
 * right vectors, U's the left ones (b_j / σ_j; a null σ_j leaves a zero column) */
static void kg_svd3(const double *A, double *U, double *S, double *V)
{
    double B[9];
    memcpy(B, A, sizeof B);
    kg_svd_square(3, B, S, V, U);
}

/* The `need` null vectors of A (rows × 9, overwritten; rows = 9 − need, or more) into
 * N (need × 9): 0, or -1 when A has a further negligible singular value (below
 * KG_DEGENERATE of the largest: the null space LAPACK returns would have an arbitrary
 * basis) or is not finite. Over-determined: the right singular vectors of the smallest
 * singular values, the smallest first (np.linalg.svd(A)[2][-1], [-2]). Minimal (rows =
 * 9 − need): the complement of the rows, the last columns of Q in Aᵀ = Q R (Householder),
 * an orthonormal basis of the same null space (the seven-point F do not depend on it). */
static int kg_null9(long rows, double *A, int need, double *N)
{
    if (rows > 9 - need) {
        double V[81], S[9];
        kg_svd_right9(rows, A, V, S);
        if (!isfinite(S[0]) || !(S[8 - need] > KG_DEGENERATE * S[0])) return -1;
        for (int c = 0; c < need; ++c)
            for (int i = 0; i < 9; ++i) N[c * 9 + i] = V[i * 9 + 8 - c];
        return 0;
    }
    const int r = (int)rows;
    double M[72], beta[8], R[64], sv[8]; /* M = Aᵀ (9 × r): the reflectors below R */
    for (int i = 0; i < 9; ++i)
        for (int j = 0; j < r; ++j) M[i * r + j] = A[j * 9 + i];
    for (int j = 0; j < r; ++j) {
        double norm = 0.0;
        for (int i = j; i < 9; ++i) norm += M[i * r + j] * M[i * r + j];
        norm = sqrt(norm);
        double alpha = M[j * r + j] > 0 ? -norm : norm;
        double x0 = M[j * r + j], v0 = x0 - alpha;
        double vv = v0 * v0 + (norm * norm - x0 * x0);
        beta[j] = vv > 0 ? 2 / vv : 0.0;
        M[j * r + j] = v0;
        for (int c = j + 1; c < r; ++c) {
            double dot = 0.0;
            for (int i = j; i < 9; ++i) dot += M[i * r + j] * M[i * r + c];
            dot *= beta[j];
            for (int i = j; i < 9; ++i) M[i * r + c] -= dot * M[i * r + j];
        }
        for (int c = 0; c < r; ++c) R[j * r + c] = c < j ? 0.0 : c == j ? alpha : M[j * r + c];
    }
    for (int c = 0; c < need; ++c) { /* Q e_{r+c} = H_0 … H_{r−1} e_{r+c} */
        double *e = N + 9 * c;
        for (int i = 0; i < 9; ++i) e[i] = i == r + c ? 1.0 : 0.0;
        for (int j = r - 1; j >= 0; --j) {
            double dot = 0.0;
            for (int i = j; i < 9; ++i) dot += M[i * r + j] * e[i];
            dot *= beta[j];
            for (int i = j; i < 9; ++i) e[i] -= dot * M[i * r + j];
        }
    }
    kg_jacobi_null(r, r, R, NULL); /* the singular values of A: those of R */
    double top = kg_column_norms(r, r, R, sv), low = top;
    for (int j = 0; j < r; ++j) low = sv[j] < low ? sv[j] : low;
    return isfinite(top) && low > KG_DEGENERATE * top ? 0 : -1;
}

/* np.roots of the cubic c (highest power first), the roots kept by fundamental_7point
 * (|imag| <= 1e-8 (1 + |real|)) into roots: their number, or -1 when np.roots would raise
 * (coefficients not finite) */
static double kg_horner(int degree, const double *p, double x)
{
    double v = p[0];
    for (int i = 1; i <= degree; ++i) v = v * x + p[i];
    return v;
}

static double kg_polish(int degree, const double *p, double x) /* Newton steps */
{
    for (int it = 0; it < 3; ++it) {
        double v = p[0], d = 0.0;
        for (int i = 1; i <= degree; ++i) {
            d = d * x + v;
            v = v * x + p[i];
        }
        if (d == 0 || !isfinite(v / d)) break;
        double next = x - v / d;
        if (fabs(kg_horner(degree, p, next)) >= fabs(v)) break;
        x = next;
    }
    return x;
}

static int kg_keep(double re, double im, double *roots, int n)
{
    if (fabs(im) > 1e-8 * (1 + fabs(re))) return n;
    roots[n] = re;
    return n + 1;
}

static int kg_real_roots(const double *c, double *roots)
{
    for (int i = 0; i < 4; ++i)
        if (!isfinite(c[i])) return -1;
    int first = 0, last = 3;
    while (first < 4 && c[first] == 0) ++first;
    if (first == 4) return 0;
    while (c[last] == 0) --last;
    const double *p = c + first;
    int degree = last - first, n = 0;
    if (degree == 1) {
        n = kg_keep(-p[1] / p[0], 0.0, roots, n);
    } else if (degree == 2) {
        double disc = p[1] * p[1] - 4 * p[0] * p[2];
        if (disc >= 0) {
            double q = -(p[1] + (p[1] >= 0 ? 1.0 : -1.0) * sqrt(disc)) / 2;
            n = kg_keep(kg_polish(2, p, q / p[0]), 0.0, roots, n);
            n = kg_keep(kg_polish(2, p, p[2] / q), 0.0, roots, n);
        } else {
            n = kg_keep(-p[1] / (2 * p[0]), sqrt(-disc) / (2 * fabs(p[0])), roots, n);
        }
    } else if (degree == 3) {
        double a = p[1] / p[0], b = p[2] / p[0], cc = p[3] / p[0];
        double Q = (a * a - 3 * b) / 9, R = (2 * a * a * a - 9 * a * b + 27 * cc) / 54;
        if (R * R < Q * Q * Q) { /* three real roots */
            double theta = acos(R / sqrt(Q * Q * Q)), sq = -2 * sqrt(Q);
            for (int k = 0; k < 3; ++k)
                n = kg_keep(kg_polish(3, p, sq * cos((theta + 2 * 3.14159265358979323846 * k) / 3) - a / 3), 0.0,
                            roots, n);
        } else { /* one real root and a pair: the pair from the deflated quadratic */
            double A = -(R >= 0 ? 1.0 : -1.0) * cbrt(fabs(R) + sqrt(R * R - Q * Q * Q));
            double B = A != 0 ? Q / A : 0.0;
            double x = kg_polish(3, p, A + B - a / 3);
            n = kg_keep(x, 0.0, roots, n);
            double b1 = a + x, b0 = b + x * b1; /* x² + b1 x + b0 */
            double disc = b1 * b1 - 4 * b0;
            if (disc >= 0) {
                double q = -(b1 + (b1 >= 0 ? 1.0 : -1.0) * sqrt(disc)) / 2;
                n = kg_keep(kg_polish(3, p, q), 0.0, roots, n);
                if (q != 0) n = kg_keep(kg_polish(3, p, b0 / q), 0.0, roots, n);
            } else {
                n = kg_keep(-b1 / 2, sqrt(-disc) / 2, roots, n);
            }
        }
    }
    for (int i = last; i < 3; ++i) n = kg_keep(0.0, 0.0, roots, n); /* trailing zeros */
    return n;
}

/* fundamental_8point, fundamental_7point: the candidates F (unit, pixels) into Fs; their
 * number, or -1 (not covered) */
static int kg_fundamental(long m, const double *X, double *Fs)
{
    double T1[3], T2[3];
    kg_normalising_transform(m, X, 0, T1);
    kg_normalising_transform(m, X, 2, T2);
    double stack[9 * 40], *A = m <= 40 ? stack : malloc(sizeof(double) * 9 * m);
    if (!A) return -1;
    for (long i = 0; i < m; ++i) { /* _epipolar_rows: p2 ⊗ p1 */
        double p1[3], p2[3];
        kg_normalised(X, i, 0, T1, p1);
        kg_normalised(X, i, 2, T2, p2);
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) A[i * 9 + a * 3 + b] = p2[a] * p1[b];
    }
    double Nv[18];
    int null = kg_null9(m, A, m == 7 ? 2 : 1, Nv);
    if (A != stack) free(A);
    if (null < 0) return -1;
    /* Tᵀ F T with T = [[s, 0, −s x̄], [0, s, −s ȳ], [0, 0, 1]] */
    double Ta[9] = {T1[0], 0, -T1[0] * T1[1], 0, T1[0], -T1[0] * T1[2], 0, 0, 1};
    double Tb[9] = {T2[0], 0, -T2[0] * T2[1], 0, T2[0], -T2[0] * T2[2], 0, 0, 1};
    double Tbt[9] = {Tb[0], Tb[3], Tb[6], Tb[1], Tb[4], Tb[7], Tb[2], Tb[5], Tb[8]};
    int count = 0;
    double roots[3];
    double F1[9], F2[9];
    for (int i = 0; i < 9; ++i) {
        F1[i] = Nv[i];
        F2[i] = m == 7 ? Nv[9 + i] : 0.0;
    }
    if (m == 7) {
        double dets[4], c[4];
        for (int a = 0; a < 4; ++a) {
            double M[9];
            for (int i = 0; i < 9; ++i) M[i] = kg_alphas[a] * F1[i] + (1 - kg_alphas[a]) * F2[i];
            dets[a] = kg3_det(M);
        }
        for (int i = 0; i < 4; ++i)
            c[i] = kg_cubic_from_values[i * 4] * dets[0] + kg_cubic_from_values[i * 4 + 1]
                   * dets[1] + kg_cubic_from_values[i * 4 + 2] * dets[2]
                   + kg_cubic_from_values[i * 4 + 3] * dets[3];
        count = kg_real_roots(c, roots);
        if (count < 0) return -1;
    } else { /* rank 2: the closest in Frobenius norm */
        double U3[9], S3[3], V3[9], D[9];
        kg_svd3(F1, U3, S3, V3);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                D[i * 3 + j] = U3[i * 3] * S3[0] * V3[j * 3] + U3[i * 3 + 1] * S3[1]
                               * V3[j * 3 + 1];
        memcpy(F1, D, sizeof D);
        roots[0] = 1.0;
        count = 1;
    }
    for (int r = 0; r < count; ++r) {
        double F[9], G[9];
        for (int i = 0; i < 9; ++i) F[i] = roots[r] * F1[i] + (1 - roots[r]) * F2[i];
        kg3_mul(Tbt, F, G);
        kg3_mul(G, Ta, Fs + 9 * r);
        if (!kg_unit(9, Fs + 9 * r)) return -1;
    }
    return count;
}

/* focal_lengths(F, pp, pp): squared(F, e2, p1, p2), squared(Fᵀ, e1, p2, p1) */
static double kg_squared(const double *G, const double *e, const double *p,
                         const double *p_other)
{
    double a[3], aG[3], Gtp[3];
    kg_cross(p_other, e, a);
    a[2] = 0.0;
    for (int j = 0; j < 3; ++j) {
        aG[j] = a[0] * G[j] + a[1] * G[3 + j] + a[2] * G[6 + j];
        Gtp[j] = G[j] * p_other[0] + G[3 + j] * p_other[1] + G[6 + j] * p_other[2];
    }
    double den = aG[0] * Gtp[0] + aG[1] * Gtp[1];
    return den != 0 ? -kg_dot3(aG, p) * kg_dot3(p, Gtp) / den : INFINITY;
}

static void kg_focal_lengths(const double *F, const double *pp, double *sq)
{
    double U[9], S[3], V[9], e1[3], e2[3], u1[3], u2[3], Ft[9];
    kg_svd3(F, U, S, V); /* epipoles: e1 = Vt[-1], e2 = U[:, -1] (= u1 × u2) */
    for (int i = 0; i < 3; ++i) {
        e1[i] = V[i * 3 + 2];
        u1[i] = U[i * 3];
        u2[i] = U[i * 3 + 1];
    }
    kg_cross(u1, u2, e2);
    double p[3] = {pp[0], pp[1], 1.0};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) Ft[i * 3 + j] = F[j * 3 + i];
    sq[0] = kg_squared(F, e2, p, p);
    sq[1] = kg_squared(Ft, e1, p, p);
}

/* depths and the cheirality count of best_pose */
static long kg_in_front(const double *R, const double *t, long m, const double *y1,
                        const double *y2)
{
    long count = 0;
    for (long i = 0; i < m; ++i) {
        const double *b = y2 + 3 * i, *y = y1 + 3 * i;
        double a[3];
        for (int r = 0; r < 3; ++r) a[r] = R[r * 3] * y[0] + R[r * 3 + 1] * y[1] + R[r * 3 + 2] * y[2];
        double aa = kg_dot3(a, a), bb = kg_dot3(b, b), ab = kg_dot3(a, b);
        double at = kg_dot3(a, t), bt = kg_dot3(b, t);
        double det = aa * bb - ab * ab;
        double lam1 = (-bb * at + ab * bt) / det, lam2 = (ab * at - aa * bt) / -det;
        count += lam1 > 0 && lam2 > 0;
    }
    return count;
}

/* quaternion_from_rotation (Shepperd), w >= 0 */
static void kg_quaternion(const double *R, double *q)
{
    double tr = R[0] + R[4] + R[8];
    double cands[4] = {1 + tr, 1 + 2 * R[0] - tr, 1 + 2 * R[4] - tr, 1 + 2 * R[8] - tr};
    int i = 0;
    for (int j = 1; j < 4; ++j)
        if (cands[j] > cands[i]) i = j;
    double r = sqrt(cands[i] > 0 ? cands[i] : 0.0) / 2;
    if (i == 0) {
        q[0] = r; q[1] = (R[7] - R[5]) / (4 * r); q[2] = (R[2] - R[6]) / (4 * r);
        q[3] = (R[3] - R[1]) / (4 * r);
    } else if (i == 1) {
        q[0] = (R[7] - R[5]) / (4 * r); q[1] = r; q[2] = (R[1] + R[3]) / (4 * r);
        q[3] = (R[2] + R[6]) / (4 * r);
    } else if (i == 2) {
        q[0] = (R[2] - R[6]) / (4 * r); q[1] = (R[1] + R[3]) / (4 * r); q[2] = r;
        q[3] = (R[5] + R[7]) / (4 * r);
    } else {
        q[0] = (R[3] - R[1]) / (4 * r); q[1] = (R[2] + R[6]) / (4 * r);
        q[2] = (R[5] + R[7]) / (4 * r); q[3] = r;
    }
    double norm = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    double sign = q[0] / norm >= 0 ? 1.0 : -1.0;
    for (int j = 0; j < 4; ++j) q[j] = sign * q[j] / norm;
}

/* _pose_params into out[2..8] */
static void kg_pose_params(const double *R, const double *t, double *out)
{
    kg_quaternion(R, out + 2);
    for (int i = 0; i < 3; ++i) out[6 + i] = t[i];
}

/* _rays with the focal lengths f1, f2 */
static void kg_rays(long m, const double *X, const double *k, double f1, double f2,
                    double *y1, double *y2)
{
    for (long i = 0; i < m; ++i) {
        y1[3 * i] = (X[4 * i] - k[0]) / k[2];
        y1[3 * i + 1] = (X[4 * i + 1] - k[1]) / k[2];
        y1[3 * i + 2] = f1;
        y2[3 * i] = (X[4 * i + 2] - k[0]) / k[2];
        y2[3 * i + 1] = (X[4 * i + 3] - k[1]) / k[2];
        y2[3 * i + 2] = f2;
    }
}

static int kg_finite_input(long m, const double *X, const double *k)
{
    for (long i = 0; i < 4 * m; ++i)
        if (!isfinite(X[i])) return 0;
    return 1;
}

/* two_view_fundamental: up to 3 candidates of KG_TWO_VIEW_Q values (w: NaN) into out;
 * their number, or -1 when not covered (the caller runs the Python) */
int kg_two_view_fundamental(long m, const double *X, const double *k, double *out)
{
    if (m < 7 || !kg_finite_input(m, X, k)) return 0;
    if (!isfinite(k[0]) || !isfinite(k[1]) || !isfinite(k[2]) || k[2] == 0) return -1;
    double Fs[27];
    int nF = kg_fundamental(m, X, Fs);
    if (nF < 0) return -1;
    double *y = malloc(sizeof(double) * 6 * m);
    if (!y) return -1;
    double *y1 = y, *y2 = y + 3 * m;
    const double f0 = k[2];
    int count = 0;
    for (int c = 0; c < nF; ++c) {
        const double *F = Fs + 9 * c;
        double sq[2];
        kg_focal_lengths(F, k, sq);
        double f1 = sqrt(0.0 > sq[0] ? 0.0 : sq[0]) / f0, f2 = sqrt(0.0 > sq[1] ? 0.0 : sq[1]) / f0;
        if (!(KG_FOCAL_MIN < f1 && f1 < KG_FOCAL_MAX && KG_FOCAL_MIN < f2 && f2 < KG_FOCAL_MAX))
            continue;
        /* E = diag(1, 1, 1/f2) Tinvᵀ F Tinv diag(1, 1, 1/f1), Tinv = [[f0, 0, cx],
         * [0, f0, cy], [0, 0, 1]] */
        double Ti[9] = {f0, 0, k[0], 0, f0, k[1], 0, 0, 1};
        double Tit[9] = {f0, 0, 0, 0, f0, 0, k[0], k[1], 1};
        double G[9], E[9];
        kg3_mul(Tit, F, G);
        kg3_mul(G, Ti, E);
        for (int i = 0; i < 3; ++i) {
            E[6 + i] /= f2;
            E[i * 3 + 2] /= f1;
        }
        /* nearest_essential and essential_poses: U, V of E with det +1 each */
        double U[9], S[3], V[9];
        kg_svd3(E, U, S, V);
        if (!(S[1] > 0) || !isfinite(S[0])) {
            free(y);
            return -1;
        }
        double u1[3] = {U[0], U[3], U[6]}, u2[3] = {U[1], U[4], U[7]}, t[3];
        double v1[3] = {V[0], V[3], V[6]}, v2[3] = {V[1], V[4], V[7]}, v3[3];
        kg_cross(u1, u2, t);
        kg_cross(v1, v2, v3);
        for (int i = 0; i < 3; ++i) {
            U[i * 3 + 2] = t[i];
            V[i * 3 + 2] = v3[i];
        }
        static const double W[9] = {0, -1, 0, 1, 0, 0, 0, 0, 1};
        static const double Wt[9] = {0, 1, 0, -1, 0, 0, 0, 0, 1};
        double UW[9], Ra[9], Rb[9], mt[3] = {-t[0], -t[1], -t[2]};
        kg3_mul(U, W, UW);
        kg3_mul_t(UW, V, Ra);
        kg3_mul(U, Wt, UW);
        kg3_mul_t(UW, V, Rb);
        kg_rays(m, X, k, f1, f2, y1, y2);
        const double *Rs[4] = {Ra, Ra, Rb, Rb}, *ts[4] = {t, mt, t, mt};
        /* best_pose: most points in front, then the larger trace, then the t whose
         * largest component is positive (the first maximum, as Python's max) */
        long counts[4];
        double traces[4], signs[4];
        int best = 0;
        for (int p = 0; p < 4; ++p) {
            counts[p] = kg_in_front(Rs[p], ts[p], m, y1, y2);
            traces[p] = Rs[p][0] + Rs[p][4] + Rs[p][8];
            int i = 0;
            for (int j = 1; j < 3; ++j)
                if (fabs(ts[p][j]) > fabs(ts[p][i])) i = j;
            signs[p] = ts[p][i] > 0 ? 1.0 : (ts[p][i] < 0 ? -1.0 : 0.0);
            if (counts[p] > counts[best] || (counts[p] == counts[best] &&
                    (traces[p] > traces[best] || (traces[p] == traces[best] &&
                                                  signs[p] > signs[best]))))
                best = p;
        }
        double *o = out + KG_TWO_VIEW_Q * count++;
        o[0] = f1;
        o[1] = f2;
        kg_pose_params(Rs[best], ts[best], o);
        o[9] = o[10] = o[11] = NAN;
    }
    free(y);
    return count;
}

/* homography_dlt: H (unit, pixels); 0, or -1 when not covered */
static int kg_homography_dlt(long m, const double *X, double *H)
{
    double T1[3], T2[3];
    kg_normalising_transform(m, X, 0, T1);
    kg_normalising_transform(m, X, 2, T2);
    double stack[9 * 40], *A = 2 * m <= 40 ? stack : malloc(sizeof(double) * 9 * 2 * m);
    if (!A) return -1;
    for (long i = 0; i < m; ++i) {
        double p1[3], p2[3];
        kg_normalised(X, i, 0, T1, p1);
        kg_normalised(X, i, 2, T2, p2);
        double *a = A + 9 * i, *b = A + 9 * (m + i);
        for (int j = 0; j < 3; ++j) {
            a[j] = 0.0;
            a[3 + j] = -p2[2] * p1[j];
            a[6 + j] = p2[1] * p1[j];
            b[j] = p2[2] * p1[j];
            b[3 + j] = 0.0;
            b[6 + j] = -p2[0] * p1[j];
        }
    }
    double Hn[9];
    int null = kg_null9(2 * m, A, 1, Hn);
    if (A != stack) free(A);
    if (null < 0) return -1;
    /* solve(T2, H T1): T2⁻¹ = [[1/s, 0, x̄], [0, 1/s, ȳ], [0, 0, 1]] */
    double Ta[9] = {T1[0], 0, -T1[0] * T1[1], 0, T1[0], -T1[0] * T1[2], 0, 0, 1};
    double Tbi[9] = {1 / T2[0], 0, T2[1], 0, 1 / T2[0], T2[2], 0, 0, 1}, G[9];
    kg3_mul(Hn, Ta, G);
    kg3_mul(Tbi, G, H);
    return kg_unit(9, H) ? 0 : -1;
}

/* homography_poses(H, y1, y2): up to 4 (R, t, w) as 15 values each into poses; their
 * number, or -1 when not covered */
static int kg_homography_poses(const double *H0, long m, const double *y1, const double *y2,
                               double *poses)
{
    double H[9], U[9], S[3], V[9];
    kg_svd3(H0, U, S, V);
    if (!(S[1] > 0) || !isfinite(S[0])) return -1;
    for (int i = 0; i < 9; ++i) H[i] = H0[i] / S[1];
    double total = 0.0;
    for (long i = 0; i < m; ++i) {
        const double *a = y1 + 3 * i, *b = y2 + 3 * i;
        for (int r = 0; r < 3; ++r)
            total += b[r] * (H[r * 3] * a[0] + H[r * 3 + 1] * a[1] + H[r * 3 + 2] * a[2]);
    }
    double det = kg3_det(H);
    if (total < 0 || (total == 0 && det < 0)) /* the sign that gives positive depths */
        for (int i = 0; i < 9; ++i) H[i] = -H[i];
    /* eigh(HᵀH), decreasing: the right singular vectors, s = σ² (σ2 = 1) */
    double s[3];
    for (int j = 0; j < 3; ++j) s[j] = (S[j] / S[1]) * (S[j] / S[1]);
    if (kg3_det(V) < 0)
        for (int i = 0; i < 9; ++i) V[i] = -V[i];
    double s1 = s[0], s3 = s[2];
    if (s1 - s3 < 1e-12) { /* R = U Vᵀ of H's SVD, times the sign of its det */
        double Uh[9], Sh[3], Vh[9], R[9];
        kg_svd3(H, Uh, Sh, Vh);
        kg3_mul_t(Uh, Vh, R);
        double sign = kg3_det(R) > 0 ? 1.0 : kg3_det(R) < 0 ? -1.0 : 0.0;
        for (int i = 0; i < 9; ++i) poses[i] = R[i] * sign;
        poses[9] = poses[10] = 0.0;
        poses[11] = 1.0;
        poses[12] = poses[13] = poses[14] = 0.0;
        return 1;
    }
    double v1[3] = {V[0], V[3], V[6]}, v2[3] = {V[1], V[4], V[7]}, v3[3] = {V[2], V[5], V[8]};
    double a = sqrt(1.0 - s3 > 0 ? 1.0 - s3 : 0.0), b = sqrt(s1 - 1.0 > 0 ? s1 - 1.0 : 0.0);
    double root = sqrt(s1 - s3);
    int count = 0;
    for (int side = 0; side < 2; ++side) {
        double u[3], n[3], Hv2[3], Hu[3], Hvu[3], R[9], T[3];
        double sb = side == 0 ? b : -b;
        for (int i = 0; i < 3; ++i) u[i] = (a * v1[i] + sb * v3[i]) / root;
        kg_cross(v2, u, n);
        for (int r = 0; r < 3; ++r) {
            Hv2[r] = H[r * 3] * v2[0] + H[r * 3 + 1] * v2[1] + H[r * 3 + 2] * v2[2];
            Hu[r] = H[r * 3] * u[0] + H[r * 3 + 1] * u[1] + H[r * 3 + 2] * u[2];
        }
        kg_cross(Hv2, Hu, Hvu);
        for (int i = 0; i < 3; ++i) /* R = W Uᵀ, W = [Hv2, Hu, Hv2 × Hu], U = [v2, u, n] */
            for (int j = 0; j < 3; ++j)
                R[i * 3 + j] = Hv2[i] * v2[j] + Hu[i] * u[j] + Hvu[i] * n[j];
        for (int i = 0; i < 3; ++i) /* T = (H − R) n */
            T[i] = (H[i * 3] - R[i * 3]) * n[0] + (H[i * 3 + 1] - R[i * 3 + 1]) * n[1]
                   + (H[i * 3 + 2] - R[i * 3 + 2]) * n[2];
        double scale = sqrt(kg_dot3(T, T));
        for (int sg = 0; sg < 2; ++sg) {
            double sign = sg == 0 ? 1.0 : -1.0, *o = poses + 15 * count++;
            memcpy(o, R, sizeof R);
            for (int i = 0; i < 3; ++i) {
                o[9 + i] = sign * T[i] / scale;
                o[12 + i] = sign * n[i] * scale;
            }
        }
    }
    int front[4], kept = 0;
    for (int p = 0; p < 4; ++p) { /* np.mean(y1 @ w > 0) > 0.5 */
        long positive = 0;
        for (long i = 0; i < m; ++i) positive += kg_dot3(y1 + 3 * i, poses + 15 * p + 12) > 0;
        front[p] = 2 * positive > m;
        kept += front[p];
    }
    if (kept == 0) return count;
    int at = 0;
    for (int p = 0; p < 4; ++p)
        if (front[p]) {
            if (at != p) memcpy(poses + 15 * at, poses + 15 * p, sizeof(double) * 15);
            ++at;
        }
    return kept;
}

/* The DLT homography in the family's normalised coordinates, Hn = T H T⁻¹ with T the
 * pixels -> (x − cx, y − cy, f0)/f0 map (two_view_homography, two_view_rotation); 0, or -1
 * when not covered */
static int kg_calibrated_dlt(long m, const double *X, const double *k, double *Hn)
{
    double H[9], G[9];
    if (kg_homography_dlt(m, X, H) < 0) return -1;
    const double f0 = k[2];
    double T[9] = {1 / f0, 0, -k[0] / f0, 0, 1 / f0, -k[1] / f0, 0, 0, 1};
    double Ti[9] = {f0, 0, k[0], 0, f0, k[1], 0, 0, 1};
    kg3_mul(T, H, G);
    kg3_mul(G, Ti, Hn);
    return 0;
}

/* two_view_homography: up to 4 candidates of KG_TWO_VIEW_Q values into out; their number,
 * or -1 when not covered (the caller runs the Python) */
int kg_two_view_homography(long m, const double *X, const double *k, double *out)
{
    if (m < 4 || !kg_finite_input(m, X, k)) return 0;
    if (!isfinite(k[0]) || !isfinite(k[1]) || !isfinite(k[2]) || k[2] == 0) return -1;
    double Hn[9], poses[60];
    if (kg_calibrated_dlt(m, X, k, Hn) < 0) return -1;
    double *y = malloc(sizeof(double) * 6 * m);
    if (!y) return -1;
    kg_rays(m, X, k, 1.0, 1.0, y, y + 3 * m);
    int count = kg_homography_poses(Hn, m, y, y + 3 * m, poses);
    free(y);
    for (int c = 0; c < count; ++c) {
        double *o = out + KG_TWO_VIEW_Q * c, *p = poses + 15 * c;
        o[0] = o[1] = 1.0;
        kg_pose_params(p, p + 9, o);
        for (int i = 0; i < 3; ++i) o[9 + i] = p[12 + i];
    }
    return count;
}

/* _DEGENERATE: a singular value below this fraction of the largest is taken as zero */
#define KG_NEGLIGIBLE 1e-6

/* _in_focal_range */
static int kg_in_focal_range(double F)
{
    return F > 0 && KG_FOCAL_MIN < sqrt(F) && sqrt(F) < KG_FOCAL_MAX;
}

/* _rotation_candidate into o[0..5] (the rest NaN) */
static void kg_rotation_candidate(double f, const double *R, double *o)
{
    o[0] = o[1] = f;
    kg_quaternion(R, o + 2);
    for (int i = 6; i < KG_TWO_VIEW_Q; ++i) o[i] = NAN;
}

/* geometry.rotation_from_pairs: R = B Aᵀ of the triads; 0 when a pair is parallel */
static int kg_rotation_from_pairs(const double *a1, const double *a2, const double *b1,
                                  const double *b2, double *R)
{
    double triads[2][9];
    const double *us[2] = {a1, b1}, *vs[2] = {a2, b2};
    for (int s = 0; s < 2; ++s) {
        double n[3], e1[3], e2[3], e3[3];
        kg_cross(us[s], vs[s], n);
        double nu = sqrt(kg_dot3(us[s], us[s])), nn = sqrt(kg_dot3(n, n));
        if (!(nu > 0 && nn > 0)) return 0;
        for (int i = 0; i < 3; ++i) {
            e1[i] = us[s][i] / nu;
            e2[i] = n[i] / nn;
        }
        kg_cross(e1, e2, e3);
        for (int i = 0; i < 3; ++i) { /* columns e1, e2, e3 */
            triads[s][i * 3] = e1[i];
            triads[s][i * 3 + 1] = e2[i];
            triads[s][i * 3 + 2] = e3[i];
        }
    }
    kg3_mul_t(triads[1], triads[0], R);
    return 1;
}

/* _kabsch: the rotation that best maps the unit rays y1 onto y2; 0 when σ2 is negligible */
static int kg_kabsch(long m, const double *y1, const double *y2, double *R)
{
    double M[9] = {0}, U[9], S[3], V[9];
    for (long i = 0; i < m; ++i) {
        const double *a = y1 + 3 * i, *b = y2 + 3 * i;
        double na = sqrt(kg_dot3(a, a)), nb = sqrt(kg_dot3(b, b));
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) M[r * 3 + c] += (b[r] / nb) * (a[c] / na);
    }
    kg_svd3(M, U, S, V);
    if (!(S[1] > KG_NEGLIGIBLE * S[0])) return 0;
    double u1[3] = {U[0], U[3], U[6]}, u2[3] = {U[1], U[4], U[7]};
    double v1[3] = {V[0], V[3], V[6]}, v2[3] = {V[1], V[4], V[7]}, u3[3], v3[3];
    kg_cross(u1, u2, u3);
    kg_cross(v1, v2, v3);
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            R[r * 3 + c] = u1[r] * v1[c] + u2[r] * v2[c] + u3[r] * v3[c];
    return 1;
}

/* two_view_rotation: up to 3 candidates of KG_TWO_VIEW_Q values (t, w: NaN) into out; their
 * number, or -1 when not covered (the caller runs the Python) */
int kg_two_view_rotation(long m, const double *X, const double *k, double *out)
{
    if (m < 2 || m == 3 || !kg_finite_input(m, X, k)) return 0;
    if (!isfinite(k[0]) || !isfinite(k[1]) || !isfinite(k[2]) || k[2] == 0) return -1;
    if (m > 3) { /* DLT, ω = diag(F, F, 1) from Hn ω Hnᵀ = ω, R by Kabsch */
        double Hn[9];
        if (kg_calibrated_dlt(m, X, k, Hn) < 0) return -1;
        double det = kg3_det(Hn);
        if (!(det != 0)) return 0;
        double scale = cbrt(det), A[9], B[9], num = 0.0, den = 0.0;
        for (int i = 0; i < 9; ++i) Hn[i] /= scale;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) {
                double h1 = Hn[r * 3] * Hn[c * 3], h2 = Hn[r * 3 + 1] * Hn[c * 3 + 1];
                double h3 = Hn[r * 3 + 2] * Hn[c * 3 + 2];
                A[r * 3 + c] = h1 + h2 - (r == c && r < 2 ? 1.0 : 0.0);
                B[r * 3 + c] = (r == c && r == 2 ? 1.0 : 0.0) - h3;
            }
        for (int i = 0; i < 9; ++i) {
            num += A[i] * B[i];
            den += A[i] * A[i];
        }
        double F = den > 0 ? num / den : -1.0;
        if (!kg_in_focal_range(F)) return 0;
        double f = sqrt(F), R[9];
        double *y = malloc(sizeof(double) * 6 * m);
        if (!y) return -1;
        kg_rays(m, X, k, f, f, y, y + 3 * m);
        int found = kg_kabsch(m, y, y + 3 * m, R);
        free(y);
        if (!found) return 0;
        kg_rotation_candidate(f, R, out);
        return 1;
    }
    double y1[6], y2[6]; /* the image vectors (x, y, 0) */
    kg_rays(2, X, k, 0.0, 0.0, y1, y2);
    double p = kg_dot3(y1, y1 + 3), q = kg_dot3(y2, y2 + 3);
    double s1 = kg_dot3(y1, y1), s2 = kg_dot3(y1 + 3, y1 + 3);
    double t1 = kg_dot3(y2, y2), t2 = kg_dot3(y2 + 3, y2 + 3);
    /* (p + F)² (t1 + F)(t2 + F) − (q + F)² (s1 + F)(s2 + F), highest power first */
    double cubic[4] = {
        t1 + t2 + 2 * p - s1 - s2 - 2 * q,
        t1 * t2 + 2 * p * (t1 + t2) + p * p - s1 * s2 - 2 * q * (s1 + s2) - q * q,
        2 * p * t1 * t2 + p * p * (t1 + t2) - 2 * q * s1 * s2 - q * q * (s1 + s2),
        p * p * t1 * t2 - q * q * s1 * s2};
    if (cubic[0] == 0 && cubic[1] == 0 && cubic[2] == 0 && cubic[3] == 0) return 0;
    double roots[3];
    int nroots = kg_real_roots(cubic, roots), count = 0;
    if (nroots < 0) return -1;
    for (int r = 0; r < nroots; ++r) {
        double F = roots[r];
        if (!kg_in_focal_range(F) || (p + F > 0) != (q + F > 0)) continue;
        double f = sqrt(F), R[9];
        y1[2] = y1[5] = y2[2] = y2[5] = f;
        if (kg_rotation_from_pairs(y1, y1 + 3, y2, y2 + 3, R))
            kg_rotation_candidate(f, R, out + KG_TWO_VIEW_Q * count++);
    }
    return count;
}

/* two_view_translation: one candidate of KG_TWO_VIEW_Q values (f, q, w: NaN) into out;
 * their number, or -1 when not covered (the caller runs the Python) */
int kg_two_view_translation(long m, const double *X, const double *k, double *out)
{
    if (m < 2 || !kg_finite_input(m, X, k)) return 0;
    if (!isfinite(k[0]) || !isfinite(k[1]) || !isfinite(k[2]) || k[2] == 0) return -1;
    double *y = malloc(sizeof(double) * 9 * m);
    if (!y) return -1;
    double *y1 = y, *y2 = y + 3 * m, *n = y + 6 * m, t[3];
    kg_rays(m, X, k, 1.0, 1.0, y1, y2);
    for (long i = 0; i < m; ++i) kg_cross(y1 + 3 * i, y2 + 3 * i, n + 3 * i);
    if (m == 2) {
        kg_cross(n, n + 3, t);
    } else { /* the right singular vector of the least singular value of n (m × 3) */
        double V[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, S[3];
        kg_jacobi_null((int)m, 3, n, V);
        kg_column_norms(m, 3, n, S);
        int o[3] = {0, 1, 2};
        for (int a = 1; a < 3; ++a)
            for (int b = a; b > 0 && S[o[b]] > S[o[b - 1]]; --b) {
                int tmp = o[b];
                o[b] = o[b - 1];
                o[b - 1] = tmp;
            }
        if (!isfinite(S[o[0]]) || !(S[o[1]] > KG_NEGLIGIBLE * S[o[0]])) {
            free(y);
            return 0;
        }
        for (int i = 0; i < 3; ++i) t[i] = V[i * 3 + o[2]];
    }
    double norm = sqrt(kg_dot3(t, t));
    if (!(norm > 0 && isfinite(norm))) {
        free(y);
        return 0;
    }
    int big = 0;
    for (int i = 0; i < 3; ++i) {
        t[i] /= norm;
        if (fabs(t[i]) > fabs(t[big])) big = i;
    }
    double sign = t[big] < 0 ? -1.0 : 1.0;
    for (int i = 0; i < 3; ++i) t[i] *= sign;
    static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    double mt[3] = {-t[0], -t[1], -t[2]};
    if (kg_in_front(I3, mt, m, y1, y2) > kg_in_front(I3, t, m, y1, y2)) /* best_pose */
        memcpy(t, mt, sizeof t);
    free(y);
    for (int i = 0; i < KG_TWO_VIEW_Q; ++i) out[i] = NAN;
    for (int i = 0; i < 3; ++i) out[6 + i] = t[i];
    return 1;
}
