/* Rows of fixed-point numbers as text: the characters C's and Python's "%.<d>f" write, one row per line.
 *
 * The Python side (fabric/planning/post/numtext.py) formats the same rows with numpy; this is the same
 * algorithm without numpy's passes over memory. A value is scaled to an integer of `decimals` places
 * (nearbyint(|v| * 10^d), the FPU's round-half-even like numpy's rint) and its digits are written; a
 * value whose scaled double lies within its own rounding error of a half (a tie or nearly), or is huge,
 * is written by snprintf, which rounds the exact binary value as Python does. A value not finite, or whose
 * text would be longer than 63 characters, is not written: the call returns NUMTEXT_NOT_FINITE and the
 * caller formats that block itself.
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is
 * released during the call).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#define NUMTEXT_NO_ROOM (-1)
#define NUMTEXT_NOT_FINITE (-2)
#define NUMTEXT_BAD_COLUMN (-3)

enum { KIND_FLOAT = 0, KIND_INT = 1, KIND_TEXT = 2 };

static const uint64_t POW10[13] = {1ULL, 10ULL, 100ULL, 1000ULL, 10000ULL, 100000ULL, 1000000ULL,
                                   10000000ULL, 100000000ULL, 1000000000ULL, 10000000000ULL,
                                   100000000000ULL, 1000000000000ULL};

/* "00" "01" .. "99": two digits per division */
static const char PAIRS[201] =
    "00010203040506070809101112131415161718192021222324252627282930313233343536373839"
    "40414243444546474849505152535455565758596061626364656667686970717273747576777879"
    "8081828384858687888990919293949596979899";

/* The `width` last digits of u (zero-padded) at p[0..width-1]. */
static void put_digits(char *p, uint64_t u, int width)
{
    int k = width;
    while (k >= 2) {
        unsigned pair = (unsigned)(u % 100);
        u /= 100;
        k -= 2;
        p[k] = PAIRS[2 * pair];
        p[k + 1] = PAIRS[2 * pair + 1];
    }
    if (k)
        p[0] = (char)('0' + u % 10);
}

/* Digits of u, most significant first, at p; returns the end. */
static char *put_uint(char *p, uint64_t u)
{
    int width = 1;
    for (uint64_t t = u; t >= 10; t /= 10)
        width++;
    put_digits(p, u, width);
    return p + width;
}

/* "%.<d>f" of v at p (room for at least 64 bytes); returns the end, or NULL where v is not finite. Scaled
 * values of max_scaled or more, and those within tie_tol_r of a half (relative), go to snprintf. */
static char *put_fixed(char *p, double v, int d, double max_scaled, double tie_tol_r)
{
    if (!isfinite(v))
        return NULL;
    double scaled = fabs(v) * (double)POW10[d];
    /* round half to even as nearbyint does, without the library call: exact for 0 <= scaled < 2^52, and
     * a larger scaled value (>= max_scaled, at most 1e15) goes to snprintf below anyway */
    double rounded = scaled < 4503599627370496.0 ? (scaled + 4503599627370496.0) - 4503599627370496.0 : scaled;
    double off = fabs(scaled - rounded);
    if (!(off < 0.5 - scaled * tie_tol_r) || !(scaled < max_scaled)) {
        int len = snprintf(p, 64, "%.*f", d, v);
        return (len > 0 && len < 64) ? p + len : NULL;
    }
    uint64_t iv = (uint64_t)rounded;
    if (signbit(v))
        *p++ = '-';
    if (d == 0)
        return put_uint(p, iv);
    p = put_uint(p, iv / POW10[d]);
    *p++ = '.';
    put_digits(p, iv % POW10[d], d);
    return p + d;
}

/* Rows 0..n-1 of `ncol` columns into out (capacity `cap` bytes), `sep` between columns, '\n' after each row.
 * Column c: kind[c] KIND_FLOAT (double data[c][i * stride[c]], decimals[c] in 0..12), KIND_INT (int64_t
 * data[c][i * stride[c]]) or KIND_TEXT (text[c] of text_len[c] bytes on every row). A stride (in elements)
 * lets a column be read where it lies, e.g. one coordinate of rows of three. max_scaled and tie_tol_r: numtext.py's
 * _MAX_SCALED and _TIE_TOL_R (declared there once). Returns the bytes written, or a NUMTEXT_ code. */
long numtext_rows(long n, int ncol, const int *kind, const void *const *data, const long *stride,
                  const int *decimals, const char *const *text, const long *text_len, char sep, char *out, long cap,
                  double max_scaled, double tie_tol_r)
{
    char *p = out;
    char *end = out + cap;
    for (int c = 0; c < ncol; c++)
        if (kind[c] == KIND_FLOAT && (decimals[c] < 0 || decimals[c] > 12))
            return NUMTEXT_BAD_COLUMN;
    for (long i = 0; i < n; i++) {
        for (int c = 0; c < ncol; c++) {
            if (end - p < 96)
                return NUMTEXT_NO_ROOM;
            if (c && sep)
                *p++ = sep;
            switch (kind[c]) {
            case KIND_FLOAT:
                p = put_fixed(p, ((const double *)data[c])[i * stride[c]], decimals[c], max_scaled, tie_tol_r);
                if (p == NULL)
                    return NUMTEXT_NOT_FINITE;
                break;
            case KIND_INT: {
                int64_t v = ((const int64_t *)data[c])[i * stride[c]];
                uint64_t u = (uint64_t)v;
                if (v < 0) {
                    *p++ = '-';
                    u = 0 - u;
                }
                p = put_uint(p, u);
                break;
            }
            case KIND_TEXT:
                if (end - p < text_len[c] + 2)
                    return NUMTEXT_NO_ROOM;
                memcpy(p, text[c], (size_t)text_len[c]);
                p += text_len[c];
                break;
            default:
                return NUMTEXT_BAD_COLUMN;
            }
        }
        *p++ = '\n';
    }
    return (long)(p - out);
}
