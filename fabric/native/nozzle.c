/* The nozzle frames of a printing path, the IK's flange columns and the TCP quaternions, row by row.
 *
 * The same arithmetic as fabric/robot/nozzle_frames.py (NozzleFrames.__init__, quats with one nozzle axis)
 * and fabric/robot/path_ik.py (_PathSolver.flange_cols), in the same order, without numpy's passes over
 * memory: numpy's path keeps every temporary of N rows; here a row is done in registers. Arrays are columns
 * (3 rows of n, or one value per column where `per_row` is 0).
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is
 * released during the call).
 */
#include <math.h>

/* NozzleFrames.__init__: x0 = the reference xr projected onto the plane normal to z0 (then the base x axis,
 * then the base y axis where it is parallel to z0), normalised; y0 = z0 x x0. */
void nozzle_frames(long n, const double *z0, int z_per_row, const double *xr, double *x0, double *y0)
{
    static const double FALLBACK[2][3] = {{1.0, 0.0, 0.0}, {0.0, 1.0, 0.0}};
    for (long i = 0; i < n; i++) {
        long iz = z_per_row ? i : 0, nz = z_per_row ? n : 1;
        double z[3] = {z0[iz], z0[nz + iz], z0[2 * nz + iz]};
        double r[3] = {xr[i], xr[n + i], xr[2 * n + i]};
        double x[3], nx = 0.0;
        for (int attempt = 0; attempt < 3; attempt++) {
            if (attempt) {
                r[0] = FALLBACK[attempt - 1][0];
                r[1] = FALLBACK[attempt - 1][1];
                r[2] = FALLBACK[attempt - 1][2];
            }
            double dot = r[0] * z[0] + r[1] * z[1] + r[2] * z[2];
            for (int k = 0; k < 3; k++)
                x[k] = r[k] - dot * z[k];
            nx = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
            if (!(nx < 1e-6))
                break;
        }
        for (int k = 0; k < 3; k++)
            x[k] /= nx;
        x0[i] = x[0];
        x0[n + i] = x[1];
        x0[2 * n + i] = x[2];
        y0[i] = z[1] * x[2] - z[2] * x[1];
        y0[n + i] = z[2] * x[0] - z[0] * x[2];
        y0[2 * n + i] = z[0] * x[1] - z[1] * x[0];
    }
}

/* _PathSolver.flange_cols of every row: the arm end frame's position, z and y columns (9 rows of n) of the TCP
 * frames R0 Rz(theta) at positions p, given m (9: the TCP -> end-frame point, z and y columns) and cos, sin of
 * theta (per row or one). */
void nozzle_flange_cols(long n, const double *p, const double *x0, const double *y0, const double *z0,
                        int z_per_row, const double *c, const double *s, int theta_per_row, const double *m,
                        double *out)
{
    for (long i = 0; i < n; i++) {
        long iz = z_per_row ? i : 0, nz = z_per_row ? n : 1, it = theta_per_row ? i : 0;
        double ci = c[it], si = s[it];
        for (int k = 0; k < 3; k++) {
            const double *mk = m + 3 * k;
            int xy = mk[0] != 0.0 || mk[1] != 0.0;
            double a = ci * mk[0] - si * mk[1], b = si * mk[0] + ci * mk[1];
            for (int r = 0; r < 3; r++) {
                double o = k == 0 ? p[r * n + i] : 0.0;
                if (xy) {
                    o += x0[r * n + i] * a;
                    o += y0[r * n + i] * b;
                }
                if (mk[2] != 0.0)
                    o += z0[r * nz + iz] * mk[2];
                out[(3 * k + r) * n + i] = o;
            }
        }
    }
}

/* NozzleFrames.quats with one nozzle axis: every frame is B Rz(alpha_i), so the quaternion (w, x, y, z; n rows
 * of 4) is q_B (cos h, 0, 0, sin h) with h = (alpha_i + theta_i) / 2, alpha_i = atan2(b_y . x0_i, b_x . x0_i);
 * signed as frames.quat_sign: the first of w, x, y, z larger than sign_tol in size is positive. */
void nozzle_quats(long n, const double *x0, const double *bx, const double *by, const double *qb,
                  const double *theta, int theta_per_row, double sign_tol, double *out)
{
    double w1 = qb[0], x1 = qb[1], y1 = qb[2], z1 = qb[3];
    for (long i = 0; i < n; i++) {
        double xa = x0[i], xb = x0[n + i], xc = x0[2 * n + i];
        double dy = by[0] * xa + by[1] * xb + by[2] * xc;
        double dx = bx[0] * xa + bx[1] * xb + bx[2] * xc;
        double half = 0.5 * (atan2(dy, dx) + theta[theta_per_row ? i : 0]);
        double c = cos(half), s = sin(half);
        double q[4] = {w1 * c - z1 * s, x1 * c + y1 * s, y1 * c - x1 * s, z1 * c + w1 * s};
        int lead = 0;
        while (lead < 3 && !(fabs(q[lead]) > sign_tol))
            lead++;
        int flip = q[lead] < 0.0;
        for (int k = 0; k < 4; k++)
            out[4 * i + k] = flip ? -q[k] : q[k];
    }
}
