/* The entropy-coded data of a baseline (sequential, Huffman) JPEG, at the bit level: index it, decode
 * some MCUs, encode MCUs, and splice new MCUs into it while every other MCU's bits are copied as they
 * are (shifted), so a patch costs one Huffman decode of the picture and no re-encode of it.
 *
 * Why hand-written: libjpeg(-turbo) and Pillow offer the coefficients only as a whole-picture read and
 * write (jpegtran, tjTransform: one entropy decode and one entropy encode of every block), which costs
 * more than the codec floor that ppd's JPEG path is measured against (bench/results/batch.md). The
 * bit-level splice is what makes a patch cheaper than re-saving the photo.
 *
 * Scope: 8-bit baseline or extended sequential Huffman, one scan holding every component, no restart
 * markers. The Python side (poisoner/jpeg_scan.py) checks that and falls back to libjpeg-turbo for
 * anything else. Every read is bounds-checked: a malformed stream raises ValueError, never reads out
 * of its buffer (tests/poisoner/test_jpeg_scan.py fuzzes it in a child process).
 *
 * Buffers: the "clean" stream is the scan's bytes with byte stuffing (0xFF 0x00) removed, followed by
 * PAD bytes of 0xFF (unstuff() makes it), so a 64-bit load at any bit position below the end plus one
 * block's worth of bits stays inside it. Coefficients are int16, natural (not zigzag) order, 64 per
 * block, blocks in MCU order (component by component in scan order, each component's v x h blocks row
 * by row), as the scan codes them.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Big-endian words in memory: swapped on a little-endian machine. GCC and Clang builtins: where they
 * are missing the build leaves the module out (setup.py: optional), and ppd takes libjpeg-turbo. */
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
#define BE64(x) (x)
#else
#define BE64(x) __builtin_bswap64(x)
#endif

#define PAD 1024          /* > one block's bits (64 x 32) / 8, with room for the 8-byte load */
#define MAX_COMPS 4
#define MAX_BLOCKS 10     /* per MCU (JPEG's limit) */
#define SKIP_EOB 127      /* skip table's advance for end of block: takes k past any coefficient's */
#define SKIP_BITS 12      /* the skip table's index: the next 12 bits of the stream */

static const uint8_t NATURAL[64 + 16] = {
    0,  1,  8,  16, 9,  2,  3,  10, 17, 24, 32, 25, 18, 11, 4,  5,  12, 19, 26, 33, 40, 48,
    41, 34, 27, 20, 13, 6,  7,  14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23,
    30, 37, 44, 51, 58, 59, 52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63,
    63, 63, 63, 63, 63, 63, 63, 63, 63, 63, 63, 63, 63, 63, 63, 63}; /* overrun guard */

typedef struct {
    int present;
    uint16_t look[512];    /* 9-bit lookahead: (length << 8) | symbol; length 0: longer code */
    uint32_t skip[1 << SKIP_BITS]; /* skipping AC symbols, by the next SKIP_BITS bits: the first
                            * symbol's bits (code length + value bits) and advance (run + 1, 16 for ZRL,
                            * SKIP_EOB for end of block), and, where the second symbol's code also lies
                            * inside the index, both symbols' bits and advance added up (skip_entry);
                            * 0: a longer code (get_symbol) */
    int32_t maxcode[18];   /* largest code of each length, -1 when none */
    int32_t valoff[18];    /* index of a length's first value minus its first code */
    uint8_t vals[256];
    int nvals;
    uint16_t code[256];    /* encoding: code and length of each symbol (length 0: absent) */
    uint8_t size[256];
} Huff;

typedef struct {
    int ncomp;
    int h[MAX_COMPS], v[MAX_COMPS];
    Huff *dc[MAX_COMPS], *ac[MAX_COMPS];
    int bpm;                        /* blocks per MCU */
    int comp_of[MAX_BLOCKS];        /* component of each block of an MCU */
    int last_of[MAX_COMPS];         /* index in the MCU of each component's last block */
    Huff tables[8];                 /* DC 0-3, AC 0-3 */
} Coding;

/* A skip table entry: bits 0-4 both symbols' bits, 5-12 both advances, 13-17 the first symbol's bits,
 * 18-24 its advance, 25-29 its code length (a single symbol: both = the first). */
static inline uint32_t skip_entry(int code_len, int bits1, uint32_t adv1, int bits, uint32_t adv)
{
    return (uint32_t)bits | (adv << 5) | ((uint32_t)bits1 << 13) | (adv1 << 18) | ((uint32_t)code_len << 25);
}
#define SKIP_BOTH_BITS(e) ((int)((e) & 31))
#define SKIP_BOTH_ADV(e) ((int)(((e) >> 5) & 255))
#define SKIP_FIRST_BITS(e) ((int)(((e) >> 13) & 31))
#define SKIP_FIRST_ADV(e) ((int)(((e) >> 18) & 127))
#define SKIP_CODE_LEN(e) ((int)(((e) >> 25) & 31))

/* Where a symbol's code and value bits end inside the index and the next symbol's code fits in what
 * is left, the entry takes both: one look-up for two symbols. Never after an end of block (a block's
 * DC follows); whether the first symbol ends the block at coefficient 63 is the caller's to check. */
static void pair_up(Huff *t)
{
    const uint32_t mask = (1u << SKIP_BITS) - 1;
    for (uint32_t i = 0; i <= mask; i++) {
        uint32_t e = t->skip[i];
        int bits1 = SKIP_FIRST_BITS(e), adv1 = SKIP_FIRST_ADV(e);
        if (!e || adv1 == SKIP_EOB || bits1 >= SKIP_BITS) continue;
        uint32_t e2 = t->skip[(i << bits1) & mask];  /* the rest of the index, zeros after it */
        if (!e2 || SKIP_CODE_LEN(e2) > SKIP_BITS - bits1) continue;  /* its code runs past the index */
        t->skip[i] = skip_entry(SKIP_CODE_LEN(e), bits1, (uint32_t)adv1, bits1 + SKIP_FIRST_BITS(e2),
                                (uint32_t)(adv1 + SKIP_FIRST_ADV(e2)));
    }
}

/* ---- tables ---------------------------------------------------------------------------------- */
static int build_huff(Huff *t, const uint8_t *spec, Py_ssize_t len, int is_dc)
{
    /* spec: 16 counts, then the values (a DHT table without its class/id byte); refused as libjpeg
     * refuses a table (jpeg_make_d_derived_tbl): too many codes, a code overflow, a DC symbol > 15 */
    memset(t, 0, sizeof(*t));
    if (len < 16) return -1;
    int total = 0;
    for (int i = 0; i < 16; i++) total += spec[i];
    if (total > 256 || len != 16 + total) return -1;
    if (is_dc)
        for (int i = 0; i < total; i++)
            if (spec[16 + i] > 15) return -1;
    memcpy(t->vals, spec + 16, total);
    t->nvals = total;
    int32_t code = 0;
    int k = 0;
    for (int l = 1; l <= 16; l++) {
        int n = spec[l - 1];
        /* checked before the codes are written (the lookahead holds 512 entries): a length may not
         * take more codes than it has, and the all-ones code is reserved (as libjpeg checks) */
        if (n && code + n >= (1 << l)) return -1;
        t->valoff[l] = k - code;
        for (int i = 0; i < n; i++, k++, code++) {
            int sym = t->vals[k];
            if (l <= 9) {
                int shift = 9 - l;
                for (int j = 0; j < (1 << shift); j++)
                    t->look[(code << shift) + j] = (uint16_t)((l << 8) | sym);
            }
            if (!is_dc && l <= SKIP_BITS) {
                int shift = SKIP_BITS - l;
                int size = sym & 15, run = sym >> 4;
                uint32_t advance = size ? run + 1 : (run == 15 ? 16 : SKIP_EOB);
                for (int j = 0; j < (1 << shift); j++)
                    t->skip[(code << shift) + j] = skip_entry(l, l + size, advance, l + size, advance);
            }
            if (t->size[sym] == 0) {
                t->code[sym] = (uint16_t)code;
                t->size[sym] = (uint8_t)l;
            }
        }
        t->maxcode[l] = n ? code - 1 : -1;
        code <<= 1;
    }
    if (!is_dc) pair_up(t);
    t->maxcode[17] = INT32_MAX;
    t->present = 1;
    return 0;
}

/* coding: a tuple of (h, v, dc_table, ac_table) per component in scan order; tables: a tuple of 8
 * (DC 0-3, AC 0-3), each bytes (16 counts + values) or None. */
static int parse_coding(Coding *c, PyObject *comps, PyObject *tables)
{
    memset(c, 0, sizeof(*c));
    if (!PyTuple_Check(tables) || PyTuple_GET_SIZE(tables) != 8 || !PyTuple_Check(comps)) {
        PyErr_SetString(PyExc_TypeError, "coding: comps tuple and 8 tables expected");
        return -1;
    }
    for (int i = 0; i < 8; i++) {
        PyObject *t = PyTuple_GET_ITEM(tables, i);
        if (t == Py_None) continue;
        char *buf;
        Py_ssize_t len;
        if (PyBytes_AsStringAndSize(t, &buf, &len) < 0) return -1;
        if (build_huff(&c->tables[i], (const uint8_t *)buf, len, i < 4) < 0) {
            PyErr_SetString(PyExc_ValueError, "bad Huffman table");
            return -1;
        }
    }
    Py_ssize_t n = PyTuple_GET_SIZE(comps);
    if (n < 1 || n > MAX_COMPS) {
        PyErr_SetString(PyExc_ValueError, "1 to 4 components expected");
        return -1;
    }
    c->ncomp = (int)n;
    int b = 0;
    for (int i = 0; i < n; i++) {
        int h, v, td, ta;
        if (!PyArg_ParseTuple(PyTuple_GET_ITEM(comps, i), "iiii", &h, &v, &td, &ta)) return -1;
        if (h < 1 || h > 4 || v < 1 || v > 4 || td < 0 || td > 3 || ta < 0 || ta > 3 || b + h * v > MAX_BLOCKS ||
            !c->tables[td].present || !c->tables[4 + ta].present) {
            PyErr_SetString(PyExc_ValueError, "bad component coding (sampling or missing table)");
            return -1;
        }
        c->h[i] = h;
        c->v[i] = v;
        c->dc[i] = &c->tables[td];
        c->ac[i] = &c->tables[4 + ta];
        for (int j = 0; j < h * v; j++) c->comp_of[b++] = i;
        c->last_of[i] = b - 1;
    }
    c->bpm = b;
    return 0;
}

/* ---- bits in ---------------------------------------------------------------------------------- */
/* A 64-bit accumulator, most significant bit first, refilled without branches (8-byte loads; the
 * stream's padding keeps them inside the buffer). */
typedef struct {
    const uint8_t *buf;
    const uint8_t *p;  /* next byte to load */
    uint64_t acc;      /* n valid bits at the top */
    int n;
    uint64_t nbits;    /* bits of real data (before the padding) */
} Reader;

static inline uint64_t load_be64(const uint8_t *p)
{
    uint64_t v;
    memcpy(&v, p, 8);
    return BE64(v);
}

static inline void fill(Reader *r)
{
    r->acc |= load_be64(r->p) >> r->n;
    r->p += (63 - r->n) >> 3;
    r->n |= 56;
}

static inline uint64_t reader_pos(const Reader *r) { return (uint64_t)(r->p - r->buf) * 8 - (uint64_t)r->n; }

static inline void consume(Reader *r, int k)
{
    r->acc <<= k;
    r->n -= k;
}

static inline void seek(Reader *r, uint64_t pos)
{
    r->p = r->buf + (pos >> 3);
    r->acc = 0;
    r->n = 0;
    fill(r);
    consume(r, (int)(pos & 7));
}

/* The next symbol (the accumulator holds >= 16 bits), or -1 for a code not in the table. */
static inline int get_symbol(Reader *r, const Huff *t)
{
    unsigned e = t->look[r->acc >> 55];
    if (e >> 8) {
        consume(r, (int)(e >> 8));
        return e & 0xFF;
    }
    for (int l = 10; l <= 16; l++) {
        int32_t code = (int32_t)(r->acc >> (64 - l));
        if (code <= t->maxcode[l]) {
            int idx = t->valoff[l] + code;
            if (idx < 0 || idx >= t->nvals) return -1;
            consume(r, l);
            return t->vals[idx];
        }
    }
    return -1;
}

static inline int32_t get_value(Reader *r, int s)
{
    /* s (1..16) bits as a JPEG magnitude category value */
    uint32_t bits = (uint32_t)(r->acc >> (64 - s));
    consume(r, s);
    if (bits < (1u << (s - 1))) return (int32_t)bits - (int32_t)((1u << s) - 1);
    return (int32_t)bits;
}

/* One block: returns 0, or -1 on a bad code or a stream that ends inside it. dc_diff gets the DC
 * difference; coef (natural order) gets the AC values when not NULL (its DC is left to the caller). */
static int decode_block(Reader *r, const Huff *dc, const Huff *ac, int32_t *dc_diff, int16_t *coef)
{
    fill(r);
    int s = get_symbol(r, dc);
    if (s < 0 || s > 15) return -1;
    *dc_diff = s ? get_value(r, s) : 0;
    for (int k = 1; k < 64; k++) {
        fill(r);
        int rs = get_symbol(r, ac);
        if (rs < 0) return -1;
        int run = rs >> 4, size = rs & 15;
        if (size) {
            k += run;
            if (k > 63) return -1;
            if (coef)
                coef[NATURAL[k]] = (int16_t)get_value(r, size);
            else
                consume(r, size);
        } else {
            if (run != 15) break;
            k += 15;
        }
    }
    if (reader_pos(r) > r->nbits) return -1;  /* ran past the data: truncated */
    return 0;
}

/* One block skipped (index): only its DC difference is kept. Two AC symbols with their values take
 * one table look-up and one shift where both codes lie in the next SKIP_BITS bits (a 12 MP q92 file
 * indexed in a third less time than with one symbol a look-up: bench/results/batch.md round 12), one
 * symbol otherwise; the pair is taken only when the block goes on after its first symbol (else the
 * second is the next block's DC). The accumulator is refilled only when fewer than 32 bits are left.
 * Accepts what decode_block accepts, except a zero run (ZRL) past the block's end, which decode_block
 * (like libjpeg) reads and this refuses: the index runs first, so a file it accepts is one decode_block
 * reads the same way. */
static inline int skip_block(Reader *r, const Huff *dc, const Huff *ac, int32_t *dc_diff)
{
    fill(r);
    int s = get_symbol(r, dc);
    if (s < 0 || s > 15) return -1;
    *dc_diff = s ? get_value(r, s) : 0;
    int k = 1;
    while (k < 64) {
        if (r->n < 32) fill(r);
        uint32_t e = ac->skip[r->acc >> (64 - SKIP_BITS)];
        if (e) {
            if (k + SKIP_FIRST_ADV(e) < 64) {  /* the block goes on after the first: the pair holds */
                consume(r, SKIP_BOTH_BITS(e));
                k += SKIP_BOTH_ADV(e);
            } else {
                consume(r, SKIP_FIRST_BITS(e));
                k += SKIP_FIRST_ADV(e);
            }
        } else {
            int rs = get_symbol(r, ac);
            if (rs < 0) return -1;
            consume(r, rs & 15);
            k += (rs & 15) ? (rs >> 4) + 1 : ((rs >> 4) == 15 ? 16 : SKIP_EOB);
        }
    }
    /* k is 64 after a coefficient at 63, >= SKIP_EOB + 1 after an end of block; between, a run
     * (or a ZRL) went past the block's last coefficient */
    if (k > 64 && k <= 63 + 16) return -1;
    if (reader_pos(r) > r->nbits) return -1;
    return 0;
}

/* ---- bits out --------------------------------------------------------------------------------- */
typedef struct {
    uint8_t *buf;
    size_t len, cap;  /* bytes written; room (kept >= len + 8 by reserve) */
    uint64_t acc;     /* n pending bits at the top */
    int n;
} Writer;

static int writer_init(Writer *w, size_t cap)
{
    memset(w, 0, sizeof(*w));
    w->cap = cap + 64;
    w->buf = malloc(w->cap);
    return w->buf ? 0 : -1;
}

/* Room for `more` bytes and the 8-byte stores; -1 when out of memory. */
static int reserve(Writer *w, size_t more)
{
    if (w->len + more + 16 <= w->cap) return 0;
    size_t cap = (w->len + more + 16) * 2;
    uint8_t *b = realloc(w->buf, cap);
    if (!b) return -1;
    w->buf = b;
    w->cap = cap;
    return 0;
}

static inline void put_bits(Writer *w, uint64_t bits, int k)
{
    /* 1 <= k <= 32; bits holds k valid low bits (higher bits zero); n < 32 before */
    w->acc |= bits << (64 - k - w->n);
    w->n += k;
    if (w->n >= 32) {
        uint64_t v = BE64(w->acc);
        memcpy(w->buf + w->len, &v, 8);
        int bytes = w->n >> 3;
        w->len += (size_t)bytes;
        w->acc <<= bytes * 8;
        w->n -= bytes * 8;
    }
}

static int writer_finish(Writer *w)
{
    /* pad the last byte with one-bits (as libjpeg does), flush */
    if (reserve(w, 16) < 0) return -1;
    if (w->n & 7) put_bits(w, (1u << (8 - (w->n & 7))) - 1, 8 - (w->n & 7));
    while (w->n >= 8) {
        w->buf[w->len++] = (uint8_t)(w->acc >> 56);
        w->acc <<= 8;
        w->n -= 8;
    }
    return 0;
}

static inline int nbits_of(int32_t x)
{
    uint32_t a = (uint32_t)(x < 0 ? -x : x);
    return a ? 32 - __builtin_clz(a) : 0;
}

static inline uint64_t low_bits(int32_t v, int s) { return (uint64_t)((uint32_t)v & ((1u << s) - 1)); }

#define BLOCK_BYTES 256 /* the most one block can take: (16 + 11) + 63 x (16 + 10) bits */

/* One block from coef (natural order) with the DC predictor *pred (updated). 0, -1 when a value is
 * out of range, -2 when the table lacks a symbol the block needs, -3 when out of memory. */
static int encode_block(Writer *w, const Huff *dc, const Huff *ac, const int16_t *coef, int32_t *pred)
{
    if (reserve(w, BLOCK_BYTES) < 0) return -3;
    int32_t diff = coef[0] - *pred;
    *pred = coef[0];
    int s = nbits_of(diff);
    if (s > 11) return -1;
    if (!dc->size[s]) return -2;
    put_bits(w, dc->code[s], dc->size[s]);
    if (s) put_bits(w, low_bits(diff < 0 ? diff - 1 : diff, s), s);
    int run = 0;
    for (int k = 1; k < 64; k++) {
        int32_t v = coef[NATURAL[k]];
        if (!v) {
            run++;
            continue;
        }
        while (run > 15) {
            if (!ac->size[0xF0]) return -2;
            put_bits(w, ac->code[0xF0], ac->size[0xF0]);
            run -= 16;
        }
        s = nbits_of(v);
        if (s > 10) return -1;
        int sym = (run << 4) | s;
        if (!ac->size[sym]) return -2;
        put_bits(w, ac->code[sym], ac->size[sym]);
        put_bits(w, low_bits(v < 0 ? v - 1 : v, s), s);
        run = 0;
    }
    if (run) {
        if (!ac->size[0]) return -2;
        put_bits(w, ac->code[0], ac->size[0]);
    }
    return 0;
}

/* n bits from the reader's position to the writer, as they are: bit by bit up to the writer's next
 * byte boundary, then whole bytes as the source's bytes shifted by a constant (8 at a time), then
 * the rest. */
static int copy_bits(Writer *w, Reader *r, uint64_t n)
{
    if (reserve(w, (size_t)(n >> 3) + 16) < 0) return -3;
    int lead = (8 - (w->n & 7)) & 7;
    if ((uint64_t)lead > n) lead = (int)n;
    if (lead) {
        fill(r);
        put_bits(w, r->acc >> (64 - lead), lead);
        consume(r, lead);
        n -= (uint64_t)lead;
    }
    while (w->n >= 8) {  /* flush: the writer now ends on a byte boundary */
        w->buf[w->len++] = (uint8_t)(w->acc >> 56);
        w->acc <<= 8;
        w->n -= 8;
    }
    uint64_t pos = reader_pos(r), bytes = n >> 3;
    if (w->n == 0 && bytes) {
        const uint8_t *src = r->buf + (pos >> 3);
        uint8_t *dst = w->buf + w->len;
        int sh = (int)(pos & 7);
        if (!sh) {
            memcpy(dst, src, (size_t)bytes);
        } else {
            uint64_t i = 0;
            for (; i + 8 <= bytes; i += 8) {
                uint64_t v = (load_be64(src + i) << sh) | (uint64_t)(src[i + 8] >> (8 - sh));
                v = BE64(v);
                memcpy(dst + i, &v, 8);
            }
            for (; i < bytes; i++) dst[i] = (uint8_t)((src[i] << sh) | (src[i + 1] >> (8 - sh)));
        }
        w->len += (size_t)bytes;
        seek(r, pos + bytes * 8);
        n -= bytes * 8;
    }
    while (n) {
        int k = n > 32 ? 32 : (int)n;
        fill(r);
        put_bits(w, r->acc >> (64 - k), k);
        consume(r, k);
        n -= (uint64_t)k;
    }
    return 0;
}

/* The writer's bytes with 0x00 stuffed after each 0xFF, as a new bytes object. */
static PyObject *stuffed(const Writer *w)
{
    size_t ff = 0;
    const uint8_t *b = w->buf, *end = w->buf + w->len;
    for (const uint8_t *q = b; (q = memchr(q, 0xFF, (size_t)(end - q))) != NULL; q++) ff++;
    PyObject *out = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(w->len + ff));
    if (!out) return NULL;
    uint8_t *o = (uint8_t *)PyBytes_AS_STRING(out);
    const uint8_t *q = b;
    while (q < end) {
        const uint8_t *f = memchr(q, 0xFF, (size_t)(end - q));
        const uint8_t *stop = f ? f + 1 : end;
        memcpy(o, q, (size_t)(stop - q));
        o += stop - q;
        if (f) *o++ = 0;
        q = stop;
    }
    return out;
}

/* ---- Python API ------------------------------------------------------------------------------- */
static int check_buffer(Py_buffer *b, Py_ssize_t need, const char *what)
{
    if (b->len < need) {
        PyErr_Format(PyExc_ValueError, "%s: buffer of %zd bytes, %zd needed", what, b->len, need);
        return -1;
    }
    return 0;
}

static int reader_from(Reader *r, Py_buffer *clean, Py_ssize_t nbytes)
{
    if (nbytes < 0 || clean->len < nbytes + PAD) {
        PyErr_SetString(PyExc_ValueError, "clean stream lacks its padding");
        return -1;
    }
    r->buf = clean->buf;
    r->nbits = (uint64_t)nbytes * 8;
    seek(r, 0);
    return 0;
}

PyDoc_STRVAR(unstuff_doc,
             "unstuff(data, start) -> (clean, nbytes, end): the entropy-coded bytes from data[start] to the\n"
             "next marker, stuffing removed, followed by padding; nbytes: their count; end: the marker's\n"
             "position in data. A restart marker raises ValueError (not handled here).");

static PyObject *py_unstuff(PyObject *self, PyObject *args)
{
    Py_buffer data;
    Py_ssize_t start;
    if (!PyArg_ParseTuple(args, "y*n", &data, &start)) return NULL;
    const uint8_t *d = data.buf;
    Py_ssize_t n = data.len;
    if (start < 0 || start > n) {
        PyBuffer_Release(&data);
        PyErr_SetString(PyExc_ValueError, "scan start outside the data");
        return NULL;
    }
    PyObject *clean = PyBytes_FromStringAndSize(NULL, n - start + PAD);
    if (!clean) {
        PyBuffer_Release(&data);
        return NULL;
    }
    uint8_t *o = (uint8_t *)PyBytes_AS_STRING(clean);
    Py_ssize_t k = 0, i = start, end = -1;
    while (i < n) {
        const uint8_t *ff = memchr(d + i, 0xFF, (size_t)(n - i));
        Py_ssize_t stop = ff ? ff - d : n;
        memcpy(o + k, d + i, (size_t)(stop - i));
        k += stop - i;
        i = stop;
        if (i >= n) break;
        if (i + 1 >= n) break;  /* a lone 0xFF at the end: truncated */
        uint8_t m = d[i + 1];
        if (m == 0x00) {
            o[k++] = 0xFF;
            i += 2;
        } else if (m == 0xFF) {
            i += 1;  /* fill byte before a marker */
        } else if (m >= 0xD0 && m <= 0xD7) {
            Py_DECREF(clean);
            PyBuffer_Release(&data);
            PyErr_SetString(PyExc_ValueError, "restart marker in the scan");
            return NULL;
        } else {
            end = i;
            break;
        }
    }
    PyBuffer_Release(&data);
    if (end < 0) {
        Py_DECREF(clean);
        PyErr_SetString(PyExc_ValueError, "scan has no end marker (truncated)");
        return NULL;
    }
    memset(o + k, 0xFF, PAD);
    if (_PyBytes_Resize(&clean, k + PAD) < 0) return NULL;
    return Py_BuildValue("(Nnn)", clean, k, end);
}

PyDoc_STRVAR(index_doc,
             "index(clean, nbytes, comps, tables, n_mcus, offsets, dc) -> bits used: decodes every MCU; writes\n"
             "each MCU's start bit (offsets, int64, n_mcus + 1 with the end) and each block's DC value (dc,\n"
             "int16, n_mcus x blocks per MCU). ValueError on a bad or truncated stream.");

static PyObject *py_index(PyObject *self, PyObject *args)
{
    Py_buffer clean, offsets, dcs;
    Py_ssize_t nbytes, n_mcus;
    PyObject *comps, *tables;
    if (!PyArg_ParseTuple(args, "y*nOOnw*w*", &clean, &nbytes, &comps, &tables, &n_mcus, &offsets, &dcs))
        return NULL;
    PyObject *result = NULL;
    Coding *c = malloc(sizeof(Coding));
    Reader r;
    if (!c) {
        PyErr_NoMemory();
        goto done;
    }
    if (parse_coding(c, comps, tables) < 0 || reader_from(&r, &clean, nbytes) < 0) goto done;
    if (n_mcus < 1 || check_buffer(&offsets, (n_mcus + 1) * 8, "offsets") < 0 ||
        check_buffer(&dcs, n_mcus * c->bpm * 2, "dc") < 0)
        goto done;
    int64_t *off = offsets.buf;
    int16_t *dc = dcs.buf;
    int32_t pred[MAX_COMPS] = {0};
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t m = 0; m < n_mcus && !bad; m++) {
        off[m] = (int64_t)reader_pos(&r);
        for (int b = 0; b < c->bpm; b++) {
            int ci = c->comp_of[b];
            int32_t diff;
            if (skip_block(&r, c->dc[ci], c->ac[ci], &diff) < 0) {
                bad = 1;
                break;
            }
            int32_t v = pred[ci] + diff;
            if (v < -32768 || v > 32767) {
                bad = 1;
                break;
            }
            pred[ci] = v;
            dc[m * c->bpm + b] = (int16_t)v;
        }
    }
    off[n_mcus] = (int64_t)reader_pos(&r);
    Py_END_ALLOW_THREADS
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "corrupt or truncated entropy-coded data");
        goto done;
    }
    result = PyLong_FromUnsignedLongLong(reader_pos(&r));
done:
    free(c);
    PyBuffer_Release(&clean);
    PyBuffer_Release(&offsets);
    PyBuffer_Release(&dcs);
    return result;
}

/* Check an offsets array (from index) before seeking into the stream with it. */
static int check_offsets(const int64_t *off, Py_ssize_t n_mcus, uint64_t nbits)
{
    for (Py_ssize_t m = 0; m < n_mcus; m++)
        if (off[m] < 0 || off[m + 1] < off[m] || (uint64_t)off[m + 1] > nbits) return -1;
    return 0;
}

/* What decode and splice share: the coding, a reader on the clean stream, and the index (offsets,
 * dc), the MCU numbers (in the picture; increasing for a splice) and the coefficient buffer (one MCU's
 * blocks per number) checked against each other and the stream. NULL, an exception set, when
 * something does not fit. */
static Coding *open_indexed(PyObject *comps, PyObject *tables, Py_buffer *clean, Py_ssize_t nbytes,
                            Py_buffer *offsets, Py_buffer *dcs, Py_buffer *mcus, Py_buffer *coefs, int increasing,
                            Reader *r)
{
    Coding *c = malloc(sizeof(Coding));
    if (!c) {
        PyErr_NoMemory();
        return NULL;
    }
    if (parse_coding(c, comps, tables) < 0 || reader_from(r, clean, nbytes) < 0) goto fail;
    Py_ssize_t n_mcus = offsets->len / 8 - 1, count = mcus->len / 8;
    if (n_mcus < 1 || check_buffer(dcs, n_mcus * c->bpm * 2, "dc") < 0 ||
        check_buffer(coefs, count * c->bpm * 128, "coef") < 0)
        goto fail;
    const int64_t *off = offsets->buf, *which = mcus->buf;
    if (check_offsets(off, n_mcus, r->nbits) < 0) {
        PyErr_SetString(PyExc_ValueError, "offsets do not fit the stream");
        goto fail;
    }
    for (Py_ssize_t i = 0; i < count; i++)
        if (which[i] < 0 || which[i] >= n_mcus || (increasing && i && which[i] <= which[i - 1])) {
            PyErr_SetString(PyExc_ValueError, "MCU numbers must lie in the picture (and increase, to splice)");
            goto fail;
        }
    return c;
fail:
    free(c);
    return NULL;
}

PyDoc_STRVAR(decode_doc,
             "decode(clean, nbytes, comps, tables, offsets, dc, mcus, out): the coefficients of the MCUs\n"
             "whose indices are in mcus (int64), into out (int16, len(mcus) x blocks per MCU x 64, natural\n"
             "order; zeroed first); offsets and dc as index wrote them.");

static PyObject *py_decode(PyObject *self, PyObject *args)
{
    Py_buffer clean, offsets, dcs, mcus, out;
    Py_ssize_t nbytes;
    PyObject *comps, *tables;
    if (!PyArg_ParseTuple(args, "y*nOOy*y*y*w*", &clean, &nbytes, &comps, &tables, &offsets, &dcs, &mcus, &out))
        return NULL;
    PyObject *result = NULL;
    Reader r;
    Coding *c = open_indexed(comps, tables, &clean, nbytes, &offsets, &dcs, &mcus, &out, 0, &r);
    if (!c) goto done;
    const int64_t *off = offsets.buf, *which = mcus.buf;
    const int16_t *dc = dcs.buf;
    int16_t *coef = out.buf;
    Py_ssize_t count = mcus.len / 8;
    memset(coef, 0, (size_t)(count * c->bpm * 128));
    int bad = 0;
    for (Py_ssize_t i = 0; i < count && !bad; i++) {
        int64_t m = which[i];
        seek(&r, (uint64_t)off[m]);
        for (int b = 0; b < c->bpm; b++) {
            int ci = c->comp_of[b];
            int32_t diff;
            int16_t *blk = coef + (i * c->bpm + b) * 64;
            if (decode_block(&r, c->dc[ci], c->ac[ci], &diff, blk) < 0) {
                bad = 1;
                break;
            }
            blk[0] = dc[m * c->bpm + b];
        }
    }
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "cannot decode those MCUs");
        goto done;
    }
    result = Py_NewRef(Py_None);
done:
    free(c);
    PyBuffer_Release(&clean);
    PyBuffer_Release(&offsets);
    PyBuffer_Release(&dcs);
    PyBuffer_Release(&mcus);
    PyBuffer_Release(&out);
    return result;
}

static PyObject *encode_error(int rc)
{
    if (rc == -2)
        PyErr_SetString(PyExc_LookupError, "the Huffman tables lack a symbol these coefficients need");
    else if (rc == -3)
        PyErr_NoMemory();
    else
        PyErr_SetString(PyExc_ValueError, "coefficient out of range for baseline JPEG");
    return NULL;
}

PyDoc_STRVAR(encode_doc,
             "encode(coef, comps, tables) -> bytes: MCUs (int16, natural order, MCU order) coded as a whole\n"
             "scan (predictors from 0), padded with one-bits and stuffed. LookupError when a table lacks a\n"
             "symbol, ValueError when a value is out of range.");

static PyObject *py_encode(PyObject *self, PyObject *args)
{
    Py_buffer coefs;
    PyObject *comps, *tables;
    if (!PyArg_ParseTuple(args, "y*OO", &coefs, &comps, &tables)) return NULL;
    PyObject *result = NULL;
    Coding *c = malloc(sizeof(Coding));
    Writer w = {0};
    if (!c) {
        PyErr_NoMemory();
        goto done;
    }
    if (parse_coding(c, comps, tables) < 0) goto done;
    Py_ssize_t count = coefs.len / (c->bpm * 128);
    if (count * c->bpm * 128 != coefs.len) {
        PyErr_SetString(PyExc_ValueError, "coefficients are not whole MCUs");
        goto done;
    }
    if (writer_init(&w, (size_t)coefs.len / 4) < 0) {
        PyErr_NoMemory();
        goto done;
    }
    const int16_t *coef = coefs.buf;
    int32_t pred[MAX_COMPS] = {0};
    int rc = 0;
    for (Py_ssize_t m = 0; m < count && !rc; m++)
        for (int b = 0; b < c->bpm && !rc; b++) {
            int ci = c->comp_of[b];
            rc = encode_block(&w, c->dc[ci], c->ac[ci], coef + (m * c->bpm + b) * 64, &pred[ci]);
        }
    if (!rc && writer_finish(&w) < 0) rc = -3;
    if (rc) {
        encode_error(rc);
        goto done;
    }
    result = stuffed(&w);
done:
    free(c);
    free(w.buf);
    PyBuffer_Release(&coefs);
    return result;
}

PyDoc_STRVAR(splice_doc,
             "splice(clean, nbytes, comps, tables, offsets, dc, mcus, coef) -> bytes: the scan with the MCUs\n"
             "whose indices are in mcus (int64, increasing) replaced by coef (int16, natural order, one MCU\n"
             "after another), coded with the same tables; every other MCU's bits copied as they are, except\n"
             "the one after each replaced run, re-coded for its changed DC predictor. Padded and stuffed.\n"
             "LookupError when a table lacks a symbol the new blocks need.");

static PyObject *py_splice(PyObject *self, PyObject *args)
{
    Py_buffer clean, offsets, dcs, mcus, coefs;
    Py_ssize_t nbytes;
    PyObject *comps, *tables;
    if (!PyArg_ParseTuple(args, "y*nOOy*y*y*y*", &clean, &nbytes, &comps, &tables, &offsets, &dcs, &mcus, &coefs))
        return NULL;
    PyObject *result = NULL;
    Writer w = {0};
    Reader r;
    Coding *c = open_indexed(comps, tables, &clean, nbytes, &offsets, &dcs, &mcus, &coefs, 1, &r);
    if (!c) goto done;
    Py_ssize_t n_mcus = offsets.len / 8 - 1, count = mcus.len / 8;
    const int64_t *off = offsets.buf, *which = mcus.buf;
    const int16_t *dc = dcs.buf, *coef = coefs.buf;
    if (writer_init(&w, (size_t)nbytes + 4096) < 0) {
        PyErr_NoMemory();
        goto done;
    }
    int32_t pred[MAX_COMPS] = {0};
    int16_t blocks[MAX_BLOCKS * 64];
    int rc = 0, shifted = 0;
    Py_ssize_t m = 0, i = 0;
    while (m < n_mcus && !rc) {
        if (i < count && which[i] == m) {  /* a new MCU */
            for (int b = 0; b < c->bpm && !rc; b++) {
                int ci = c->comp_of[b];
                rc = encode_block(&w, c->dc[ci], c->ac[ci], coef + (i * c->bpm + b) * 64, &pred[ci]);
            }
            shifted = 1;
            i++;
            m++;
            continue;
        }
        if (shifted) {  /* the source's MCU, its DC differences taken from the new predictors */
            memset(blocks, 0, sizeof(blocks));
            seek(&r, (uint64_t)off[m]);
            for (int b = 0; b < c->bpm && !rc; b++) {
                int ci = c->comp_of[b];
                int32_t diff;
                if (decode_block(&r, c->dc[ci], c->ac[ci], &diff, blocks + b * 64) < 0) {
                    rc = -4;
                    break;
                }
                blocks[b * 64] = dc[m * c->bpm + b];
                rc = encode_block(&w, c->dc[ci], c->ac[ci], blocks + b * 64, &pred[ci]);
            }
            shifted = 0;
            m++;
            continue;
        }
        Py_ssize_t next = i < count ? which[i] : n_mcus;  /* copy the run up to the next new MCU */
        seek(&r, (uint64_t)off[m]);
        rc = copy_bits(&w, &r, (uint64_t)(off[next] - off[m]));
        for (int ci = 0; ci < c->ncomp; ci++) pred[ci] = dc[(next - 1) * c->bpm + c->last_of[ci]];
        m = next;
    }
    if (!rc && writer_finish(&w) < 0) rc = -3;
    if (rc == -4) {
        PyErr_SetString(PyExc_ValueError, "cannot decode the source's MCU");
        goto done;
    }
    if (rc) {
        encode_error(rc);
        goto done;
    }
    result = stuffed(&w);
done:
    free(c);
    free(w.buf);
    PyBuffer_Release(&clean);
    PyBuffer_Release(&offsets);
    PyBuffer_Release(&dcs);
    PyBuffer_Release(&mcus);
    PyBuffer_Release(&coefs);
    return result;
}

PyDoc_STRVAR(next_marker_doc,
             "next_marker(data, start) -> int: the position of the first marker at or after start in\n"
             "entropy-coded data (0xFF followed by a byte other than 0x00, 0xFF or a restart marker's),\n"
             "or -1; what poisoner.completeness's regular expression finds, at memchr's speed.");

static PyObject *py_next_marker(PyObject *self, PyObject *args)
{
    Py_buffer data;
    Py_ssize_t start, found = -1;
    if (!PyArg_ParseTuple(args, "y*n", &data, &start)) return NULL;
    const uint8_t *d = data.buf;
    Py_ssize_t n = data.len, i = start < 0 ? 0 : start;
    while (i + 1 < n) {
        const uint8_t *ff = memchr(d + i, 0xFF, (size_t)(n - 1 - i));
        if (!ff) break;
        i = ff - d;
        uint8_t m = d[i + 1];
        if (m != 0x00 && m != 0xFF && !(m >= 0xD0 && m <= 0xD7)) {
            found = i;
            break;
        }
        i += 1;
    }
    PyBuffer_Release(&data);
    return PyLong_FromSsize_t(found);
}

static PyMethodDef methods[] = {
    {"next_marker", py_next_marker, METH_VARARGS, next_marker_doc},
    {"unstuff", py_unstuff, METH_VARARGS, unstuff_doc},
    {"index", py_index, METH_VARARGS, index_doc},
    {"decode", py_decode, METH_VARARGS, decode_doc},
    {"encode", py_encode, METH_VARARGS, encode_doc},
    {"splice", py_splice, METH_VARARGS, splice_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_jpeg_entropy",
                                    "Bit-level access to a baseline JPEG's entropy-coded data.", -1, methods};

PyMODINIT_FUNC PyInit__jpeg_entropy(void) { return PyModule_Create(&module); }
