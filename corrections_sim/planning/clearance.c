/* A lower bound on every geom distance MuJoCo's collision check can report along a trajectory.
 *
 * Built and documented by corrections_sim/planning/clearance.py, which lays out the two tables
 * this file reads (`mi`, integers, and `md`, doubles) and compiles it into the planner's cache.
 * Every number returned is a lower bound on a true distance (metres); pruning only skips work
 * whose answer is already known to be above the threshold.
 *
 * Layout of mi: header [n_frames, n_capsules, n_statics, n_frame_static, n_frame_frame],
 *   then per static its kind (0 box, 1 plane), per capsule its frame,
 *   per frame-static pair (frame, static, first, count) into the capsule list,
 *   per frame-frame pair (frame1, frame2, first, count) into the capsule-pair list,
 *   the capsule list (the capsules of the pair's frame MuJoCo tests against the static),
 *   the capsule-pair list (two capsule indices each).
 * Layout of md: the base frame (R row-major 9, p 3); per frame its offset from the previous
 *   frame (p 3, R 9, then the joint turns about z); per frame its covering sphere (centre 3,
 *   radius 1, in the frame); per capsule (a 3, b 3, radius 1, in its frame); reach, n_frames
 *   x n_frames row-major: reach[f][j] (j <= f) bounds the distance from joint j's axis to any
 *   point of frame f's sphere.
 * statics: per static 15 doubles: centre 3, three unit axes 9 (rows), half-sizes 3; a plane
 *   (normal +z) keeps its height in the centre's z.
 */
#include <math.h>
#include <string.h>

#define HEADER 5
#define MAX_FRAMES 16
#define MAX_CAPSULES 64
#define MAX_PAIRS 512

typedef struct {
    double R[9], p[3];
} Pose;

static void compose(const Pose *parent, const double *offset, double angle, Pose *out)
{
    const double *op = offset, *oR = offset + 3;
    double c = cos(angle), s = sin(angle), M[9];
    int i, j, k;
    for (i = 0; i < 3; ++i) {
        out->p[i] = parent->p[i];
        for (k = 0; k < 3; ++k) out->p[i] += parent->R[3 * i + k] * op[k];
    }
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 3; ++j) {
            M[3 * i + j] = 0.0;
            for (k = 0; k < 3; ++k) M[3 * i + j] += parent->R[3 * i + k] * oR[3 * k + j];
        }
    /* M @ Rz(angle) */
    for (i = 0; i < 3; ++i) {
        out->R[3 * i + 0] = M[3 * i + 0] * c + M[3 * i + 1] * s;
        out->R[3 * i + 1] = -M[3 * i + 0] * s + M[3 * i + 1] * c;
        out->R[3 * i + 2] = M[3 * i + 2];
    }
}

static void to_world(const Pose *f, const double *v, double *out)
{
    int i;
    for (i = 0; i < 3; ++i)
        out[i] = f->p[i] + f->R[3 * i] * v[0] + f->R[3 * i + 1] * v[1] + f->R[3 * i + 2] * v[2];
}

static double dist3(const double *a, const double *b)
{
    double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    return sqrt(dx * dx + dy * dy + dz * dz);
}

/* Distance from the segment a-b to a static, minus nothing: a lower bound.
 * Box: along each box axis the projections of the segment and the box are separated by at
 * least the gap between their intervals, and the distance is at least the norm of the gaps. */
static double segment_static(const double *a, const double *b, int kind, const double *st)
{
    int k;
    double sum = 0.0;
    if (kind == 1) return fmin(a[2], b[2]) - st[2];
    for (k = 0; k < 3; ++k) {
        const double *axis = st + 3 + 3 * k;
        double h = st[12 + k];
        double pa = axis[0] * (a[0] - st[0]) + axis[1] * (a[1] - st[1]) + axis[2] * (a[2] - st[2]);
        double pb = axis[0] * (b[0] - st[0]) + axis[1] * (b[1] - st[1]) + axis[2] * (b[2] - st[2]);
        double gap = fmax(fmax(fmin(pa, pb) - h, -h - fmax(pa, pb)), 0.0);
        sum += gap * gap;
    }
    return sqrt(sum);
}

typedef struct {
    const int *kind, *cap_frame, *fs, *ff, *caps, *cap_pairs;
    int n_frames, n_caps, n_statics, n_fs, n_ff;
    const double *base, *offsets, *spheres, *capsules, *reach;
} Tables;

static int tables(const int *mi, const double *md, Tables *t)
{
    t->n_frames = mi[0];
    t->n_caps = mi[1];
    t->n_statics = mi[2];
    t->n_fs = mi[3];
    t->n_ff = mi[4];
    if (t->n_frames > MAX_FRAMES || t->n_caps > MAX_CAPSULES) return 1;
    t->kind = mi + HEADER;
    t->cap_frame = t->kind + t->n_statics;
    t->fs = t->cap_frame + t->n_caps;
    t->ff = t->fs + 4 * t->n_fs;
    t->caps = t->ff + 4 * t->n_ff;
    {
        int i, total = 0;
        for (i = 0; i < t->n_fs; ++i) total += t->fs[4 * i + 3];
        t->cap_pairs = t->caps + total; /* after the capsule list */
    }
    t->base = md;
    t->offsets = md + 12;
    t->spheres = t->offsets + 12 * t->n_frames;
    t->capsules = t->spheres + 4 * t->n_frames;
    t->reach = t->capsules + 7 * t->n_caps;
    return 0;
}

/* The least bound of one pair of capsules: each covered by two spheres of radius r + L/4. */
static double capsule_capsule(const Tables *t, const double *ends, int i, int j)
{
    double ci[2][3], cj[2][3], ri, rj, best = INFINITY;
    int s, u, k;
    ri = t->capsules[7 * i + 6] + 0.25 * dist3(ends + 6 * i, ends + 6 * i + 3);
    rj = t->capsules[7 * j + 6] + 0.25 * dist3(ends + 6 * j, ends + 6 * j + 3);
    for (s = 0; s < 2; ++s)
        for (k = 0; k < 3; ++k) {
            double w = 0.25 + 0.5 * s;
            ci[s][k] = ends[6 * i + k] + w * (ends[6 * i + 3 + k] - ends[6 * i + k]);
            cj[s][k] = ends[6 * j + k] + w * (ends[6 * j + 3 + k] - ends[6 * j + k]);
        }
    for (s = 0; s < 2; ++s)
        for (u = 0; u < 2; ++u) best = fmin(best, dist3(ci[s], cj[u]) - ri - rj);
    return best;
}

static double capsule_static(const Tables *t, const double *ends, int c, const double *statics,
                             int s)
{
    return segment_static(ends + 6 * c, ends + 6 * c + 3, t->kind[s], statics + 15 * s) -
           t->capsules[7 * c + 6];
}

static double sphere_static(const Tables *t, const double *centres, int f, const double *statics,
                            int s)
{
    const double *c = centres + 3 * f;
    return segment_static(c, c, t->kind[s], statics + 15 * s) - t->spheres[4 * f + 3];
}

/* Frames and sphere centres at q; capsule ends are placed when first needed (`placed`). */
static void place_frames(const Tables *t, const double *q, Pose *frames, double *centres)
{
    int f;
    Pose base;
    for (f = 0; f < 9; ++f) base.R[f] = t->base[f];
    for (f = 0; f < 3; ++f) base.p[f] = t->base[9 + f];
    for (f = 0; f < t->n_frames; ++f) {
        compose(f == 0 ? &base : &frames[f - 1], t->offsets + 12 * f, q[f], &frames[f]);
        to_world(&frames[f], t->spheres + 4 * f, centres + 3 * f);
    }
}

static const double *capsule_ends(const Tables *t, const Pose *frames, double *ends, char *placed,
                                  int c)
{
    if (!placed[c]) {
        const double *cap = t->capsules + 7 * c;
        to_world(&frames[t->cap_frame[c]], cap, ends + 6 * c);
        to_world(&frames[t->cap_frame[c]], cap + 3, ends + 6 * c + 3);
        placed[c] = 1;
    }
    return ends;
}

typedef struct {
    Pose frames[MAX_FRAMES];
    double centres[3 * MAX_FRAMES], ends[6 * MAX_CAPSULES];
    char placed[MAX_CAPSULES];
    double *slack_fs, *slack_ff;
} Scratch;

/* One sample: every pair whose slack (a lower bound carried from an earlier sample, less how
 * far its frames can have moved since) is at most `refine` is bounded anew. Returns the least
 * bound, or the first capsule bound at or below `stop` with *stopped set. */
static double sample(const Tables *t, const double *q, const double *moved, const double *statics,
                     double refine, double stop, Scratch *w, int *stopped)
{
    int i, k, have_frames = 0;
    double least = INFINITY;
    for (i = 0; i < t->n_fs; ++i) {
        const int *pr = t->fs + 4 * i;
        double b = w->slack_fs[i] - moved[pr[0]];
        if (b <= refine) {
            if (!have_frames) {
                place_frames(t, q, w->frames, w->centres);
                memset(w->placed, 0, (size_t)t->n_caps);
                have_frames = 1;
            }
            b = sphere_static(t, w->centres, pr[0], statics, pr[1]);
            if (b <= refine) {
                double spheres = b;
                b = INFINITY;
                for (k = 0; k < pr[3]; ++k) {
                    int c = t->caps[pr[2] + k];
                    double fine = capsule_static(
                        t, capsule_ends(t, w->frames, w->ends, w->placed, c), c, statics, pr[1]);
                    if (fine <= stop) {
                        *stopped = 1;
                        return fine;
                    }
                    b = fmin(b, fine);
                }
                b = fmax(b, spheres); /* both bound the pair's distance */
            }
        }
        w->slack_fs[i] = b;
        least = fmin(least, b);
    }
    for (i = 0; i < t->n_ff; ++i) {
        const int *pr = t->ff + 4 * i;
        double b = w->slack_ff[i] - moved[pr[0]] - moved[pr[1]];
        if (b <= refine) {
            if (!have_frames) {
                place_frames(t, q, w->frames, w->centres);
                memset(w->placed, 0, (size_t)t->n_caps);
                have_frames = 1;
            }
            b = dist3(w->centres + 3 * pr[0], w->centres + 3 * pr[1]) - t->spheres[4 * pr[0] + 3] -
                t->spheres[4 * pr[1] + 3];
            if (b <= refine) {
                double spheres = b;
                b = INFINITY;
                for (k = 0; k < pr[3]; ++k) {
                    const int *cp = t->cap_pairs + 2 * (pr[2] + k);
                    double fine;
                    capsule_ends(t, w->frames, w->ends, w->placed, cp[0]);
                    capsule_ends(t, w->frames, w->ends, w->placed, cp[1]);
                    fine = capsule_capsule(t, w->ends, cp[0], cp[1]);
                    if (fine <= stop) {
                        *stopped = 1;
                        return fine;
                    }
                    b = fmin(b, fine);
                }
                b = fmax(b, spheres);
            }
        }
        w->slack_ff[i] = b;
        least = fmin(least, b);
    }
    return least;
}

/* The least lower bound over every pair at every sample of a trajectory, the samples being
 * those of check_trajectory: per segment of the waypoints (n_waypoints x nq) `substeps`
 * samples a + (i / substeps)(b - a), then the last waypoint.
 *
 * A pair whose frames' spheres come within `refine` is bounded capsule by capsule, and the
 * first capsule bound at or below `stop` is returned at once (the trajectory cannot be
 * certified). Between samples a frame moves at most sum_j reach[f][j] |dq_j| (a point at
 * distance r from joint j's axis moves at most r |dq_j| when it turns), so a pair whose last
 * bound, less that much per sample since, still exceeds `refine` is not bounded again.
 * Bad sizes or tables: NAN. */
double clearance_bound(const int *mi, const double *md, const double *statics,
                       const double *waypoints, int n_waypoints, int nq, int substeps,
                       double refine, double stop)
{
    Tables t;
    Scratch w;
    double slack_fs[MAX_PAIRS], slack_ff[MAX_PAIRS], moved[MAX_FRAMES], q[MAX_FRAMES] = {0};
    double step[MAX_FRAMES];
    double least = INFINITY;
    int seg, i, j, f, stopped = 0;
    if (tables(mi, md, &t) != 0 || n_waypoints < 1 || substeps < 1 || nq < t.n_frames ||
        t.n_fs > MAX_PAIRS || t.n_ff > MAX_PAIRS)
        return NAN;
    for (i = 0; i < t.n_fs; ++i) slack_fs[i] = -INFINITY;
    for (i = 0; i < t.n_ff; ++i) slack_ff[i] = -INFINITY;
    w.slack_fs = slack_fs;
    w.slack_ff = slack_ff;
    for (seg = 0; seg < n_waypoints; ++seg) {
        const double *a = waypoints + (long)seg * nq, *b = a + nq;
        int n = seg == n_waypoints - 1 ? 1 : substeps;
        for (i = 0; i < n; ++i) {
            double s = (double)i / substeps, v;
            for (j = 0; j < t.n_frames; ++j) {
                double now = i ? a[j] + s * (b[j] - a[j]) : a[j];
                step[j] = fabs(now - q[j]);
                q[j] = now;
            }
            for (f = 0; f < t.n_frames; ++f) { /* how far frame f can have moved */
                moved[f] = 0.0;
                for (j = 0; j <= f; ++j) moved[f] += t.reach[t.n_frames * f + j] * step[j];
                moved[f] = moved[f] * (1.0 + 1e-9) + 1e-12;
            }
            v = sample(&t, q, moved, statics, refine, stop, &w, &stopped);
            if (stopped) return v;
            least = fmin(least, v);
        }
    }
    return least;
}

/* For tests: at one configuration q, every frame's pose (12 each: R 9, p 3), and for every
 * capsule-static entry and every capsule-pair entry its bound (the capsule list's order, then
 * the capsule-pair list's), each with the bound of its frames' spheres. Returns 0, or 1 when
 * the tables are too large. */
int clearance_details(const int *mi, const double *md, const double *statics, const double *q,
                      double *poses, double *fine, double *coarse)
{
    Tables t;
    Pose frames[MAX_FRAMES];
    double ends[6 * MAX_CAPSULES], centres[3 * MAX_FRAMES];
    char placed[MAX_CAPSULES];
    int i, k, m = 0;
    if (tables(mi, md, &t) != 0) return 1;
    place_frames(&t, q, frames, centres);
    memset(placed, 0, sizeof placed);
    for (i = 0; i < t.n_caps; ++i) capsule_ends(&t, frames, ends, placed, i);
    for (i = 0; i < t.n_frames; ++i) {
        for (k = 0; k < 9; ++k) poses[12 * i + k] = frames[i].R[k];
        for (k = 0; k < 3; ++k) poses[12 * i + 9 + k] = frames[i].p[k];
    }
    for (i = 0; i < t.n_fs; ++i) {
        const int *pr = t.fs + 4 * i;
        double b = sphere_static(&t, centres, pr[0], statics, pr[1]);
        for (k = 0; k < pr[3]; ++k, ++m) {
            fine[m] = capsule_static(&t, ends, t.caps[pr[2] + k], statics, pr[1]);
            coarse[m] = b;
        }
    }
    for (i = 0; i < t.n_ff; ++i) {
        const int *pr = t.ff + 4 * i;
        double b = dist3(centres + 3 * pr[0], centres + 3 * pr[1]) - t.spheres[4 * pr[0] + 3] -
                   t.spheres[4 * pr[1] + 3];
        for (k = 0; k < pr[3]; ++k, ++m) {
            const int *cp = t.cap_pairs + 2 * (pr[2] + k);
            fine[m] = capsule_capsule(&t, ends, cp[0], cp[1]);
            coarse[m] = b;
        }
    }
    return 0;
}
