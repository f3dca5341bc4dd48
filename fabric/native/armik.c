/* The closed-form IK of 6-axis OPW and UR arms along a path, with the branch choice: the loop of
 * ClosedFormIK._track (fabric/robot/closed_form.py) row by row, without numpy's passes over memory.
 *
 * The formulas are those of fabric/robot/opw.py (OPWArm._terms, _solve, _wrist_variant) and
 * fabric/robot/ur.py (URArm._shoulder, _wrist, _plane, _elbow), term for term, so both paths give the same
 * joints (to the last bits of libm's and numpy's trigonometric functions). The branch choice is the same
 * state machine as _track: *tracking* keeps the current branch while it stays valid and quiet (its step is
 * under half the distance to any other branch), in blocks whose sizes grow and reset as there; at the first
 * row that fails, the *full* method solves all 8 branches over a window of rows, each row taking the allowed
 * branch nearest the row before it (select_branches), the window growing while it ends on an invalid row.
 * The sizes of blocks and windows only decide which method answers a row; they are kept as there so that a
 * row with no allowed branch at all (where the two methods differ) is answered as there too.
 *
 * A row whose A1 is undefined (the wrist centre on axis 1: held from the row before, a rare exact case) is
 * not solved here: armik_track answers ARMIK_HOLD before writing anything and the caller takes numpy's path.
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is
 * released during the call).
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#define ARMIK_HOLD (-1)
#define ARMIK_BAD_FAMILY (-2)

enum { FAMILY_OPW = 0, FAMILY_UR = 1 };

/* par: the family's lengths, then 6 offsets, 6 signs, 6 lower and 6 upper limits, 6 multi-turn flags (0/1),
 * then the tolerances: wrist |sin|, elbow |cos|, shoulder mm, joint-limit rad. */
enum { P_OFF = 10, P_SIGN = 16, P_LOWER = 22, P_UPPER = 28, P_MULTI = 34, P_WRIST = 40, P_ELBOW = 41,
       P_SHOULDER = 42, P_LIMIT = 43, P_COUNT = 44 };

typedef struct {
    int family;
    const double *p;
} Arm;

static const double PI = 3.14159265358979323846;
static const double TWO_PI = 6.28318530717958647692;

static double wrap(double a) { return a - TWO_PI * nearbyint(a / TWO_PI); }

static double flip(double a) { return a >= 0.0 ? a - PI : a + PI; }

/* joint angle of model angle theta (OPWArm._q / URArm._q) */
static double to_q(const Arm *arm, double theta, int j)
{
    double s = arm->p[P_SIGN + j], o = arm->p[P_OFF + j];
    if (o != 0.0)
        return wrap(s > 0.0 ? theta - o : o - theta);
    return s > 0.0 ? theta : -theta;
}

/* One row's solution of one branch: q (model -> joint angles, [-pi, pi]), reach, singular, gap. */
typedef struct {
    double q[6];
    int reach;
    int sing;
    double gap;
} Branch;

/* OPWArm._terms + _solve + _wrist_variant for one row (c: the nine model columns). */
static void opw_branch(const Arm *arm, const double *c, int branch, Branch *out)
{
    const double *p = arm->p;
    double a1 = p[0], b = p[2], cc1 = p[3], c2 = p[4], c4 = p[6], k = p[7], phi = p[8];
    int shoulder = branch / 4, elbow = (branch / 2) % 2, wrist = branch % 2;
    double cx = c[0] - c4 * c[3], cy = c[1] - c4 * c[4], cz = c[2] - c4 * c[5];
    double rho2 = cx * cx + cy * cy;
    double t = sqrt(fmax(rho2 - b * b, 0.0));
    int ok_s = rho2 >= b * b;
    double zx = c[3], zy = c[4], zz = c[5], yx = c[6], yy = c[7], yz = c[8];
    double inv = 1.0 / (rho2 > 0.0 ? rho2 : 1.0);
    double ts = shoulder ? -t : t;
    double c1 = (cx * ts + cy * b) * inv;
    double s1 = (cy * ts - cx * b) * inv;
    double th1 = atan2(s1, c1);
    double u = ts - a1;
    double v = cz - cc1;
    double D = (u * u + v * v - c2 * c2 - k * k) / (2.0 * c2 * k);
    int ok = ok_s && fabs(D) <= 1.0 + 1e-12;
    double Dc = D < -1.0 ? -1.0 : (D > 1.0 ? 1.0 : D);
    double sabs = sqrt(fmax(0.0, 1.0 - Dc * Dc));
    double spsi = elbow ? -sabs : sabs;
    double A = c2 + k * Dc, Bk = k * spsi;
    double th2 = atan2(u * A - v * Bk, v * A + u * Bk);
    double th3 = atan2(spsi, Dc);
    if (phi != 0.0)
        th3 = wrap(th3 - phi);
    double th23 = th2 + th3;
    double c23 = cos(th23), s23 = sin(th23);
    double zx1 = c1 * zx + s1 * zy, zy1 = c1 * zy - s1 * zx;
    double yx1 = c1 * yx + s1 * yy, yy1 = c1 * yy - s1 * yx;
    double R02 = c23 * zx1 - s23 * zz, R12 = zy1, R22 = s23 * zx1 + c23 * zz;
    double R01 = c23 * yx1 - s23 * yz, R11 = yy1, R21 = s23 * yx1 + c23 * yz;
    double h = sqrt(R02 * R02 + R12 * R12);
    double th4 = atan2(R12, R02);
    double th5 = atan2(h, R22);
    double th6 = atan2(h * h * R21 - R22 * (R02 * R01 + R12 * R11), R02 * R11 - R12 * R01);
    if (h < 1e-3) {     /* opw._zyz_theta6 */
        double cw4 = cos(th4), sw4 = sin(th4), cw5 = cos(th5), sw5 = sin(th5);
        th6 = atan2(sw5 * R21 - cw5 * (cw4 * R01 + sw4 * R11), cw4 * R11 - sw4 * R01);
    }
    out->sing = h < p[P_WRIST] || sabs < p[P_ELBOW] || t < p[P_SHOULDER];
    double gap = 2.0 * atan2(sabs, fabs(Dc));
    if (b != 0.0) {
        double gs = 2.0 * atan2(t, fabs(b));
        gap = gs < gap ? gs : gap;
    }
    out->gap = gap;
    out->reach = ok;
    if (wrist) {
        th4 = flip(th4);
        th5 = -th5;
        th6 = flip(th6);
    }
    double th[6] = {th1, th2, th3, th4, th5, th6};
    for (int j = 0; j < 6; j++)
        out->q[j] = to_q(arm, th[j], j);
}

/* URArm._branches for one row and one branch (c: the nine DH frame-6 columns). */
static void ur_branch(const Arm *arm, const double *c, int branch, Branch *out)
{
    const double *p = arm->p;
    double d1 = p[0], a2 = p[1], a3 = p[2], d4 = p[3], d5 = p[4], d6 = p[5];
    int sh = branch / 4, e = (branch / 2) % 2, w = branch % 2;
    double px = c[0], py = c[1], pz = c[2], zx = c[3], zy = c[4], zz = c[5], yx = c[6], yy = c[7], yz = c[8];
    double xx = yy * zz - yz * zy, xy = yz * zx - yx * zz, xz = yx * zy - yy * zx;
    /* _shoulder */
    double p5x = px - d6 * zx, p5y = py - d6 * zy;
    double r2 = p5x * p5x + p5y * p5y;
    double t = sqrt(fmax(r2 - d4 * d4, 0.0));
    int ok_s = r2 >= d4 * d4;
    double ts = sh ? -t : t;
    double inv = 1.0 / (r2 > 0.0 ? r2 : 1.0);
    double c1 = (ts * p5x - d4 * p5y) * inv;
    double s1 = (ts * p5y + d4 * p5x) * inv;
    double th1 = atan2(s1, c1);
    double sh_gap = 2.0 * atan2(t, fabs(d4));
    /* _wrist */
    double c5 = s1 * zx - c1 * zy;
    double zx6 = s1 * xx - c1 * xy;
    double zy6 = s1 * yx - c1 * yy;
    double h = hypot(zx6, zy6);
    double hinv = 1.0 / (h > 0.0 ? h : 1.0);
    double sgn = w ? -1.0 : 1.0;
    double c6 = h > 0.0 ? sgn * zx6 * hinv : 1.0;
    double s6 = -sgn * zy6 * hinv;
    double s5 = sgn * h;
    /* _plane */
    double a = c5 * c6, bb = -c5 * s6, cc = -s5;
    double x4x = a * xx + bb * yx + cc * zx, x4y = a * xy + bb * yy + cc * zy, x4z = a * xz + bb * yz + cc * zz;
    double th234 = atan2(x4z, c1 * x4x + s1 * x4y);
    double ox = px - d6 * zx + d5 * (s6 * xx + c6 * yx);
    double oy = py - d6 * zy + d5 * (s6 * xy + c6 * yy);
    double oz = pz - d6 * zz + d5 * (s6 * xz + c6 * yz);
    double X = c1 * ox + s1 * oy, Y = oz - d1;
    double c3 = (X * X + Y * Y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3);
    int ok_p = fabs(c3) <= 1.0 + 1e-12;
    c3 = c3 < -1.0 ? -1.0 : (c3 > 1.0 ? 1.0 : c3);
    double sabs = sqrt(1.0 - c3 * c3);
    out->reach = ok_s && ok_p;
    out->sing = h < p[P_WRIST] || sabs < p[P_ELBOW] || t < p[P_SHOULDER];
    double ge = 2.0 * atan2(sabs, fabs(c3));
    out->gap = ge < sh_gap ? ge : sh_gap;
    /* _elbow */
    double s3 = e ? -sabs : sabs;
    double A = a2 + a3 * c3, Bk = a3 * s3;
    double th2 = atan2(Y * A - X * Bk, X * A + Y * Bk);
    double th3 = atan2(s3, c3);
    double th4 = wrap(th234 - th2 - th3);
    out->q[0] = to_q(arm, th1, 0);
    out->q[1] = to_q(arm, th2, 1);
    out->q[2] = to_q(arm, th3, 2);
    out->q[3] = to_q(arm, th4, 3);
    out->q[4] = to_q(arm, atan2(s5, c5), 4);
    out->q[5] = to_q(arm, atan2(s6, c6), 5);
}

/* A1 undefined (ClosedFormArm.q1_free's degenerate rows): OPW with b = 0, or UR, with the wrist centre
 * (axis-5 point) on axis 1. */
static int a1_undefined(const Arm *arm, const double *c)
{
    const double *p = arm->p;
    if (arm->family == FAMILY_OPW) {
        if (p[2] != 0.0)
            return 0;
        double cx = c[0] - p[6] * c[3], cy = c[1] - p[6] * c[4];
        return cx * cx + cy * cy < 1e-12;
    }
    double p5x = c[0] - p[5] * c[3], p5y = c[1] - p[5] * c[4];
    return p5x * p5x + p5y * p5y < 1e-12;
}

/* ClosedFormIK.branches_cols for one branch: solve, then single-turn joints into [lower, lower + 2 pi)
 * (ClosedFormIK._canon_col); returns whether the branch is valid (reachable and within the limits). */
static int solve_branch(const Arm *arm, const double *c, int branch, Branch *out)
{
    if (arm->family == FAMILY_OPW)
        opw_branch(arm, c, branch, out);
    else
        ur_branch(arm, c, branch, out);
    const double *p = arm->p;
    int inlim = 1;
    for (int j = 0; j < 6; j++) {
        if (p[P_MULTI + j] != 0.0)
            continue;
        double lo = p[P_LOWER + j], v = out->q[j];
        if (lo > -PI) {
            if (v < lo)
                v += TWO_PI;
        } else if (lo + TWO_PI <= PI) {
            if (v >= lo + TWO_PI)
                v -= TWO_PI;
        }
        out->q[j] = v;
        inlim &= v <= p[P_UPPER + j] + p[P_LIMIT];
    }
    return out->reach && inlim;
}

/* squared joint distance, every angle compared modulo 2 pi (closed_form._sq_dist) */
static double sq_dist(const double *a, const double *b)
{
    double s = 0.0;
    for (int j = 0; j < 6; j++) {
        double d = wrap(a[j] - b[j]);
        s += d * d;
    }
    return s;
}

static void gather(const double *C, long n, long i, double *c)
{
    for (int k = 0; k < 9; k++)
        c[k] = C[k * n + i];
}

static void put(double *q, long n, long i, const double *v)
{
    for (int j = 0; j < 6; j++)
        q[j * n + i] = v[j];
}

/* The full method over rows [i, j): all 8 branches, the allowed one nearest the row before (the first row:
 * nearest `prev`), select_branches' rules for a row with none allowed. Leaves the last row's chosen branch in
 * *b_last and whether it is valid in *ok_last. */
static void full_window(const Arm *arm, const double *C, long n, long i, long j, const double *prev,
                        double *q, uint8_t *row_ok, uint8_t *reach_any, uint8_t *sing, int *b_last, int *ok_last)
{
    Branch br[8], ref;
    int valid[8];
    int chosen = 0;
    double c[9];
    memcpy(ref.q, prev, sizeof ref.q);
    for (long r = i; r < j; r++) {
        gather(C, n, r, c);
        int any_ok = 0, any_reach = 0;
        for (int k = 0; k < 8; k++) {
            valid[k] = solve_branch(arm, c, k, &br[k]);
            any_ok |= valid[k];
            any_reach |= br[k].reach;
        }
        int best = -1;
        double best_d = INFINITY;
        for (int k = 0; k < 8; k++) {
            int allowed = any_ok ? valid[k] : br[k].reach;
            if (!allowed)
                continue;
            double d = sq_dist(br[k].q, ref.q);
            if (d < best_d || best < 0) {
                best_d = d;
                best = k;
            }
        }
        if (best < 0)          /* none allowed: the window's first row takes branch 0, a later row keeps its own */
            best = r == i ? 0 : chosen;
        chosen = best;
        put(q, n, r, br[chosen].q);
        row_ok[r] = (uint8_t)valid[chosen];
        sing[r] = (uint8_t)br[chosen].sing;
        reach_any[r] = (uint8_t)any_reach;
        ref = br[chosen];
        *ok_last = valid[chosen];
    }
    *b_last = chosen;
}

/* ClosedFormIK._track over n rows of model columns C (9 rows of n: position, z axis, y axis), from the
 * joints `seed`: fills q (6 rows of n), row_ok, reach_any and sing (0/1 per row). Returns n, ARMIK_HOLD when
 * some row's A1 is undefined (nothing written), or ARMIK_BAD_FAMILY. */
long armik_track(int family, const double *par, long n, const double *C, const double *seed, long max_rows,
                 double *q, uint8_t *row_ok, uint8_t *reach_any, uint8_t *sing)
{
    Arm arm = {family, par};
    double c[9], prev[6];
    if (family != FAMILY_OPW && family != FAMILY_UR)
        return ARMIK_BAD_FAMILY;
    for (long r = 0; r < n; r++) {
        gather(C, n, r, c);
        if (a1_undefined(&arm, c))
            return ARMIK_HOLD;
    }
    memcpy(prev, seed, sizeof prev);
    long i = 0, window = 32, block = 2048;
    int b = -1;
    while (i < n) {
        if (b < 0) {
            long j = i + window < n ? i + window : n;
            int ok_last = 0;
            full_window(&arm, C, n, i, j, prev, q, row_ok, reach_any, sing, &b, &ok_last);
            if (!ok_last)
                b = -1;
            if (b < 0)
                window = window * 2 < max_rows ? window * 2 : max_rows;
            for (int k = 0; k < 6; k++)
                prev[k] = q[k * n + j - 1];
            i = j;
            continue;
        }
        long j = i + block < n ? i + block : n;
        long r = i;
        Branch br;
        for (; r < j; r++) {
            gather(C, n, r, c);
            if (!solve_branch(&arm, c, b, &br))
                break;
            double sep = br.gap < PI ? br.gap : PI;
            double d2 = 0.0, dw2 = 0.0;
            for (int k = 0; k < 6; k++) {
                double d = br.q[k] - prev[k];
                double dw = wrap(d);
                d2 += d * d;
                dw2 += dw * dw;
            }
            if (!(4.0 * d2 < sep * sep) && !(4.0 * dw2 < sep * sep))
                break;
            put(q, n, r, br.q);
            row_ok[r] = 1;
            reach_any[r] = 1;
            sing[r] = (uint8_t)br.sing;
            memcpy(prev, br.q, sizeof prev);
        }
        long f = r - i;
        i = r;
        if (i < j) {           /* switch to the full method at row i */
            b = -1;
            window = f >= 256 ? 32 : (window * 4 < max_rows ? window * 4 : max_rows);
            block = 2048;
        } else {
            block = block * 2 < max_rows ? block * 2 : max_rows;
        }
    }
    return n;
}

/* The size of par armik_track reads (a check for the caller). */
long armik_par_count(void) { return P_COUNT; }
