/* The TCP's position for a chain of revolute joints, and the linear moves whose joint interpolation sags.
 *
 * chain_point: the walk of fabric/robot/chain_point.py (ChainPoint.__call__), row by row and in the same order of
 * operations: from the TCP back to the base, the point is turned about each joint's axis (x, y or z of its frame,
 * either way: a plane rotation) and placed by the joint's fixed placement in its parent, the products by 0 and 1
 * skipped as there. numpy's sin and cos are the C library's on the platforms we build for, so the positions are
 * numpy's to the bit.
 *
 * chain_straying: steps 1 and 2 of fabric/planning/refine.py over every row of a program in one pass: the
 * bound from the joint travel (sag_bound_mm), then, where it exceeds the threshold, the TCP half-way through
 * the joint interpolation against the middle of the straight line (_measured). numpy makes a pass over
 * memory for each operation and gathers the rows it measures; here a row is done in registers. The bound's
 * sum runs in another order than numpy's matrix product (a last-bit difference in a bound that only picks
 * the rows to measure); the half-way joints are computed as numpy computes them.
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is
 * released during the call).
 */
#define _GNU_SOURCE               /* sincos: glibc's, the same bits as its sin and cos */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

static void sin_cos(double x, double *s, double *c)
{
#ifdef __GLIBC__
    sincos(x, s, c);
#else
    *s = sin(x);
    *c = cos(x);
#endif
}

/* One joint's placement R v + t as fabric/robot/chain_point.py's _placed computes it: per output coordinate
 * the terms of R's entries that are not 0, in order, each v[k] itself (1), -v[k] (-1) or r v[k]; the
 * translation added only where it is not 0. Made once per call (the walk then has no tests of R). */
typedef struct {
    int n[3];             /* terms of each output coordinate */
    int k[3][3];          /* their v index */
    int kind[3][3];       /* 1: v[k], -1: -v[k], 0: r * v[k] */
    double r[3][3];
    double t[3];
} Placement;

enum { MAX_JOINTS = 16 };

typedef struct {
    int nq;
    int axis[MAX_JOINTS];      /* 0, 1, 2: about x, y, z of the joint's frame */
    int sign[MAX_JOINTS];      /* -1: about -x, -y, -z (by -q) */
    Placement place[MAX_JOINTS];
    double tcp[3];
} Walk;

/* The walk of a chain given as axis (2 x nq: axes, then signs), R (nq x 9), t (nq x 3), tcp (3); 0 where
 * the chain is longer than MAX_JOINTS. */
static int walk_of(int nq, const int *axis, const double *R, const double *t, const double *tcp, Walk *w)
{
    if (nq > MAX_JOINTS)
        return 0;
    w->nq = nq;
    for (int j = 0; j < nq; j++) {
        w->axis[j] = axis[j];
        w->sign[j] = axis[nq + j];
        Placement *pl = &w->place[j];
        for (int i = 0; i < 3; i++) {
            pl->n[i] = 0;
            pl->t[i] = t[3 * j + i];
            for (int k = 0; k < 3; k++) {
                double r = R[9 * j + 3 * i + k];
                if (fabs(r) < 1e-15)
                    continue;
                int m = pl->n[i]++;
                pl->k[i][m] = k;
                pl->kind[i][m] = r == 1.0 ? 1 : (r == -1.0 ? -1 : 0);
                pl->r[i][m] = r;
            }
        }
    }
    for (int i = 0; i < 3; i++)
        w->tcp[i] = tcp[i];
    return 1;
}

static double term(const Placement *pl, int i, int m, const double *v)
{
    double x = v[pl->k[i][m]];
    return pl->kind[i][m] == 1 ? x : (pl->kind[i][m] == -1 ? -x : pl->r[i][m] * x);
}

static void placed(const Placement *pl, double *v)
{
    double out[3];
    for (int i = 0; i < 3; i++) {
        double acc = 0.0;
        for (int m = 0; m < pl->n[i]; m++)
            acc = m ? acc + term(pl, i, m, v) : term(pl, i, m, v);
        out[i] = pl->t[i] != 0.0 ? acc + pl->t[i] : acc;
    }
    v[0] = out[0];
    v[1] = out[1];
    v[2] = out[2];
}

static void walk(const Walk *w, const double *q, double *v)
{
    v[0] = w->tcp[0];
    v[1] = w->tcp[1];
    v[2] = w->tcp[2];
    for (int k = w->nq - 1; k >= 0; k--) {
        double c, s;
        sin_cos(q[k], &s, &c);
        if (w->sign[k] < 0)
            s = -s;
        int a = (w->axis[k] + 1) % 3, b = (w->axis[k] + 2) % 3;
        double va = v[a], vb = v[b];
        v[a] = c * va - s * vb;
        v[b] = s * va + c * vb;
        placed(&w->place[k], v);
    }
}

/* ChainPoint.__call__: TCP positions out (n x 3) for joints q (n x nq, rows q_stride doubles apart); -1 for a
 * chain longer than MAX_JOINTS. */
int chain_point(long n, int nq, const int *axis, const double *R, const double *t, const double *tcp,
                const double *q, long q_stride, double *out)
{
    Walk w;
    if (!walk_of(nq, axis, R, t, tcp, &w))
        return -1;
    for (long i = 0; i < n; i++)
        walk(&w, q + i * q_stride, out + 3 * i);
    return 0;
}

/* refine._straying over every row (look is None) then refine._measured: writes the rows (ascending) whose TCP
 * half-way through the joint interpolation is more than `thresh_mm` from the middle of the straight line, and by
 * how much, and returns how many (-1: a chain longer than MAX_JOINTS). A row is looked at when it is a linear
 * move (op == movel) solved (status == ik_ok) after a solved row (row 0: after prev, given by prev_q / prev_xyz,
 * prev_ok; prev_q NULL where there is none) and the bound on its sag exceeds thresh_mm. xyz: the rows' TCP in the
 * plate frame, W: the plate frame in the base (4 x 4, row-major), reach: the bound's distances (nq). */
long chain_straying(long n, int nq, const int *axis, const double *R, const double *t, const double *tcp,
                    const double *q, const unsigned char *op, const unsigned char *status, const double *xyz,
                    const double *W, const double *reach, double thresh_mm, const double *prev_q,
                    const double *prev_xyz, int prev_ok, int movel, int ik_ok, int64_t *rows_out, double *sag_out)
{
    Walk w;
    double dq[MAX_JOINTS], mid_q[MAX_JOINTS], p[3];
    long found = 0;
    if (!walk_of(nq, axis, R, t, tcp, &w))
        return -1;
    for (long i = 0; i < n; i++) {
        const double *q1 = q + i * nq;
        const double *q_before = i ? q1 - nq : (prev_q ? prev_q : q1);
        int before_ok = i ? status[i - 1] == ik_ok : (prev_q != NULL && prev_ok);
        if (op[i] != movel || status[i] != ik_ok || !before_ok)
            continue;
        double cum = 0.0, bound = 0.0;
        for (int k = 0; k < nq; k++) {
            dq[k] = q1[k] - q_before[k];
            double d = fabs(dq[k]);
            cum += d;
            bound += d * (d + 2.0 * (cum - d)) * reach[k];
        }
        if (!(bound / 8.0 > thresh_mm))
            continue;
        for (int k = 0; k < nq; k++)
            mid_q[k] = 0.5 * ((q1[k] - dq[k]) + q1[k]);
        walk(&w, mid_q, p);
        const double *a = i ? xyz + 3 * (i - 1) : prev_xyz, *b = xyz + 3 * i;
        double m[3] = {0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])};
        double sq = 0.0;
        for (int r = 0; r < 3; r++) {
            double mr = W[4 * r] * m[0] + W[4 * r + 1] * m[1] + W[4 * r + 2] * m[2] + W[4 * r + 3];
            sq += (p[r] - mr) * (p[r] - mr);
        }
        double sag = sqrt(sq);
        if (sag > thresh_mm) {
            rows_out[found] = i;
            sag_out[found] = sag;
            found++;
        }
    }
    return found;
}
