/* The scene hint's Gaussian (poisoner/scene.py `gaussian`) in C: the same float32 values as
 * scipy.ndimage.gaussian_filter and as scene.py's numpy version, bit for bit, at a fraction of the
 * numpy version's time (issue 30: the hint was a third of `ppd poison`'s CPU on 24 photos).
 *
 * Each axis in turn (axis 0 first), the borders mirrored ('reflect': d c b a | a b c d, repeated for a
 * line shorter than the kernel), every sum in double in scipy's own order (the centre tap times its
 * weight, then each symmetric pair, outermost first: (a + b) * weight added on), cast to float after each
 * axis. Built with -ffp-contract=off (setup.py): a fused multiply-add could round differently (rarely
 * visible after the cast to float, but nothing here relies on that). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdlib.h>
#include <string.h>

static Py_ssize_t reflect(Py_ssize_t i, Py_ssize_t n)
{
    while (i < 0 || i >= n)
        i = i < 0 ? -i - 1 : 2 * n - i - 1;
    return i;
}

/* Along axis 0: each output row from the rows around it (row-contiguous reads). */
static void along_rows(const float *in, float *out, Py_ssize_t h, Py_ssize_t w, const double *wt, int r,
                       double *acc)
{
    for (Py_ssize_t y = 0; y < h; y++) {
        const float *c = in + y * w;
        for (Py_ssize_t x = 0; x < w; x++)
            acc[x] = (double)c[x] * wt[r];
        for (int j = r; j > 0; j--) {
            const float *a = in + reflect(y - j, h) * w, *b = in + reflect(y + j, h) * w;
            const double k = wt[r - j];
            for (Py_ssize_t x = 0; x < w; x++)
                acc[x] += ((double)a[x] + (double)b[x]) * k;
        }
        float *o = out + y * w;
        for (Py_ssize_t x = 0; x < w; x++)
            o[x] = (float)acc[x];
    }
}

/* Along axis 1: each row on its own, through a copy with its mirrored borders. */
static void along_columns(const float *in, float *out, Py_ssize_t h, Py_ssize_t w, const double *wt, int r,
                          double *acc, double *pad)
{
    for (Py_ssize_t y = 0; y < h; y++) {
        const float *row = in + y * w;
        for (Py_ssize_t i = 0; i < w + 2 * r; i++)
            pad[i] = (double)row[reflect(i - r, w)];
        for (Py_ssize_t x = 0; x < w; x++)
            acc[x] = pad[x + r] * wt[r];
        for (int j = r; j > 0; j--) {
            const double k = wt[r - j];
            for (Py_ssize_t x = 0; x < w; x++)
                acc[x] += (pad[x + r - j] + pad[x + r + j]) * k;
        }
        float *o = out + y * w;
        for (Py_ssize_t x = 0; x < w; x++)
            o[x] = (float)acc[x];
    }
}

/* Whether a buffer's struct format is `fmt` in this machine's byte order. */
static int native(const char *format, const char *fmt)
{
    const char *f = format ? format : "B";
    if (f[0] == '@' || f[0] == '=' || f[0] == (PY_LITTLE_ENDIAN ? '<' : '>'))
        f++;
    return strcmp(f, fmt) == 0;
}

/* A C-contiguous buffer of n items of the struct format `fmt` ("f" float, "d" double). */
static int get_buffer(PyObject *obj, Py_buffer *view, int writable, const char *fmt, Py_ssize_t n,
                      const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    if (!native(view->format, fmt) || view->len != n * view->itemsize) {
        PyErr_Format(PyExc_ValueError, "gaussian: %s must hold %zd items of format '%s'", what, n, fmt);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* gaussian(src, dst, height, width, weights): src and dst C-contiguous float32 buffers of
 * height * width items, weights the kernel's 2r + 1 doubles (r < width and height need not hold:
 * the borders mirror as often as needed). */
static PyObject *py_gaussian(PyObject *self, PyObject *args)
{
    PyObject *src_obj, *dst_obj, *weights_obj;
    Py_ssize_t h, w;
    (void)self;
    if (!PyArg_ParseTuple(args, "OOnnO", &src_obj, &dst_obj, &h, &w, &weights_obj))
        return NULL;
    /* the sizes first: every product below stays far inside Py_ssize_t */
    if (h <= 0 || w <= 0 || w > PY_SSIZE_T_MAX / 16 / h) {
        PyErr_SetString(PyExc_ValueError, "gaussian: height and width must be positive and not huge");
        return NULL;
    }
    Py_buffer src, dst, weights;
    if (get_buffer(src_obj, &src, 0, "f", h * w, "src") < 0)
        return NULL;
    if (get_buffer(dst_obj, &dst, 1, "f", h * w, "dst") < 0) {
        PyBuffer_Release(&src);
        return NULL;
    }
    PyObject *result = NULL;
    float *mid = NULL;
    double *acc = NULL, *pad = NULL;
    if (PyObject_GetBuffer(weights_obj, &weights, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        PyBuffer_Release(&src);
        PyBuffer_Release(&dst);
        return NULL;
    }
    Py_ssize_t taps = weights.itemsize ? weights.len / weights.itemsize : 0;
    if (!native(weights.format, "d") || taps % 2 != 1 || taps > 4097) {
        PyErr_SetString(PyExc_ValueError, "gaussian: weights must be an odd number (at most 4097) of doubles");
        goto done;
    }
    int r = (int)(taps / 2);
    mid = malloc((size_t)(h * w) * sizeof(float));
    acc = malloc((size_t)w * sizeof(double));
    pad = malloc((size_t)(w + 2 * r) * sizeof(double));
    if (mid == NULL || acc == NULL || pad == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    along_rows((const float *)src.buf, mid, h, w, (const double *)weights.buf, r, acc);
    along_columns(mid, (float *)dst.buf, h, w, (const double *)weights.buf, r, acc, pad);
    Py_END_ALLOW_THREADS
    result = Py_NewRef(Py_None);
done:
    free(mid);
    free(acc);
    free(pad);
    PyBuffer_Release(&src);
    PyBuffer_Release(&dst);
    PyBuffer_Release(&weights);
    return result;
}

static PyMethodDef methods[] = {
    {"gaussian", py_gaussian, METH_VARARGS, "The scene hint's separable Gaussian, scipy's values."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, .m_name = "_scene_filter", .m_doc = NULL, .m_size = -1, .m_methods = methods,
};

PyMODINIT_FUNC PyInit__scene_filter(void) { return PyModule_Create(&module); }
