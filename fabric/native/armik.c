/* The closed-form IK of OPW, UR and Panda-type arms along a path, with the branch choice: the loop of
 * ClosedFormIK._track (fabric/robot/closed_form.py) row by row, without numpy's passes over memory.
 *
 * The formulas are those of fabric/robot/opw.py (OPWArm._terms, _solve, _wrist_variant),
 * fabric/robot/ur.py (URArm._shoulder, _wrist, _plane, _elbow) and fabric/robot/panda.py (PandaArm._link6,
 * _elbow, _wrist_reach, _wrist, _upper_arm, _shoulder, _branches), term for term and in the same order, so
 * both paths give the same joints (to the last bits of libm's and numpy's trigonometric functions).
 * The branch choice is the same state machine as _track: *tracking* keeps the current branch while it stays valid and quiet (its step is
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

enum { FAMILY_OPW = 0, FAMILY_UR = 1, FAMILY_PANDA = 2 };
enum { NQ_MAX = 7 };

/* par: per joint (NQ_MAX each) the offsets, signs, lower and upper limits and multi-turn flags (0/1), then the
 * tolerances: wrist |sin|, elbow |cos|, shoulder mm, joint-limit rad. fam: the family's constants (opw_branch,
 * ur_branch, panda_*: F_* below). */
enum { P_OFF = 0, P_SIGN = 7, P_LOWER = 14, P_UPPER = 21, P_MULTI = 28, P_WRIST = 35, P_ELBOW = 36,
       P_SHOULDER = 37, P_LIMIT = 38, P_COUNT = 39 };
/* the Panda type's constants: K (3x3, row-major), kW, the turned vectors u, gv, hv (X0, X1, X2, Xk, Xs: 15
 * each), D, 1 / (2 R4), g4, beta */
enum { F_K = 0, F_KW = 9, F_U = 12, F_GV = 27, F_HV = 42, F_D = 57, F_INV2R4 = 58, F_G4 = 59, F_BETA = 60,
       F_PANDA_COUNT = 61 };

/* panda._lin of constant coefficients (x, y, z: c0 x + c1 y + c2 z) as a list of its terms, made once per
 * call: the zero coefficients left out, 1 and -1 without a product, as there */
typedef struct {
    int n, k[3], kind[3];      /* kind 1: +v[k], -1: -v[k], 0: c v[k] */
    double c[3];
} Lin;

typedef struct {
    int family;
    int nq;
    const double *f;           /* the family's constants */
    const double *p;           /* par */
    Lin lin[4];                /* Panda type: K's columns (link 6's axes), then kW (the wrist's offset) */
} Arm;

/* A7 of a Panda-type arm, per row or one for all (cos, sin and the wrapped angle, computed by the caller) */
typedef struct {
    const double *c7, *s7, *q7;
    int per_row;
} Free;

static const double PI = 3.14159265358979323846;
static const double TWO_PI = 6.28318530717958647692;

/* round half to even, as nearbyint in the default rounding mode, without the library call: exact for
 * |x| < 2^51 (adding and taking away 1.5 * 2^52 leaves the integer part) */
static double round_even(double x)
{
    if (!(fabs(x) < 2251799813685248.0))
        return nearbyint(x);
    return (x + 6755399441055744.0) - 6755399441055744.0;
}

static double wrap(double a) { return a - TWO_PI * round_even(a / TWO_PI); }

static double flip(double a) { return a >= 0.0 ? a - PI : a + PI; }

/* joint angle of model angle theta (OPWArm._q / URArm._q) */
static double to_q(const Arm *arm, double theta, int j)
{
    double s = arm->p[P_SIGN + j], o = arm->p[P_OFF + j];
    if (o != 0.0)
        return wrap(s > 0.0 ? theta - o : o - theta);
    return s > 0.0 ? theta : -theta;
}

/* The branch's gap (ClosedFormArm.ik_branch_cols' gap_rad) as the family writes it: the smallest over groups
 * of twice the largest atan2(y, x) of the group (y, x >= 0), at most pi. Kept as its terms: the tracking
 * test needs the atan2 calls only where a cheap lower bound does not settle it (gap_lower), and the full
 * method none. */
typedef struct {
    double y[2][2], x[2][2];
    int groups, size[2];
} Gap;

/* One row's solution of one branch: q (model -> joint angles, [-pi, pi]), reach, singular, gap. */
typedef struct {
    double q[NQ_MAX];
    int reach;
    int sing;
    Gap gap;
} Branch;

static void gap_group(Gap *g, double y0, double x0, double y1, double x1, int size)
{
    int k = g->groups++;
    g->size[k] = size;
    g->y[k][0] = y0;
    g->x[k][0] = x0;
    g->y[k][1] = y1;
    g->x[k][1] = x1;
}

/* The gap exactly as the family computes it (the same atan2 calls, so the same bits). */
static double gap_exact(const Gap *g)
{
    double gap = PI;                  /* the most a gap is taken for (the tracking test's min(gap, pi)) */
    for (int k = 0; k < g->groups; k++) {
        double a = 2.0 * atan2(g->y[k][0], g->x[k][0]);
        if (g->size[k] > 1) {
            double b = 2.0 * atan2(g->y[k][1], g->x[k][1]);
            a = a > b ? a : b;
        }
        gap = a < gap ? a : gap;
    }
    return gap;
}

/* A lower bound of gap_exact without a trigonometric call: atan2(y, x) >= sin(atan2(y, x)) = y / |(x, y)|
 * on [0, pi/2], less a relative 1e-12 for rounding. */
static double gap_lower(const Gap *g)
{
    double gap = PI;
    for (int k = 0; k < g->groups; k++) {
        double a = 0.0;
        for (int l = 0; l < g->size[k]; l++) {
            double y = g->y[k][l], x = g->x[k][l], r2 = x * x + y * y;
            double b = r2 > 0.0 ? 2.0 * (y / sqrt(r2)) * (1.0 - 1e-12) : 0.0;
            a = b > a ? b : a;
        }
        gap = a < gap ? a : gap;
    }
    return gap;
}

/* OPWArm._terms + _solve + _wrist_variant for one row (c: the nine model columns). */
static void opw_branch(const Arm *arm, const double *c, int branch, Branch *out)
{
    const double *p = arm->p, *f = arm->f;
    double a1 = f[0], b = f[2], cc1 = f[3], c2 = f[4], c4 = f[6], k = f[7], phi = f[8];
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
    out->gap.groups = 0;                              /* theta3 between the two elbows, wrapped */
    gap_group(&out->gap, sabs, fabs(Dc), 0.0, 0.0, 1);
    if (b != 0.0)                                     /* theta1 between the two shoulders */
        gap_group(&out->gap, t, fabs(b), 0.0, 0.0, 1);
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
    const double *p = arm->p, *f = arm->f;
    double d1 = f[0], a2 = f[1], a3 = f[2], d4 = f[3], d5 = f[4], d6 = f[5];
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
    out->gap.groups = 0;
    gap_group(&out->gap, sabs, fabs(c3), 0.0, 0.0, 1);
    gap_group(&out->gap, t, fabs(d4), 0.0, 0.0, 1);
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
    const double *p = arm->f;
    if (arm->family == FAMILY_PANDA)     /* PandaArm.q1_free: never a pre-pass (held on the chosen joints) */
        return 0;
    if (arm->family == FAMILY_OPW) {
        if (p[2] != 0.0)
            return 0;
        double cx = c[0] - p[6] * c[3], cy = c[1] - p[6] * c[4];
        return cx * cx + cy * cy < 1e-12;
    }
    double p5x = c[0] - p[5] * c[3], p5y = c[1] - p[5] * c[4];
    return p5x * p5x + p5y * p5y < 1e-12;
}

/* The Panda type (panda.py), one row. */
typedef struct {           /* PandaArm._link6 */
    double R6[3][3];       /* R6[c]: link 6's column c */
    double W[3], WW, v[3];
} Link6;

typedef struct {           /* PandaArm._elbow, _wrist_reach and the elbow's gap and singular flags */
    double q4, k, sphi, u[3], gv[3], hv[3], g;
    int ok;
    Gap gap;
    int sing_ew;
} PElbow;

static void lin_of(const double *coef, int stride, Lin *out)
{   /* coefficients coef[0], coef[stride], coef[2 stride] */
    out->n = 0;
    for (int k = 0; k < 3; k++) {
        double ck = coef[stride * k];
        if (ck == 0.0)
            continue;
        out->k[out->n] = k;
        out->kind[out->n] = ck == 1.0 ? 1 : (ck == -1.0 ? -1 : 0);
        out->c[out->n] = ck;
        out->n++;
    }
}

#ifdef __GNUC__
#define INLINE static inline __attribute__((always_inline))
#else
#define INLINE static inline
#endif

INLINE void lin3(const Lin *L, const double *const vec[3], double *out)
{   /* panda._lin: the terms summed in order, component by component (0 where there are none) */
    for (int i = 0; i < 3; i++) {
        double acc = 0.0;
        for (int m = 0; m < L->n; m++) {
            double x = vec[L->k[m]][i];
            double term = L->kind[m] == 1 ? x : (L->kind[m] == -1 ? -x : L->c[m] * x);
            acc = m ? acc + term : term;
        }
        out[i] = acc;
    }
}

static void panda_link6(const Arm *arm, const double *c, double c7, double s7, Link6 *l)
{
    double p[3] = {c[0], c[1], c[2]}, z[3] = {c[3], c[4], c[5]}, y[3] = {c[6], c[7], c[8]};
    double x[3] = {y[1] * z[2] - y[2] * z[1], y[2] * z[0] - y[0] * z[2], y[0] * z[1] - y[1] * z[0]};
    double xr[3], yr[3];
    for (int i = 0; i < 3; i++) {
        xr[i] = c7 * x[i] - s7 * y[i];
        yr[i] = s7 * x[i] + c7 * y[i];
    }
    const double *const vec[3] = {xr, yr, z};
    double w[3];
    for (int col = 0; col < 3; col++)
        lin3(&arm->lin[col], vec, l->R6[col]);
    lin3(&arm->lin[3], vec, w);
    for (int i = 0; i < 3; i++)
        l->W[i] = p[i] + w[i];
    l->WW = l->W[0] * l->W[0] + l->W[1] * l->W[1] + l->W[2] * l->W[2];
    for (int col = 0; col < 3; col++)
        l->v[col] = -(l->R6[col][0] * l->W[0] + l->R6[col][1] * l->W[1] + l->R6[col][2] * l->W[2]);
}

static void turned_at(const double *X, double k, double esp, double *out)
{   /* X0 + k Xk + esp Xs (PandaArm._elbow's at) */
    for (int i = 0; i < 3; i++)
        out[i] = X[i] + k * X[9 + i] + esp * X[12 + i];
}

static void panda_elbow(const Arm *arm, const Link6 *l, int elbow, PElbow *e)
{
    const double *f = arm->f, *p = arm->p;
    double k = (f[F_D] - l->WW) * f[F_INV2R4];
    e->ok = fabs(k) <= 1.0 + 1e-12;
    k = k < -1.0 ? -1.0 : (k > 1.0 ? 1.0 : k);
    double sphi = sqrt(1.0 - k * k);
    double esp = elbow ? -sphi : sphi;
    e->q4 = wrap(f[F_G4] + atan2(esp, k));
    e->k = k;
    e->sphi = sphi;
    turned_at(f + F_U, k, esp, e->u);
    turned_at(f + F_GV, k, esp, e->gv);
    turned_at(f + F_HV, k, esp, e->hv);
    double ua = e->u[0], ub = e->u[1], uc = e->u[2], va = l->v[0], vb = l->v[1], vc = l->v[2];
    double g2 = 0.5 * ((ub * ub + uc * uc - vb * vb) + (va * va + vc * vc - ua * ua));
    e->g = sqrt(fmax(g2, 0.0));
    e->ok = e->ok && g2 >= -1e-12 * l->WW;
    e->gap.groups = 0;
    gap_group(&e->gap, sphi, fabs(k), 0.0, 0.0, 1);
    gap_group(&e->gap, e->g, fabs(ua), e->g, fabs(vb), 2);
    e->sing_ew = e->ok && (sphi < p[P_ELBOW] || e->g < p[P_WRIST] * sqrt(l->WW));
}

/* q5, q6 and the upper arm's d = R3 w3, m = R3 y of one wrist choice (PandaArm._wrist, _upper_arm) */
static void panda_wrist(const Link6 *l, const PElbow *e, int wrist, double *q5, double *q6, double *d, double *m)
{
    double ua = e->u[0], ub = e->u[1], uc = e->u[2], va = l->v[0], vb = l->v[1], vc = l->v[2];
    double gw = wrist ? -e->g : e->g;
    double y5 = uc * vb - ub * gw, x5 = ub * vb + uc * gw;
    double y6 = vc * ua - va * gw, x6 = vc * gw + va * ua;
    double h5 = hypot(x5, y5), h6 = hypot(x6, y6);
    double i5 = 1.0 / (h5 > 0.0 ? h5 : 1.0), i6 = 1.0 / (h6 > 0.0 ? h6 : 1.0);
    double c5 = h5 > 0.0 ? x5 * i5 : 1.0, s5 = y5 * i5;
    double c6 = h6 > 0.0 ? x6 * i6 : 1.0, s6 = y6 * i6;
    *q5 = atan2(y5, x5);
    *q6 = atan2(y6, x6);
    const double *vecs[2] = {e->gv, e->hv};
    double *outs[2] = {d, m};
    for (int t = 0; t < 2; t++) {
        double a = vecs[t][0], b = vecs[t][1], cc = vecs[t][2];
        double b1 = c5 * b + s5 * cc, c1 = c5 * cc - s5 * b;
        double a2 = c6 * a - s6 * c1, c2 = s6 * a + c6 * c1;
        for (int i = 0; i < 3; i++)
            outs[t][i] = l->R6[0][i] * a2 + l->R6[1][i] * b1 + l->R6[2][i] * c2;
    }
}

/* PandaArm._shoulder's result: q1, q2, q3 and h = |d_xy| (the gimbal lock's distance) */
typedef struct {
    double q1, q2, q3, h;
} PShoulder;

/* PandaArm._shoulder (no A1 held) for a shoulder sign (+1, -1) */
static PShoulder panda_shoulder(const Arm *arm, const double *d, const double *m, double sign)
{
    PShoulder out;
    double beta = arm->f[F_BETA];
    double dx = d[0], dy = d[1], dz = d[2];
    double h = hypot(dx, dy);
    double inv = 1.0 / (h > 0.0 ? h : 1.0);
    double c1 = h > 0.0 ? sign * dx * inv : sign * 1.0;
    double s1 = sign * dy * inv;
    out.q1 = atan2(s1, c1);
    double cx = c1 * dx + s1 * dy;
    double q2 = atan2(cx, dz);
    if (beta != 0.0)
        q2 = wrap(q2 - beta);
    out.q2 = q2;
    double mx = m[0], my = m[1], mz = m[2];
    double mx1 = c1 * mx + s1 * my, my1 = c1 * my - s1 * mx;
    out.q3 = atan2(cx * mz - dz * mx1, my1);
    out.h = h;
    return out;
}

static void panda_fill(const PElbow *e, double q5, double q6, double q7, PShoulder sh, const Arm *arm,
                       Branch *out)
{
    out->q[0] = sh.q1;
    out->q[1] = sh.q2;
    out->q[2] = sh.q3;
    out->q[3] = e->q4;
    out->q[4] = q5;
    out->q[5] = q6;
    out->q[6] = q7;
    out->reach = e->ok;
    out->sing = e->sing_ew || (e->ok && sh.h < arm->p[P_WRIST]);
    out->gap = e->gap;
}

/* One branch as PandaArm.ik_branch_cols solves it (its own shoulder sign, no flip) */
static void panda_branch(const Arm *arm, const double *c, double c7, double s7, double q7, int branch, Branch *out)
{
    Link6 l;
    PElbow e;
    double q5, q6, d[3], m[3];
    panda_link6(arm, c, c7, s7, &l);
    panda_elbow(arm, &l, (branch / 2) % 2, &e);
    panda_wrist(&l, &e, branch % 2, &q5, &q6, d, m);
    panda_fill(&e, q5, q6, q7, panda_shoulder(arm, d, m, branch / 4 ? -1.0 : 1.0), arm, out);
}

/* All 8 branches as PandaArm.ik_branches_cols solves them: the second shoulder is the first turned over the
 * top, (q1 + pi, -q2 - 2 beta, q3 + pi) */
static void panda_all(const Arm *arm, const double *c, double c7, double s7, double q7, Branch *br)
{
    Link6 l;
    double beta = arm->f[F_BETA];
    panda_link6(arm, c, c7, s7, &l);
    for (int el = 0; el < 2; el++) {
        PElbow e;
        panda_elbow(arm, &l, el, &e);
        for (int w = 0; w < 2; w++) {
            double q5, q6, d[3], m[3];
            panda_wrist(&l, &e, w, &q5, &q6, d, m);
            PShoulder first = panda_shoulder(arm, d, m, 1.0);
            PShoulder over = {flip(first.q1), wrap(-first.q2 - 2.0 * beta), flip(first.q3), first.h};
            panda_fill(&e, q5, q6, q7, first, arm, &br[2 * el + w]);
            panda_fill(&e, q5, q6, q7, over, arm, &br[4 + 2 * el + w]);
        }
    }
}

/* Single-turn joints into [lower, lower + 2 pi) (ClosedFormIK._canon_col: both ends take the limit tolerance);
 * whether the branch is valid (reachable and within the limits). */
static int limit(const Arm *arm, Branch *out)
{
    const double *p = arm->p;
    int inlim = 1;
    for (int j = 0; j < arm->nq; j++) {
        if (p[P_MULTI + j] != 0.0)
            continue;
        double lo = p[P_LOWER + j], tol = p[P_LIMIT], v = out->q[j];
        if (lo > -PI) {
            if (v < lo - tol)
                v += TWO_PI;
        } else if (lo + TWO_PI <= PI) {
            if (v >= lo + TWO_PI - tol)
                v -= TWO_PI;
        }
        out->q[j] = v;
        inlim &= v >= lo - tol && v <= p[P_UPPER + j] + tol;
    }
    return out->reach && inlim;
}

/* One branch of row r (the tracking method: ClosedFormArm.ik_branch_cols), limited; whether it is valid. */
static int solve_branch(const Arm *arm, const double *c, const Free *fr, long r, int branch, Branch *out)
{
    if (arm->family == FAMILY_OPW) {
        opw_branch(arm, c, branch, out);
    } else if (arm->family == FAMILY_UR) {
        ur_branch(arm, c, branch, out);
    } else {
        long i = fr->per_row ? r : 0;
        panda_branch(arm, c, fr->c7[i], fr->s7[i], fr->q7[i], branch, out);
    }
    return limit(arm, out);
}

/* All 8 branches of row r (the full method: ClosedFormArm.ik_branches_cols), limited; valid[k] per branch. */
static void solve_all(const Arm *arm, const double *c, const Free *fr, long r, Branch *br, int *valid)
{
    if (arm->family == FAMILY_PANDA) {
        long i = fr->per_row ? r : 0;
        panda_all(arm, c, fr->c7[i], fr->s7[i], fr->q7[i], br);
    } else {
        for (int k = 0; k < 8; k++) {
            if (arm->family == FAMILY_OPW)
                opw_branch(arm, c, k, &br[k]);
            else
                ur_branch(arm, c, k, &br[k]);
        }
    }
    for (int k = 0; k < 8; k++)
        valid[k] = limit(arm, &br[k]);
}

/* squared joint distance, every angle compared modulo 2 pi (closed_form._sq_dist) */
static double sq_dist(int nq, const double *a, const double *b)
{
    double s = 0.0;
    for (int j = 0; j < nq; j++) {
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

static void put(int nq, double *q, long n, long i, const double *v)
{
    for (int j = 0; j < nq; j++)
        q[j * n + i] = v[j];
}

/* The full method over rows [i, j): all 8 branches, the allowed one nearest the row before (the first row:
 * nearest `prev`), select_branches' rules for a row with none allowed. Leaves the last row's chosen branch in
 * *b_last and whether it is valid in *ok_last. */
static void full_window(const Arm *arm, const double *C, const Free *fr, long n, long i, long j,
                        const double *prev, double *q, uint8_t *row_ok, uint8_t *reach_any, uint8_t *sing,
                        int *b_last, int *ok_last)
{
    Branch br[8], ref;
    int valid[8];
    int chosen = 0;
    double c[9];
    memcpy(ref.q, prev, sizeof ref.q);
    for (long r = i; r < j; r++) {
        gather(C, n, r, c);
        solve_all(arm, c, fr, r, br, valid);
        int any_ok = 0, any_reach = 0;
        for (int k = 0; k < 8; k++) {
            any_ok |= valid[k];
            any_reach |= br[k].reach;
        }
        int best = -1;
        double best_d = INFINITY;
        for (int k = 0; k < 8; k++) {
            int allowed = any_ok ? valid[k] : br[k].reach;
            if (!allowed)
                continue;
            double d = sq_dist(arm->nq, br[k].q, ref.q);
            if (d < best_d || best < 0) {
                best_d = d;
                best = k;
            }
        }
        if (best < 0)          /* none allowed: the window's first row takes branch 0, a later row keeps its own */
            best = r == i ? 0 : chosen;
        chosen = best;
        put(arm->nq, q, n, r, br[chosen].q);
        row_ok[r] = (uint8_t)valid[chosen];
        sing[r] = (uint8_t)br[chosen].sing;
        reach_any[r] = (uint8_t)any_reach;
        ref = br[chosen];
        *ok_last = valid[chosen];
    }
    *b_last = chosen;
}

/* ClosedFormIK._track over n rows of model columns C (9 rows of n: position, z axis, y axis), from the
 * joints `seed` (nq): fills q (nq rows of n), row_ok, reach_any and sing (0/1 per row). A Panda-type arm's A7
 * comes as its cosine, sine and wrapped value, per row (free_per_row) or one for all. Returns n, ARMIK_HOLD
 * when some row's A1 is undefined (nothing written), or ARMIK_BAD_FAMILY. */
long armik_track(int family, int nq, const double *fam, const double *par, long n, const double *C,
                 const double *free_c7, const double *free_s7, const double *free_q7, int free_per_row,
                 const double *seed, long max_rows, double *q, uint8_t *row_ok, uint8_t *reach_any, uint8_t *sing)
{
    Arm arm = {.family = family, .nq = nq, .f = fam, .p = par};
    Free fr = {free_c7, free_s7, free_q7, free_per_row};
    double c[9], prev[NQ_MAX];
    if (!((family == FAMILY_OPW || family == FAMILY_UR) && nq == 6) && !(family == FAMILY_PANDA && nq == 7))
        return ARMIK_BAD_FAMILY;
    if (family == FAMILY_PANDA) {
        for (int col = 0; col < 3; col++)          /* K[:, col]: K is row-major, so its column steps by 3 */
            lin_of(fam + F_K + col, 3, &arm.lin[col]);
        lin_of(fam + F_KW, 1, &arm.lin[3]);
    }
    for (long r = 0; r < n; r++) {
        gather(C, n, r, c);
        if (a1_undefined(&arm, c))
            return ARMIK_HOLD;
    }
    memset(prev, 0, sizeof prev);
    memcpy(prev, seed, (size_t)nq * sizeof *prev);
    long i = 0, window = 32, block = 2048;
    int b = -1;
    while (i < n) {
        if (b < 0) {
            long j = i + window < n ? i + window : n;
            int ok_last = 0;
            full_window(&arm, C, &fr, n, i, j, prev, q, row_ok, reach_any, sing, &b, &ok_last);
            if (!ok_last)
                b = -1;
            if (b < 0)
                window = window * 2 < max_rows ? window * 2 : max_rows;
            for (int k = 0; k < nq; k++)
                prev[k] = q[k * n + j - 1];
            i = j;
            continue;
        }
        long j = i + block < n ? i + block : n;
        long r = i;
        Branch br;
        for (; r < j; r++) {
            gather(C, n, r, c);
            if (!solve_branch(&arm, c, &fr, r, b, &br))
                break;
            double d2 = 0.0, dw2 = 0.0;
            for (int k = 0; k < nq; k++) {
                double d = br.q[k] - prev[k];
                double dw = wrap(d);
                d2 += d * d;
                dw2 += dw * dw;
            }
            double sep = gap_lower(&br.gap);
            if (!(4.0 * d2 < sep * sep) && !(4.0 * dw2 < sep * sep)) {
                sep = gap_exact(&br.gap);          /* the bound did not settle it: the family's own gap */
                if (!(4.0 * d2 < sep * sep) && !(4.0 * dw2 < sep * sep))
                    break;
            }
            put(nq, q, n, r, br.q);
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

/* The sizes of par and of a Panda-type arm's fam that armik_track reads (a check for the caller). */
long armik_par_count(void) { return P_COUNT; }

long armik_panda_count(void) { return F_PANDA_COUNT; }

/* ClosedFormIK._place_multi_turn for joint j of q (nq rows of n): a multi-turn joint's angles (each in
 * [-pi, pi]) unwrapped from seed_j on, as whole turns (the integer count kept apart so that a long path
 * loses no precision), then a wind-up beyond the limits shifted back by whole turns. `turns`: room for n
 * values. The same operations as numpy's path, in the same order. */
void armik_place_multi_turn(long n, double *col, double seed_j, double lo, double hi, double tol, double *turns)
{
    int wrapped = 0, outside = 0;
    double prev = seed_j, acc = 0.0;
    for (long i = 0; i < n; i++) {
        double d = col[i] - prev;
        prev = col[i];
        if (fabs(d) > 0.999 * PI) {
            acc += -round_even(d / TWO_PI);
            wrapped = 1;
        } else {
            acc += 0.0;
        }
        turns[i] = acc;
    }
    for (long i = 0; i < n; i++) {
        double c = wrapped ? col[i] + TWO_PI * turns[i] : col[i];
        if (!wrapped)
            turns[i] = 0.0;
        if (c > hi + tol) {
            turns[i] -= ceil((c - hi) / TWO_PI);
            outside = 1;
        } else if (c < lo - tol) {
            turns[i] += ceil((lo - c) / TWO_PI);
            outside = 1;
        }
    }
    if (wrapped || outside)
        for (long i = 0; i < n; i++)
            col[i] = col[i] + TWO_PI * turns[i];
}
