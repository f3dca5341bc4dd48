/* One IK branch tracked along a path: the tracking step of the closed-form solver, row by row.
 *
 * The Python side is ClosedFormIK._track (fabric/robot/closed_form.py) with the families' one-branch solves
 * (fabric/robot/opw.py: OPWArm._solve, fabric/robot/ur.py: URArm._branches); the geometry and its symbols are
 * documented there. numpy solves a block of rows of one branch, then keeps the leading rows where the branch
 * stays valid and quiet. Here each row is solved and tested in turn and the first row that fails ends the
 * call: the rows after it are never solved.
 *
 * A row is kept ("fine") when
 *   - the branch reaches it (the wrist centre is reachable by the upper arm and forearm),
 *   - every single-turn joint lies within its limits once put in [lower, lower + 2 pi) (ClosedFormIK.canon),
 *   - its step from the previous row is quiet: 4 |dq|^2 < min(gap, pi)^2, dq compared modulo 2 pi where the
 *     plain difference fails, gap being the branch's distance from the nearest other branch (then the branch
 *     is provably the nearest to the previous row's joints).
 * Kept rows' joints go to q (row j of joint j, stride qstride) and their singular flags to sing; the call
 * returns how many rows were kept.
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is released
 * during the call) from fabric/robot/native_track.py.
 */
#include <math.h>

#define TWO_PI 6.283185307179586
#define PI_ 3.141592653589793
#define LIMIT_TOL_RAD 1e-9
#define WRIST_SING_SIN 0.01
#define ELBOW_SING_COS 0.01
#define SHOULDER_SING_MM 10.0

/* The joint representation shared by both families: q = sign * (theta - offset), wrapped when offset != 0;
 * base: the family's base frame in the columns' frame (R row-major, t), or none. */
typedef struct {
    double off[6];
    double sign[6];
    double lower[6];
    double upper[6];
    double single[6];  /* 1: single-turn joint (limits tested), 0: multi-turn (placed later by unwrapping) */
    double has_base;
    double R[9];
    double t[3];
} Joints;

typedef struct {
    double a1, a2, b, c1, c2, c3, c4, k, phi, cos_phi, sin_phi;
} OPW;

/* A row's gap to the other branches, min over k of 2 atan2(y[k], x[k]) (x, y >= 0), left unevaluated: most
 * steps are far shorter than its lower bound min 2 y / (x + y) (atan(u) >= u / (1 + u) for u >= 0). */
typedef struct {
    double y[2], x[2];
    int n;
} Gap;

static double gap_lower(const Gap *g)
{
    double lo = PI_;
    for (int k = 0; k < g->n; k++) {
        double s = g->x[k] + g->y[k];
        double v = s > 0.0 ? 2.0 * g->y[k] / s : 0.0;
        lo = v < lo ? v : lo;
    }
    return lo;
}

static double gap_exact(const Gap *g)
{
    double v = PI_;
    for (int k = 0; k < g->n; k++) {
        double a = 2.0 * atan2(g->y[k], g->x[k]);
        v = a < v ? a : v;
    }
    return v;
}

typedef struct {
    double d1, a2, a3, d4, d5, d6;
} UR;

static double wrap(double a) { return a - TWO_PI * nearbyint(a / TWO_PI); }

/* atan(x) for 0 <= x <= 1 by Cephes' rational form (S. L. Moshier's atan.c; relative error about 2e-16),
 * reduced about tan(pi/8) instead of 0.66 since x never exceeds 1 here. */
static double atan01(double x)
{
    static const double P[5] = {-8.750608600031904122785E-1, -1.615753718733365076637E1,
                                -7.500855792314704667340E1, -1.228866684490136173410E2,
                                -6.485021904942025371773E1};
    static const double Q[5] = {2.485846490142306297962E1, 1.650270098316988542046E2,
                                4.328810604912902668951E2, 4.853903996359136964868E2,
                                1.945506571482613964425E2};
    double y = 0.0, extra = 0.0;
    if (x > 0.66) {                                   /* atan(x) = pi/4 + atan((x - 1) / (x + 1)) */
        y = 0.7853981633974483;
        extra = 0.5 * 6.123233995736765886130E-17;
        x = (x - 1.0) / (x + 1.0);
    }
    double z = x * x;
    double p = (((P[0] * z + P[1]) * z + P[2]) * z + P[3]) * z + P[4];
    double q = ((((z + Q[0]) * z + Q[1]) * z + Q[2]) * z + Q[3]) * z + Q[4];
    return y + (x * (z * p / q) + x + extra);
}

/* atan2(y, x) in [-pi, pi] to within a few units in the last place of libm's: about a third of its time,
 * which the eight angles of a row spend most of. atan2(+-0, x) keeps libm's signs for x >= +0 and
 * answers +-pi for x < 0 (and x = -0: pi, where libm answers pi too for y = +0). */
static double fast_atan2(double y, double x)
{
    double ax = fabs(x), ay = fabs(y);
    double mx = ax > ay ? ax : ay, mn = ax > ay ? ay : ax;
    if (!(mx > 0.0) || isinf(mx))
        return atan2(y, x);                           /* zeros, infinities and NaN: libm's answers */
    double r = atan01(mn / mx);
    if (ay > ax)
        r = 1.5707963267948966 - r;
    if (x < 0.0)
        r = PI_ - r;
    return y < 0.0 || (y == 0.0 && signbit(y)) ? -r : r;
}

static double flip(double a) { return a >= 0.0 ? a - PI_ : a + PI_; }

static double to_q(const Joints *J, double theta, int j)
{
    double s = J->sign[j], o = J->off[j];
    if (o != 0.0)
        return wrap(s > 0 ? theta - o : o - theta);
    return s > 0 ? theta : -theta;
}

/* Row i's nine columns (position, z axis, y axis) in the family's base frame. */
static void model_cols(const Joints *J, const double *C, long stride, long i, double m[9])
{
    for (int k = 0; k < 9; k++)
        m[k] = C[k * stride + i];
    if (J->has_base == 0.0)
        return;
    const double *R = J->R;
    double v[9];
    double p[3] = {m[0] - J->t[0], m[1] - J->t[1], m[2] - J->t[2]};
    for (int c = 0; c < 3; c++) {
        const double *x = c == 0 ? p : m + 3 * c;
        for (int r = 0; r < 3; r++)
            v[3 * c + r] = R[0 * 3 + r] * x[0] + R[1 * 3 + r] * x[1] + R[2 * 3 + r] * x[2];  /* R^T x */
    }
    for (int k = 0; k < 9; k++)
        m[k] = v[k];
}

/* Single-turn joints put in [lower, lower + 2 pi) (in place); whether all are within their upper limits. */
static int canon_in_limits(const Joints *J, double q[6])
{
    int inlim = 1;
    for (int j = 0; j < 6; j++) {
        if (J->single[j] == 0.0)
            continue;
        double lo = J->lower[j];
        if (lo > -PI_) {
            if (q[j] < lo)
                q[j] += TWO_PI;
        } else if (lo + TWO_PI <= PI_) {
            if (q[j] >= lo + TWO_PI)
                q[j] -= TWO_PI;
        }
        if (!(q[j] <= J->upper[j] + LIMIT_TOL_RAD))
            inlim = 0;
    }
    return inlim;
}

/* Whether the step prev -> q is shorter than half the gap to the other branches (and pi/2), compared plain,
 * then modulo 2 pi (ClosedFormIK._track_block's test). */
static int quiet(const double prev[6], const double q[6], const Gap *gap)
{
    double dd = 0.0, dw = 0.0;
    for (int j = 0; j < 6; j++) {
        double d = q[j] - prev[j];
        dd += d * d;
    }
    double lo = gap_lower(gap);
    if (4.0 * dd < lo * lo)
        return 1;
    double g = gap_exact(gap);
    double sep2 = g * g;
    if (4.0 * dd < sep2)
        return 1;
    for (int j = 0; j < 6; j++) {
        double d = wrap(q[j] - prev[j]);
        dw += d * d;
    }
    return 4.0 * dw < sep2;
}

/* theta6 from the y column of Rz(t4) Ry(t5) Rz(t6): exact for any theta4, theta5 (opw.py: _zyz_theta6). */
static double zyz_theta6(double R01, double R11, double R21, double th4, double th5)
{
    double c4 = cos(th4), s4 = sin(th4), c5 = cos(th5), s5 = sin(th5);
    return fast_atan2(s5 * R21 - c5 * (c4 * R01 + s4 * R11), c4 * R11 - s4 * R01);
}

/* One OPW branch of one row (OPWArm._solve and _wrist_variant); returns reach, fills q, singular, gap. */
static int opw_row(const OPW *P, const Joints *J, const double m[9], int branch, double q[6], int *sing, Gap *gap)
{
    int shoulder = branch / 4, elbow = (branch / 2) % 2, wrist = branch % 2;
    double cx = m[0] - P->c4 * m[3], cy = m[1] - P->c4 * m[4], cz = m[2] - P->c4 * m[5];
    double zx = m[3], zy = m[4], zz = m[5], yx = m[6], yy = m[7], yz = m[8];
    double b = P->b;
    double rho2 = cx * cx + cy * cy;
    double t = sqrt(rho2 - b * b > 0.0 ? rho2 - b * b : 0.0);
    double inv = 1.0 / (rho2 > 0.0 ? rho2 : 1.0);
    double ts = shoulder ? -t : t;                    /* the centre at (ts, b) in the arm's plane */
    double c1 = (cx * ts + cy * b) * inv, s1 = (cy * ts - cx * b) * inv;
    double th1 = fast_atan2(s1, c1);
    double u = (shoulder ? -t : t) - P->a1, v = cz - P->c1;
    double c2 = P->c2, k = P->k;
    double D = (u * u + v * v - c2 * c2 - k * k) / (2.0 * c2 * k);
    int ok = rho2 >= b * b && fabs(D) <= 1.0 + 1e-12;
    double Dc = D < -1.0 ? -1.0 : (D > 1.0 ? 1.0 : D);
    double sabs = sqrt(1.0 - Dc * Dc > 0.0 ? 1.0 - Dc * Dc : 0.0);
    double spsi = elbow ? -sabs : sabs;
    double A = c2 + k * Dc, Bk = k * spsi;
    double y2 = u * A - v * Bk, x2 = v * A + u * Bk;
    double th2 = fast_atan2(y2, x2);
    double th3 = fast_atan2(spsi, Dc);
    if (P->phi != 0.0)
        th3 = wrap(th3 - P->phi);
    /* cos and sin of theta2 + theta3 from their vectors, no trigonometric call: theta2's is (x2, y2) scaled,
     * theta3's is (Dc, spsi) turned back by phi (cos_phi, sin_phi) */
    double r2 = sqrt(x2 * x2 + y2 * y2);
    double c2v = r2 > 0.0 ? x2 / r2 : 1.0, s2v = r2 > 0.0 ? y2 / r2 : 0.0;
    double c3v = Dc * P->cos_phi + spsi * P->sin_phi, s3v = spsi * P->cos_phi - Dc * P->sin_phi;
    double c23 = c2v * c3v - s2v * s3v, s23 = s2v * c3v + c2v * s3v;
    double zx1 = c1 * zx + s1 * zy, zy1 = c1 * zy - s1 * zx;
    double yx1 = c1 * yx + s1 * yy, yy1 = c1 * yy - s1 * yx;
    double R02 = c23 * zx1 - s23 * zz, R12 = zy1, R22 = s23 * zx1 + c23 * zz;
    double R01 = c23 * yx1 - s23 * yz, R11 = yy1, R21 = s23 * yx1 + c23 * yz;
    double h = sqrt(R02 * R02 + R12 * R12);
    double th4 = fast_atan2(R12, R02), th5 = fast_atan2(h, R22);
    double th6 = h < 1e-3 ? zyz_theta6(R01, R11, R21, th4, th5)
                          : fast_atan2(h * h * R21 - R22 * (R02 * R01 + R12 * R11), R02 * R11 - R12 * R01);
    *sing = h < WRIST_SING_SIN || sabs < ELBOW_SING_COS || t < SHOULDER_SING_MM;
    gap->y[0] = sabs;
    gap->x[0] = fabs(Dc);
    gap->y[1] = t;
    gap->x[1] = fabs(b);
    gap->n = b != 0.0 ? 2 : 1;
    if (wrist) {
        th4 = flip(th4);
        th5 = -th5;
        th6 = flip(th6);
    }
    double th[6] = {th1, th2, th3, th4, th5, th6};
    for (int j = 0; j < 6; j++)
        q[j] = to_q(J, th[j], j);
    return ok;
}

/* One UR branch of one row (URArm._shoulder, _wrist, _plane, _elbow); returns reach, fills q, singular, gap. */
static int ur_row(const UR *P, const Joints *J, const double m[9], int branch, double q[6], int *sing, Gap *gap)
{
    int shoulder = branch / 4, elbow = (branch / 2) % 2, wrist = branch % 2;
    double px = m[0], py = m[1], pz = m[2], zx = m[3], zy = m[4], zz = m[5], yx = m[6], yy = m[7], yz = m[8];
    double xx = yy * zz - yz * zy, xy = yz * zx - yx * zz, xz = yx * zy - yy * zx;   /* x = y cross z */
    double d4 = P->d4, d5 = P->d5, d6 = P->d6;
    double p5x = px - d6 * zx, p5y = py - d6 * zy;
    double r2 = p5x * p5x + p5y * p5y;
    double t = sqrt(r2 - d4 * d4 > 0.0 ? r2 - d4 * d4 : 0.0);
    int ok_sh = r2 >= d4 * d4;
    double ts = shoulder ? -t : t;
    double inv = 1.0 / (r2 > 0.0 ? r2 : 1.0);
    double c1 = (ts * p5x - d4 * p5y) * inv, s1 = (ts * p5y + d4 * p5x) * inv;
    double th1 = fast_atan2(s1, c1);
    /* wrist */
    double c5 = s1 * zx - c1 * zy;
    double zx6 = s1 * xx - c1 * xy, zy6 = s1 * yx - c1 * yy;
    double h = hypot(zx6, zy6);
    double hinv = 1.0 / (h > 0.0 ? h : 1.0);
    double sgn = wrist ? -1.0 : 1.0;
    double c6 = h > 0.0 ? sgn * zx6 * hinv : 1.0, s6 = -sgn * zy6 * hinv, s5 = sgn * h;
    /* plane */
    double a = c5 * c6, bb = -c5 * s6, cc = -s5;
    double x4x = a * xx + bb * yx + cc * zx, x4y = a * xy + bb * yy + cc * zy, x4z = a * xz + bb * yz + cc * zz;
    double th234 = fast_atan2(x4z, c1 * x4x + s1 * x4y);
    double ox = px - d6 * zx + d5 * (s6 * xx + c6 * yx);
    double oy = py - d6 * zy + d5 * (s6 * xy + c6 * yy);
    double oz = pz - d6 * zz + d5 * (s6 * xz + c6 * yz);
    double X = c1 * ox + s1 * oy, Y = oz - P->d1;
    double a2 = P->a2, a3 = P->a3;
    double c3 = (X * X + Y * Y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3);
    int ok = ok_sh && fabs(c3) <= 1.0 + 1e-12;
    c3 = c3 < -1.0 ? -1.0 : (c3 > 1.0 ? 1.0 : c3);
    double sabs = sqrt(1.0 - c3 * c3);
    *sing = h < WRIST_SING_SIN || sabs < ELBOW_SING_COS || t < SHOULDER_SING_MM;
    gap->y[0] = sabs;
    gap->x[0] = fabs(c3);
    gap->y[1] = t;
    gap->x[1] = fabs(d4);
    gap->n = 2;
    /* elbow */
    double s3 = elbow ? -sabs : sabs;
    double A = a2 + a3 * c3, Bk = a3 * s3;
    double th2 = fast_atan2(Y * A - X * Bk, X * A + Y * Bk);
    double th3 = fast_atan2(s3, c3);
    double th4 = wrap(th234 - th2 - th3);
    double th[6] = {th1, th2, th3, th4, fast_atan2(s5, c5), fast_atan2(s6, c6)};
    for (int j = 0; j < 6; j++)
        q[j] = to_q(J, th[j], j);
    return ok;
}

typedef int (*RowFn)(const void *P, const Joints *J, const double m[9], int branch, double q[6], int *sing,
                     Gap *gap);

static long track(RowFn row, const void *P, const double *C, long stride, long n, const double *joints,
                  int branch, const double *prev_in, double *q, long qstride, unsigned char *sing)
{
    const Joints *J = (const Joints *)joints;
    double prev[6], m[9], qi[6];
    Gap gap;
    int sg;
    for (int j = 0; j < 6; j++)
        prev[j] = prev_in[j];
    for (long i = 0; i < n; i++) {
        model_cols(J, C, stride, i, m);
        int fine = row(P, J, m, branch, qi, &sg, &gap);
        fine = canon_in_limits(J, qi) && fine;
        if (!fine || !quiet(prev, qi, &gap))
            return i;
        for (int j = 0; j < 6; j++) {
            q[j * qstride + i] = qi[j];
            prev[j] = qi[j];
        }
        sing[i] = (unsigned char)sg;
    }
    return n;
}

static int opw_row_fn(const void *P, const Joints *J, const double m[9], int branch, double q[6], int *sing,
                      Gap *gap)
{
    return opw_row((const OPW *)P, J, m, branch, q, sing, gap);
}

static int ur_row_fn(const void *P, const Joints *J, const double m[9], int branch, double q[6], int *sing,
                     Gap *gap)
{
    return ur_row((const UR *)P, J, m, branch, q, sing, gap);
}

/* The tracking step of an OPW arm over rows 0..n-1 of C (9 rows of stride `stride`); see the file's head.
 * params: a1, a2, b, c1, c2, c3, c4, k = hypot(a2, c3), phi = atan2(a2, c3), cos phi, sin phi; joints: a Joints block. */
long opw_track(const double *C, long stride, long n, const double *params, const double *joints, int branch,
               const double *prev, double *q, long qstride, unsigned char *sing)
{
    return track(opw_row_fn, params, C, stride, n, joints, branch, prev, q, qstride, sing);
}

/* The same for a UR-type arm; params: d1, a2, a3, d4, d5, d6. */
long ur_track(const double *C, long stride, long n, const double *params, const double *joints, int branch,
              const double *prev, double *q, long qstride, unsigned char *sing)
{
    return track(ur_row_fn, params, C, stride, n, joints, branch, prev, q, qstride, sing);
}
