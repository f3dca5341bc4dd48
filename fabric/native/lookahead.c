/* The cruise caps of the look-ahead's linear moves (fabric/motion/lookahead.py, _caps), row by row.
 *
 * numpy takes a pass over the rows per joint, and a few per pass (the difference, its magnitude, the rows of
 * the segments, the rate, the comparison, two masked writes); here a row is done at once, with the same
 * arithmetic in the same order, so the caps are numpy's to the bit.
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is
 * released during the call).
 */
#include <math.h>
#include <stdint.h>

/* _caps: q (n x nq, row-major), q0 the joints before row 0; seg (m) the segments' rows (ascending), Ls their
 * lengths, cap_prog their programmed caps; vlim (nq) the joints' velocity limits. Writes each segment's cap,
 * whether a joint's limit lowered it (slowed) and which joint limits it most (worst: the first of equal
 * rates), and for every row whether any joint moves (reorient: more than 1e-12 rad). */
void lookahead_caps(long n, int nq, const double *q, const double *q0, long m, const int64_t *seg, const double *Ls,
                    const double *vlim, const double *cap_prog, double *cap, unsigned char *slowed, int64_t *worst,
                    unsigned char *reorient)
{
    long k = 0;
    for (long i = 0; i < n; i++) {
        const double *now = q + i * nq, *before = i ? now - nq : q0;
        int moves = 0, is_seg = k < m && seg[k] == i;
        double top = -INFINITY;
        long w = 0;
        for (int j = 0; j < nq; j++) {
            double dq = fabs(now[j] - before[j]);
            moves |= dq > 1e-12;
            if (is_seg) {
                double rate = dq / (vlim[j] * Ls[k]);
                if (rate > top) {
                    top = rate;
                    w = j;
                }
            }
        }
        reorient[i] = (unsigned char)moves;
        if (!is_seg)
            continue;
        double cap_joint = 1.0 / (top > 1e-300 ? top : 1e-300);
        slowed[k] = cap_joint < cap_prog[k] * (1.0 - 1e-12);
        cap[k] = cap_prog[k] < cap_joint ? cap_prog[k] : cap_joint;
        worst[k] = w;
        k++;
    }
}
