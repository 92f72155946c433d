/* The Newton re-solve of a warm start in one compiled call (corrections_sim.planning.newton).
 *
 * Compiled into one library with the CasADi-generated evaluations, and called through
 * ctypes. f, ∇f, c, J and W = ∇²(f − μᵀc) are assembled by waypoint: newton_waypoint gives a
 * free waypoint's features φ_i, its two clearances, their Jacobian, and the gradient and
 * Hessian of θ·φ_i; newton_clearance the Hessian of μ_i·c_i, asked only where a multiplier is
 * nonzero (the clearances are 85% of the whole Hessian's operations, and one or two of the
 * 2 (T − 2) are active); the smoothness term λ Σ‖q^{i+1} − q^i‖² is written out here.
 * newton_features gives Φ of the whole trajectory at the answer. LAPACK comes as function pointers from SciPy's
 * cython_lapack (no system LAPACK): dpbtrf / dpbtrs (W's banded Cholesky), dposv (Schur
 * complements, least-squares multipliers), dgesv (the KKT system when W is not positive
 * definite).
 *
 * It is the loop of NewtonPath._solve_python, step for step (see the Python module for what
 * each step means and why its constants are what they are): guess the active set, gate on
 * the start's stationarity residual, Newton steps on the KKT system with one active-set
 * change per converged step, and the first-order and bound checks of the certificate with
 * W's banded Cholesky at the answer. Where W is not positive definite at the answer, the
 * reduced Hessian is checked by the caller (NEWTON_REDUCED); where the start's multipliers
 * need a least-squares solve of a rank-deficient system, the caller solves them
 * (NEWTON_LSTSQ) — both rare.
 *
 * Column-major storage throughout (LAPACK's). The Jacobian and W arrive as CasADi nonzeros
 * with their (row, column) triplets.
 */
#include <math.h>
#include <string.h>

typedef long long casadi_int_t;
typedef int (*casadi_fn)(const double **arg, double **res, casadi_int_t *iw, double *w, int mem);
typedef int (*casadi_work_fn)(casadi_int_t *sz_arg, casadi_int_t *sz_res, casadi_int_t *sz_iw,
                              casadi_int_t *sz_w);

int newton_waypoint(const double **, double **, casadi_int_t *, double *, int);
int newton_waypoint_work(casadi_int_t *, casadi_int_t *, casadi_int_t *, casadi_int_t *);
int newton_clearance(const double **, double **, casadi_int_t *, double *, int);
int newton_clearance_work(casadi_int_t *, casadi_int_t *, casadi_int_t *, casadi_int_t *);
int newton_features(const double **, double **, casadi_int_t *, double *, int);
int newton_features_work(casadi_int_t *, casadi_int_t *, casadi_int_t *, casadi_int_t *);

typedef void (*dpbtrf_t)(char *, int *, int *, double *, int *, int *);
typedef void (*dpbtrs_t)(char *, int *, int *, int *, double *, int *, double *, int *, int *);
typedef void (*dposv_t)(char *, int *, int *, double *, int *, double *, int *, int *);
typedef void (*dgesv_t)(int *, int *, double *, int *, int *, double *, int *, int *);

/* Outcomes (newton.py's NEWTON_* mirror them). */
enum {
    NEWTON_CERTIFIED = 0,   /* a strict local minimum: x, μ, f, Φ filled */
    NEWTON_OK = 0,          /* internal: a start made, or a stage converged */
    NEWTON_REDUCED = 1,     /* a KKT point whose W is not positive definite: the caller checks
                               the reduced Hessian (x, μ, active filled) */
    NEWTON_LSTSQ = 2,       /* the start's multipliers need a least-squares solve */
    NEWTON_GATE = -1,       /* the start's residual is above the gate */
    NEWTON_STALLED = -2,    /* no convergence within the step limits */
    NEWTON_SINGULAR = -3,   /* a KKT system could not be solved */
    NEWTON_INFEASIBLE = -4, /* converged outside a joint limit or with a held joint pulling off */
    NEWTON_EVAL = -5,       /* a compiled evaluation failed */
    NEWTON_INDEFINITE = -6  /* a KKT point with no active clearance whose W is not positive
                               definite: not a strict local minimum */
};

#define KD 7 /* W's half-bandwidth in the waypoint ordering (newton.BANDWIDTH) */
#define LDAB (KD + 1)
#define MAX_PTR 64

#define NJ 7 /* joints per waypoint */

/* W's lower-triangle nonzeros come waypoint by waypoint: the 28 of its 7 × 7 block (column by
 * column, rows from the diagonal down), then the 7 coupling it with the next waypoint (the
 * smoothness term's); the Jacobian's, per waypoint, its 2 × 7 block column by column.
 * h_row/h_col and j_row/j_col (newton.py builds them) name each one's row and column. */
#define BLOCK 28
#define PER_WAYPOINT (BLOCK + NJ)

static int lower_at(int a, int b) { return a * NJ - a * (a - 1) / 2 + (b - a); } /* b >= a */

typedef struct {
    int n, n_c, k, nnz_j, nnz_h;
    const int *j_row, *j_col; /* the Jacobian's nonzeros: constraint, variable */
    const int *h_row, *h_col; /* W's lower-triangle nonzeros: row >= column */
    int n_env;                /* p = (θ (k), env (n_env), q_start (7), q_goal (7), learnt weights) */
    double smoothness;        /* λ */
    const double *lower, *upper;
    double active, at_bound, stationarity, feasibility, gate, slow;
    int max_steps, steps_per_set, slow_after;
    /* The continuation after a failed attempt: stages of residual at most stage_residual, at
     * most max_stages of them, each solved to stage_tolerance (0 stages: none). */
    double stage_residual, stage_tolerance;
    int max_stages;
    dpbtrf_t dpbtrf;
    dpbtrs_t dpbtrs;
    dposv_t dposv;
    dgesv_t dgesv;
} NewtonProblem;

typedef struct {
    int steps, stages;
    double objective, residual; /* residual: the start's (the gate's quantity) */
} NewtonReport;

static casadi_int_t cmax(casadi_int_t a, casadi_int_t b) { return a > b ? a : b; }

/* The CasADi evaluations' largest work arrays (iw, w); 1 if they need more pointers than
 * MAX_PTR or refuse. */
static int casadi_work(casadi_int_t *iw, casadi_int_t *w) {
    casadi_work_fn works[3] = {newton_waypoint_work, newton_clearance_work, newton_features_work};
    casadi_int_t arg = 0, res = 0;
    *iw = *w = 0;
    for (int i = 0; i < 3; i++) {
        casadi_int_t a, r, ii, ww;
        if (works[i](&a, &r, &ii, &ww)) return 1;
        arg = cmax(arg, a), res = cmax(res, r), *iw = cmax(*iw, ii), *w = cmax(*w, ww);
    }
    return arg > MAX_PTR || res > MAX_PTR;
}

/* Doubles and casadi_ints a solve needs as workspace (one per thread); 0 on success. */
int newton_workspace(const NewtonProblem *pr, long long *n_double, long long *n_int) {
    casadi_int_t iw, w;
    if (casadi_work(&iw, &w)) return 1;
    long long n = pr->n, nc = pr->n_c, nk = n + nc;
    *n_double = w + 5 * n + 4 * nc + pr->nnz_j + pr->nnz_h + 2 * LDAB * n + nc * n +
                (nc + 1) * n + nc * nc + nk * nk + nk + pr->k + 2 + 2 * NJ + NJ + NJ * NJ;
    *n_int = iw + (4 * n + 2 * nc + nk + 1) / 2 + 1; /* the ints packed two to a slot */
    return 0;
}

typedef struct {
    const NewtonProblem *pr;
    const double *p;
    casadi_int_t *iw;
    double *w;
    /* state */
    double *x, *grad, *c, *jac, *hess, *mu, f;
    int *on_lower, *held, *free_at, *free, nf; /* free_at[i]: position among the free or -1 */
    int *act, m;                               /* the active clearances, ascending */
    int *row_at;                               /* a clearance's position in act, or -1 */
    double *tilt, tilt_scale; /* the continuation's objective f − tilt_scale · tiltᵀx */
    /* scratch */
    double *g, *ja, *band, *factor, *rhs, *schur, *r, *kkt, *kkt_rhs, *d;
    double *phi_i, *c_i, *jac_i, *grad_i, *hess_i; /* one waypoint's newton_waypoint */
    int *ipiv;
} Solve;

/* f, ∇f, c, J and W without the clearances' curvature, at x. */
static int eval_point(Solve *s) {
    const NewtonProblem *pr = s->pr;
    int nw = pr->n / NJ, k = pr->k;
    double lam = pr->smoothness;
    const double *theta = s->p, *q_start = s->p + k + pr->n_env, *q_goal = q_start + NJ;
    s->f = 0.0;
    for (int i = 0; i < nw; i++) {
        const double *arg[MAX_PTR] = {s->x + NJ * i, s->p};
        double *res[MAX_PTR] = {s->phi_i, s->c_i, s->jac_i, s->grad_i, s->hess_i};
        if (newton_waypoint(arg, res, s->iw, s->w, 0)) return 1;
        for (int j = 0; j < k; j++) s->f -= theta[j] * s->phi_i[j];
        for (int a = 0; a < NJ; a++) s->grad[NJ * i + a] = -s->grad_i[a];
        s->c[2 * i] = s->c_i[0], s->c[2 * i + 1] = s->c_i[1];
        memcpy(s->jac + 2 * NJ * i, s->jac_i, sizeof(double) * 2 * NJ);
        double *block = s->hess + PER_WAYPOINT * i;
        for (int a = 0; a < NJ; a++)
            for (int b = a; b < NJ; b++)
                block[lower_at(a, b)] = -s->hess_i[b + NJ * a] + (a == b ? 4.0 * lam : 0.0);
        if (i + 1 < nw)
            for (int a = 0; a < NJ; a++) block[BLOCK + a] = -2.0 * lam;
    }
    for (int i = 0; i <= nw; i++) { /* the segment from waypoint i − 1 to i (the ends fixed) */
        const double *from = i ? s->x + NJ * (i - 1) : q_start;
        const double *to = i < nw ? s->x + NJ * i : q_goal;
        for (int a = 0; a < NJ; a++) {
            double diff = to[a] - from[a];
            s->f += lam * diff * diff;
            if (i < nw) s->grad[NJ * i + a] += 2.0 * lam * diff;
            if (i) s->grad[NJ * (i - 1) + a] -= 2.0 * lam * diff;
        }
    }
    return 0;
}

/* W −= Σ μ_j ∇²c_j, by waypoint where a multiplier is nonzero. */
static int add_clearance_curvature(Solve *s) {
    int nw = s->pr->n / NJ;
    for (int i = 0; i < nw; i++) {
        if (s->mu[2 * i] == 0.0 && s->mu[2 * i + 1] == 0.0) continue;
        const double *arg[MAX_PTR] = {s->x + NJ * i, s->p, s->mu + 2 * i};
        double *res[MAX_PTR] = {s->hess_i};
        if (newton_clearance(arg, res, s->iw, s->w, 0)) return 1;
        double *block = s->hess + PER_WAYPOINT * i;
        for (int a = 0; a < NJ; a++)
            for (int b = a; b < NJ; b++) block[lower_at(a, b)] -= s->hess_i[b + NJ * a];
    }
    return 0;
}

static int eval_terms(Solve *s) { return eval_point(s) || add_clearance_curvature(s); }

static double inf_norm(const double *v, int n) {
    double m = 0.0;
    for (int i = 0; i < n; i++) m = fabs(v[i]) > m ? fabs(v[i]) : m;
    return m;
}

/* g = ∇f on the free joints, ja = J on the active rows and free columns (m × nf). */
static void gather(Solve *s) {
    const NewtonProblem *pr = s->pr;
    for (int i = 0; i < s->nf; i++) s->g[i] = s->grad[s->free[i]] - s->tilt_scale * s->tilt[i];
    memset(s->ja, 0, sizeof(double) * (size_t)s->m * s->nf);
    for (int j = 0; j < pr->n_c; j++) s->row_at[j] = -1;
    for (int a = 0; a < s->m; a++) s->row_at[s->act[a]] = a;
    for (int t = 0; t < pr->nnz_j; t++) {
        int a = s->row_at[pr->j_row[t]], col = s->free_at[pr->j_col[t]];
        if (a >= 0 && col >= 0) s->ja[a + (size_t)s->m * col] = s->jac[t];
    }
}

/* ‖g − J_𝒜ᵀ μ_𝒜‖∞ on the free joints; the vector itself into ``out`` unless it is NULL. */
static double stationarity(const Solve *s, double *out) {
    double worst = 0.0;
    for (int i = 0; i < s->nf; i++) {
        double v = s->g[i];
        for (int a = 0; a < s->m; a++) v -= s->ja[a + (size_t)s->m * i] * s->mu[s->act[a]];
        if (out) out[i] = v;
        worst = fabs(v) > worst ? fabs(v) : worst;
    }
    return worst;
}

/* W's free rows and columns in LAPACK's lower band storage (LDAB × nf). */
static void fill_band(Solve *s, double *band) {
    const NewtonProblem *pr = s->pr;
    memset(band, 0, sizeof(double) * LDAB * (size_t)s->nf);
    for (int t = 0; t < pr->nnz_h; t++) {
        int r = s->free_at[pr->h_row[t]], c = s->free_at[pr->h_col[t]];
        if (r >= 0 && c >= 0) band[(r - c) + LDAB * c] = s->hess[t];
    }
}

static int band_cholesky(Solve *s, double *band) {
    char uplo = 'L';
    int n = s->nf, kd = KD, ldab = LDAB, info = 0;
    s->pr->dpbtrf(&uplo, &n, &kd, band, &ldab, &info);
    return info;
}

/* The KKT step (d on the free joints, μ_𝒜): the banded Cholesky of W with the Schur complement
 * of the active clearances when W is positive definite, else dense LU. 0 on success. */
static int kkt_step(Solve *s) {
    const NewtonProblem *pr = s->pr;
    int nf = s->nf, m = s->m;
    double *mu_new = s->r + m; /* m values after the m of r */
    fill_band(s, s->factor);
    if (band_cholesky(s, s->factor) == 0) {
        for (int a = 0; a < m; a++)
            for (int i = 0; i < nf; i++) s->rhs[i + (size_t)nf * a] = s->ja[a + (size_t)m * i];
        memcpy(s->rhs + (size_t)nf * m, s->g, sizeof(double) * nf);
        char uplo = 'L';
        int n = nf, kd = KD, ldab = LDAB, nrhs = m + 1, ldb = nf, info = 0;
        pr->dpbtrs(&uplo, &n, &kd, &nrhs, s->factor, &ldab, s->rhs, &ldb, &info);
        if (info) return 1;
        const double *y = s->rhs, *wg = s->rhs + (size_t)nf * m;
        /* schur[a, l] = ja_a · y_l, r[a] = ja_a · wg − c_a */
        for (int a = 0; a < m; a++) {
            double acc = 0.0;
            for (int i = 0; i < nf; i++) acc += s->ja[a + (size_t)m * i] * wg[i];
            s->r[a] = acc - s->c[s->act[a]];
            for (int l = 0; l < m; l++) {
                double v = 0.0;
                for (int i = 0; i < nf; i++) v += s->ja[a + (size_t)m * i] * y[i + (size_t)nf * l];
                s->schur[a + (size_t)m * l] = v;
            }
        }
        if (m == 1) {
            if (!(s->schur[0] > 0)) return 1;
            mu_new[0] = s->r[0] / s->schur[0];
        } else if (m == 2) {
            double a = s->schur[0], b = s->schur[2], c = s->schur[1], e = s->schur[3];
            double det = a * e - b * c;
            if (!(a > 0 && det > 0)) return 1;
            mu_new[0] = (e * s->r[0] - b * s->r[1]) / det;
            mu_new[1] = (a * s->r[1] - c * s->r[0]) / det;
        } else if (m > 2) {
            char up = 'U';
            int mm = m, one = 1, info2 = 0;
            memcpy(mu_new, s->r, sizeof(double) * m);
            pr->dposv(&up, &mm, &one, s->schur, &mm, mu_new, &mm, &info2);
            if (info2) return 1;
        }
        for (int i = 0; i < nf; i++) {
            double v = -wg[i];
            for (int l = 0; l < m; l++) v += y[i + (size_t)nf * l] * mu_new[l];
            s->d[i] = v;
        }
    } else {
        int nk = nf + m;
        memset(s->kkt, 0, sizeof(double) * (size_t)nk * nk);
        for (int t = 0; t < pr->nnz_h; t++) {
            int r = s->free_at[pr->h_row[t]], c = s->free_at[pr->h_col[t]];
            if (r >= 0 && c >= 0) {
                s->kkt[r + (size_t)nk * c] = s->hess[t];
                s->kkt[c + (size_t)nk * r] = s->hess[t];
            }
        }
        for (int a = 0; a < m; a++)
            for (int i = 0; i < nf; i++) {
                double v = s->ja[a + (size_t)m * i];
                s->kkt[i + (size_t)nk * (nf + a)] = -v;
                s->kkt[(nf + a) + (size_t)nk * i] = v;
            }
        for (int i = 0; i < nf; i++) s->kkt_rhs[i] = -s->g[i];
        for (int a = 0; a < m; a++) s->kkt_rhs[nf + a] = -s->c[s->act[a]];
        int n = nk, one = 1, info = 0;
        pr->dgesv(&n, &one, s->kkt, &n, s->ipiv, s->kkt_rhs, &n, &info);
        if (info) return 1;
        memcpy(s->d, s->kkt_rhs, sizeof(double) * nf);
        memcpy(mu_new, s->kkt_rhs + nf, sizeof(double) * m);
    }
    for (int i = 0; i < nf; i++)
        if (!isfinite(s->d[i])) return 1;
    for (int a = 0; a < m; a++)
        if (!isfinite(mu_new[a])) return 1;
    return 0;
}

/* The one active-set change a converged point still needs: the most negative multiplier
 * leaves, else the most violated inactive clearance joins; −1 if none. */
static int active_change(const Solve *s) {
    int worst = -1;
    for (int a = 0; a < s->m; a++)
        if (s->mu[s->act[a]] < 0 && (worst < 0 || s->mu[s->act[a]] < s->mu[worst])) worst = s->act[a];
    if (worst >= 0) return worst;
    int a = 0;
    for (int j = 0; j < s->pr->n_c; j++) {
        if (a < s->m && s->act[a] == j) {
            a++;
            continue;
        }
        if (s->c[j] < 0 && (worst < 0 || s->c[j] < s->c[worst])) worst = j;
    }
    return worst;
}

static void toggle(Solve *s, int j) {
    int a = 0;
    while (a < s->m && s->act[a] < j) a++;
    if (a < s->m && s->act[a] == j) {
        memmove(s->act + a, s->act + a + 1, sizeof(int) * (s->m - a - 1));
        s->m--;
    } else {
        memmove(s->act + a + 1, s->act + a, sizeof(int) * (s->m - a));
        s->act[a] = j;
        s->m++;
    }
}

/* The start: x0 with joints on a limit held there, the guessed active set, its multipliers
 * for the new θ (least squares) and the terms there; the stationarity residual it leaves in
 * *residual and, in s->tilt, the residual vector on the free joints. */
static int start(Solve *s, const double *x0, double *residual) {
    const NewtonProblem *pr = s->pr;
    int n = pr->n, nc = pr->n_c;
    memcpy(s->x, x0, sizeof(double) * n);
    s->nf = 0;
    for (int i = 0; i < n; i++) {
        s->on_lower[i] = s->x[i] - pr->lower[i] < pr->at_bound;
        int on_upper = pr->upper[i] - s->x[i] < pr->at_bound;
        s->held[i] = s->on_lower[i] || on_upper;
        if (s->on_lower[i]) s->x[i] = pr->lower[i];
        else if (on_upper) s->x[i] = pr->upper[i];
        s->free_at[i] = s->held[i] ? -1 : s->nf;
        if (!s->held[i]) s->free[s->nf++] = i;
    }
    memset(s->mu, 0, sizeof(double) * nc);
    s->tilt_scale = 0.0;
    if (eval_point(s)) return NEWTON_EVAL;
    s->m = 0;
    for (int j = 0; j < nc; j++)
        if (s->c[j] < pr->active) s->act[s->m++] = j;
    gather(s);
    int m = s->m, nf = s->nf;
    if (m == 1) {
        double rg = 0.0, rr = 0.0;
        for (int i = 0; i < nf; i++) rg += s->ja[i] * s->g[i], rr += s->ja[i] * s->ja[i];
        s->mu[s->act[0]] = rr > 0 ? rg / rr : 0.0;
    } else if (m > 1) { /* normal equations (a few rows); least squares by the caller if singular */
        for (int a = 0; a < m; a++) {
            double v = 0.0;
            for (int i = 0; i < nf; i++) v += s->ja[a + (size_t)m * i] * s->g[i];
            s->r[a] = v;
            for (int l = 0; l < m; l++) {
                double u = 0.0;
                for (int i = 0; i < nf; i++)
                    u += s->ja[a + (size_t)m * i] * s->ja[l + (size_t)m * i];
                s->schur[a + (size_t)m * l] = u;
            }
        }
        char up = 'U';
        int mm = m, one = 1, info = 0;
        pr->dposv(&up, &mm, &one, s->schur, &mm, s->r, &mm, &info);
        if (info) return NEWTON_LSTSQ;
        for (int a = 0; a < m; a++) s->mu[s->act[a]] = s->r[a];
    }
    *residual = stationarity(s, s->tilt);
    return add_clearance_curvature(s) ? NEWTON_EVAL : NEWTON_OK; /* W at the start */
}

/* Whether the KKT point is a strict local minimum (W's banded Cholesky, or the caller's
 * reduced Hessian), inside the joint limits with the held joints pressed onto theirs. */
static int certify(Solve *s, double *x_out, double *mu_out, int *active_out, double *phi_out) {
    const NewtonProblem *pr = s->pr;
    int n = pr->n, nc = pr->n_c;
    for (int i = 0; i < n; i++)
        if (s->x[i] < pr->lower[i] || s->x[i] > pr->upper[i]) return NEWTON_INFEASIBLE;
    double *bound = s->d; /* ∂L/∂x on every joint (held ones included) */
    for (int i = 0; i < n; i++) bound[i] = s->grad[i];
    for (int t = 0; t < pr->nnz_j; t++)
        if (s->row_at[pr->j_row[t]] >= 0) bound[pr->j_col[t]] -= s->jac[t] * s->mu[pr->j_row[t]];
    for (int i = 0; i < n; i++)
        if (s->held[i] && (s->on_lower[i] ? bound[i] : -bound[i]) < -pr->stationarity)
            return NEWTON_INFEASIBLE;
    memcpy(x_out, s->x, sizeof(double) * n);
    memcpy(mu_out, s->mu, sizeof(double) * nc);
    for (int j = 0; j < nc; j++) active_out[j] = 0;
    for (int a = 0; a < s->m; a++) active_out[s->act[a]] = 1;
    fill_band(s, s->band);
    if (band_cholesky(s, s->band)) return s->m ? NEWTON_REDUCED : NEWTON_INDEFINITE;
    const double *arg[MAX_PTR] = {s->x, s->p};
    double *res[MAX_PTR] = {phi_out};
    return newton_features(arg, res, s->iw, s->w, 0) ? NEWTON_EVAL : NEWTON_CERTIFIED;
}

/* Newton steps on the KKT system from the current state until the (tilted) stationarity and
 * the active clearances are within the tolerances with no active-set change left to make
 * (NEWTON_OK: converged), else why not. *steps counts the steps taken. */
static int newton_loop(Solve *s, double stationarity_tol, double feasibility_tol, int *steps) {
    const NewtonProblem *pr = s->pr;
    int since_change = 0;
    for (int step = 0; step <= pr->max_steps; step++) {
        gather(s);
        double residual = stationarity(s, NULL), infeasible = 0.0;
        for (int a = 0; a < s->m; a++)
            infeasible = fabs(s->c[s->act[a]]) > infeasible ? fabs(s->c[s->act[a]]) : infeasible;
        if (residual <= stationarity_tol && infeasible <= feasibility_tol) {
            int change = active_change(s);
            if (change < 0) return NEWTON_OK;
            toggle(s, change);
            s->mu[change] = 0.0;
            gather(s);
            since_change = 0;
        } else if (step == pr->max_steps || since_change == pr->steps_per_set ||
                   (step >= pr->slow_after &&
                    (residual > infeasible ? residual : infeasible) > pr->slow)) {
            return NEWTON_STALLED;
        }
        if (kkt_step(s)) return NEWTON_SINGULAR;
        for (int i = 0; i < s->nf; i++) s->x[s->free[i]] += s->d[i];
        double *mu_new = s->r + s->m;
        memset(s->mu, 0, sizeof(double) * pr->n_c);
        for (int a = 0; a < s->m; a++) s->mu[s->act[a]] = mu_new[a];
        since_change++;
        (*steps)++;
        if (eval_terms(s)) return NEWTON_EVAL;
    }
    return NEWTON_STALLED;
}

/* Start from x0 (n) with parameters p; on NEWTON_CERTIFIED x_out, mu_out (n_c), phi_out (k)
 * and the report are filled, on NEWTON_REDUCED x_out, mu_out and active_out (n_c flags).
 * The plain attempt first (the gate, then the loop); where it fails and the continuation is
 * on, the start walks to the new θ in stages: x0 is a KKT point of min f − r₀ᵀx (r₀ the
 * start's residual), and stage i of N solves min f − (1 − i/N) r₀ᵀx from stage i − 1's
 * answer, the last to the full tolerances. report->stages says how many it took (0: none). */
int newton_solve(const NewtonProblem *pr, const double *x0, const double *p, double *work,
                 casadi_int_t *iwork, double *x_out, double *mu_out, int *active_out,
                 double *phi_out, NewtonReport *report) {
    int n = pr->n, nc = pr->n_c, nk = n + nc;
    casadi_int_t iw_need, w_need;
    if (casadi_work(&iw_need, &w_need)) return NEWTON_EVAL;
    if (n % NJ || nc != 2 * (n / NJ) || pr->nnz_h != PER_WAYPOINT * (n / NJ) - NJ ||
        pr->nnz_j != 2 * n)
        return NEWTON_EVAL; /* not the layout newton.py builds */
    Solve s = {0};
    s.pr = pr;
    s.p = p;
    double *w = work;
    s.w = w, w += w_need;
    s.x = w, w += n;
    s.grad = w, w += n;
    s.g = w, w += n;
    s.d = w, w += n;
    s.tilt = w, w += n;
    s.c = w, w += nc;
    s.mu = w, w += nc;
    s.r = w, w += 2 * nc;
    s.jac = w, w += pr->nnz_j;
    s.hess = w, w += pr->nnz_h;
    s.band = w, w += LDAB * n;
    s.factor = w, w += LDAB * n;
    s.ja = w, w += (size_t)nc * n;
    s.rhs = w, w += (size_t)(nc + 1) * n;
    s.schur = w, w += (size_t)nc * nc;
    s.kkt = w, w += (size_t)nk * nk;
    s.kkt_rhs = w, w += nk;
    s.phi_i = w, w += pr->k;
    s.c_i = w, w += 2;
    s.jac_i = w, w += 2 * NJ;
    s.grad_i = w, w += NJ;
    s.hess_i = w, w += NJ * NJ;
    casadi_int_t *iw = iwork;
    s.iw = iw, iw += iw_need;
    int *ints = (int *)iw; /* the rest of the int workspace, as int */
    s.on_lower = ints, ints += n;
    s.held = ints, ints += n;
    s.free_at = ints, ints += n;
    s.free = ints, ints += n;
    s.act = ints, ints += nc;
    s.row_at = ints, ints += nc;
    s.ipiv = ints, ints += nk;

    report->steps = report->stages = 0;
    int code = start(&s, x0, &report->residual);
    if (code != NEWTON_OK) return code;
    double r0 = report->residual;
    if (r0 <= pr->gate) {
        code = newton_loop(&s, pr->stationarity, pr->feasibility, &report->steps);
        if (code == NEWTON_OK) {
            report->objective = s.f;
            return certify(&s, x_out, mu_out, active_out, phi_out);
        }
    } else {
        code = NEWTON_GATE;
    }
    int stages = (int)ceil(r0 / pr->stage_residual);
    if (pr->max_stages <= 0 || stages > pr->max_stages || code == NEWTON_EVAL) return code;
    if (stages < 2) stages = 2;
    int restarted = start(&s, x0, &r0);
    if (restarted != NEWTON_OK) return restarted;
    for (int i = 1; i <= stages; i++) {
        s.tilt_scale = 1.0 - (double)i / stages;
        int last = i == stages;
        report->stages = i;
        code = newton_loop(&s, last ? pr->stationarity : pr->stage_tolerance,
                           last ? pr->feasibility : pr->stage_tolerance, &report->steps);
        if (code != NEWTON_OK) return code;
    }
    report->objective = s.f;
    return certify(&s, x_out, mu_out, active_out, phi_out);
}
