/* The G-code lexer in one pass over the bytes: a block of whole lines -> its words and line facts.
 *
 * The Python side is fabric/gcode/lexer.py (lex_block), whose docstrings define every rule; this is the same
 * lexer as a state machine, and a test lexes the same texts (fuzzed ones too) both ways and compares every
 * array. In short:
 *   - bytes are letters, blanks (space, tab, VT, FF; a CR before an LF), ';', '*', newlines (LF, a lone CR),
 *     or "other" (a value's bytes); ( ... ) comments are blanked first and end at a newline;
 *   - a line's comment starts at its first ';' or '*' (a checksum), and its words end there;
 *   - a word is a letter and the "other" bytes up to the next separator; a letter followed by blanks and then
 *     value bytes takes those (G 1 X 5); a leading N word (a line number) is dropped;
 *   - a value is [+-]digits[.digits]: exact below 10^15 (mantissa / 10^fraction digits, correctly rounded, as
 *     float() reads it), longer numbers read by strtod (also correctly rounded) when finite;
 *   - orphans: "other" bytes after a blank, comment or newline (not after a letter) before the comment;
 *   - checksums: the XOR of the line's bytes before '*' against the number after it;
 *   - exponents: an E word written against a number (X1e30).
 * The block is read as if a newline followed it (the Python side pads it with one).
 *
 * Built and loaded by fabric/native/__init__.py (cc -O2 -shared), called through ctypes (the GIL is released
 * during the call) from fabric/gcode/native_lexer.py.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

enum { C_OTHER = 0, C_LETTER, C_SPACE, C_SEMI, C_STAR, C_NL };
enum { W_OK = 0, W_EMPTY = 1, W_BAD = 2 };

#define MAX_DIGITS 15

static const double P10[MAX_DIGITS + 2] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8,
                                           1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16};

/* Outputs, each with room for the worst case (lines <= n + 1, words <= n). */
typedef struct {
    int64_t *line_start, *code_end;
    int64_t *word_line;
    uint8_t *word_letter;
    double *word_value;
    uint8_t *word_status;
    uint8_t *word_first;
    int64_t *orphan_lines, *checksum_bad_lines, *exponent_lines;
} Out;

/* counts[0..4]: lines, words, orphan lines, bad checksum lines, exponent lines */
enum { N_LINES, N_WORDS, N_ORPHAN, N_BADSUM, N_EXP };

static uint8_t LUT[256];
static int lut_ready = 0;

static void init_lut(void)
{
    for (int c = 0; c < 256; c++) {
        uint8_t k = C_OTHER;
        if ((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z'))
            k = C_LETTER;
        else if (c == ' ' || c == '\t' || c == '\v' || c == '\f')
            k = C_SPACE;
        else if (c == ';')
            k = C_SEMI;
        else if (c == '*')
            k = C_STAR;
        else if (c == '\n')
            k = C_NL;
        LUT[c] = k;
    }
    lut_ready = 1;
}

/* The byte classes of the whole block (+ the pad newline at n), parens blanked. */
static void classify(const uint8_t *t, long n, uint8_t *cls)
{
    int in_paren = 0;
    if (!lut_ready)                                  /* (two threads may both fill it: the same bytes) */
        init_lut();
    for (long i = 0; i < n; i++) {
        uint8_t c = t[i], k = LUT[c];
        if (c == '\r')
            k = (i + 1 < n ? t[i + 1] : '\n') == '\n' ? C_SPACE : C_NL;
        if (k == C_NL) {
            in_paren = 0;
        } else if (c == '(') {
            in_paren = 1;
            k = C_SPACE;
        } else if (in_paren) {
            if (c == ')')
                in_paren = 0;
            k = C_SPACE;
        }
        cls[i] = k;
    }
    cls[n] = C_NL;
}

/* [+-]digits[.digits] of t[a:b] -> value (NaN unless W_OK) and status. */
static uint8_t parse_number(const uint8_t *t, long a, long b, double *value)
{
    *value = NAN;
    if (b <= a)
        return W_EMPTY;
    int neg = t[a] == '-';
    long s = a + (t[a] == '-' || t[a] == '+');
    long body = b - s;
    int ndot = 0, ndig = 0, frac = 0;
    uint64_t mant = 0;
    for (long i = s; i < b; i++) {
        uint8_t c = t[i];
        if (c == '.') {
            if (++ndot > 1)
                return W_BAD;
        } else if (c >= '0' && c <= '9') {
            ndig++;
            if (body <= MAX_DIGITS) {
                mant = mant * 10 + (uint64_t)(c - '0');
                frac += ndot;
            }
        } else {
            return W_BAD;
        }
    }
    if (ndig < 1)
        return W_BAD;
    if (body > MAX_DIGITS) {                     /* rare: very long numbers, read by strtod */
        char buf[512];
        if (b - a >= (long)sizeof buf)
            return W_BAD;
        memcpy(buf, t + a, (size_t)(b - a));
        buf[b - a] = 0;
        double v = strtod(buf, NULL);
        if (!isfinite(v))
            return W_BAD;
        *value = v;
        return W_OK;
    }
    double v = (double)mant / P10[frac];
    *value = neg ? -v : v;
    return W_OK;
}

static void add_line(int64_t *list, int64_t *count, int64_t line)
{
    if (*count == 0 || list[*count - 1] != line)      /* lines come in order: unique and sorted */
        list[(*count)++] = line;
}

/* Room the outputs need for t[0:n]: bounds[0] >= its lines (newlines, CRs, and one), bounds[1] >= its words
 * (letters). */
void gclex_bounds(const uint8_t *t, long n, int64_t *bounds)
{
    int64_t lines = 1, letters = 0;
    if (!lut_ready)
        init_lut();
    for (long i = 0; i < n; i++) {
        uint8_t c = t[i];
        lines += c == '\n' || c == '\r';
        letters += LUT[c] == C_LETTER;
    }
    bounds[0] = lines;
    bounds[1] = letters;
}

/* Lex t[0:n] (cls: n + 1 bytes of scratch; outputs with the room gclex_bounds gives). Returns 0. */
long gclex(const uint8_t *t, long n, uint8_t *cls, int64_t *line_start, int64_t *code_end, int64_t *word_line,
           uint8_t *word_letter, double *word_value, uint8_t *word_status, uint8_t *word_first,
           int64_t *orphan_lines, int64_t *checksum_bad_lines, int64_t *exponent_lines, int64_t *counts)
{
    classify(t, n, cls);
    int64_t lines = 0, words = 0, n_orphan = 0, n_bad = 0, n_exp = 0;
    long i = 0;
    int ends_nl = n > 0 && t[n - 1] == '\n';
    while (i <= n) {
        if (i == n && ends_nl)
            break;                                   /* the pad newline closes no line of its own */
        int64_t line = lines++;
        long start = i;
        long comment = -1;                           /* first ';' or '*' of the line */
        int64_t first_word = words;
        int line_has_word = 0;
        long p = i;
        line_start[line] = start;
        for (;;) {
            uint8_t k = cls[p];
            if (k == C_OTHER) {
                /* text after a blank or the line's start (a letter's own text is read with its word):
                 * an orphan unless within the comment */
                if (comment < 0)
                    add_line(orphan_lines, &n_orphan, line);
                while (cls[p] == C_OTHER)
                    p++;
                continue;
            }
            if (k == C_NL)
                break;
            if (k == C_SEMI || k == C_STAR) {
                if (comment < 0) {
                    comment = p;
                    if (k == C_STAR) {               /* a checksum: XOR of the bytes before it */
                        uint8_t x = 0;
                        for (long j = start; j < p; j++)
                            x ^= t[j];
                        long e = p + 1;
                        while (cls[e] == C_OTHER)
                            e++;
                        double want;
                        if (parse_number(t, p + 1, e, &want) != W_OK || want != (double)x)
                            add_line(checksum_bad_lines, &n_bad, line);
                    }
                }
                p++;
                continue;
            }
            if (k == C_SPACE || comment >= 0) {      /* blanks; letters within the comment are no words */
                p++;
                continue;
            }
            /* a word: the letter and its value bytes */
            long wpos = p, ws = p + 1, we = p + 1;
            while (cls[we] == C_OTHER)
                we++;
            long next = we;
            if (we == ws && cls[ws] == C_SPACE) {    /* "X 5": blanks, then value bytes */
                long j = ws;
                while (cls[j] == C_SPACE && cls[j + 1] == C_SPACE)
                    j++;
                if (cls[j] == C_SPACE && cls[j + 1] == C_OTHER) {
                    ws = j + 1;
                    we = ws;
                    while (cls[we] == C_OTHER)
                        we++;
                    next = we;
                }
            }
            uint8_t letter = t[wpos] & 0xDF;
            if (letter == 'E' && we > ws && wpos > 0) {
                uint8_t before = t[wpos - 1];
                if ((before >= '0' && before <= '9') || before == '.')
                    add_line(exponent_lines, &n_exp, line);
            }
            if (!(line_has_word == 0 && letter == 'N')) {   /* a leading N (line number) is no word */
                word_line[words] = line;
                word_letter[words] = letter;
                word_status[words] = parse_number(t, ws, we, &word_value[words]);
                word_first[words] = words == first_word;
                words++;
            }
            line_has_word = 1;
            p = next;
        }
        code_end[line] = comment >= 0 ? comment : p;
        i = p + 1;
    }
    counts[N_LINES] = lines;
    counts[N_WORDS] = words;
    counts[N_ORPHAN] = n_orphan;
    counts[N_BADSUM] = n_bad;
    counts[N_EXP] = n_exp;
    return 0;
}
