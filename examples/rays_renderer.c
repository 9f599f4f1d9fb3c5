/* A worked example of an external renderer in C: camval's request protocol, "rays" mode.

     cc -O2 -o rays_renderer examples/rays_renderer.c -lm
     ./rays_renderer REQUEST.json        one-shot: answer one request, exit
     ./rays_renderer                     persistent: one JSON line {"request": PATH} per
                                         request on stdin, one answer line on stdout

   camval writes, per request, the camera-frame ray of every sample
   (rays-directions.npy, float32 (N,3); rays-origins.npy float32 (N,3) for a noncentral
   camera, else request "origin" = [0,0,0]) and scene.json (the board and Rt_cam_board).
   This program intersects each ray with the board plane z = 0 (board frame), looks up the
   albedo there (targets.pattern.Pattern: board rectangle, cells, circles, painted in that
   order) and writes one float32 per ray to values.npy. camval averages the samples of
   each pixel. No camera model is needed: camval did the unprojection.

   Terrain requests (scene kind "terrain", protocol version 3): it reads the height field
   (terrain-heights.npy, float64) and texture (float32), walks each ray over the grid's
   cells in order (2-D DDA, skipping cells it passes above), intersects the two triangles
   of each cell (targets/terrain.py's surface), shades the nearest hit as
   renderers/raycast_terrain.py does (Lambertian, a shadow ray towards the sun, bilinear
   albedo) and writes values.npy plus the optional range.npy and shadow.npy the request
   names (so the shadow check runs on it too).

   It parses only the JSON it needs (no library): keys are looked up by their quoted name.
   Exit status: 0 done, 10 not applicable (a request mode other than "rays"), 1 failure;
   the reason goes to stderr. Tested by tests/test_command_modes.py. */

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define EXIT_NOT_APPLICABLE 10

static char reason[10240];

static char *read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(reason, sizeof reason, "cannot open '%s': %s", path, strerror(errno));
        return NULL;
    }
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    if (!buf || fread(buf, 1, (size_t)n, f) != (size_t)n) {
        fclose(f);
        free(buf);
        snprintf(reason, sizeof reason, "cannot read '%s'", path);
        return NULL;
    }
    buf[n] = 0;
    fclose(f);
    if (size)
        *size = (size_t)n;
    return buf;
}

/* the value after "key": (NULL if absent) */
static const char *find_key(const char *json, const char *key)
{
    char pat[128];
    snprintf(pat, sizeof pat, "\"%s\"", key);
    const char *p = strstr(json, pat);
    if (!p)
        return NULL;
    p += strlen(pat);
    while (*p == ' ' || *p == '\n' || *p == '\t' || *p == '\r')
        p++;
    if (*p != ':')
        return NULL;
    p++;
    while (*p == ' ' || *p == '\n' || *p == '\t' || *p == '\r')
        p++;
    return p;
}

static int get_string(const char *json, const char *key, char *out, size_t n)
{
    const char *p = find_key(json, key);
    if (!p || *p != '"')
        return -1;
    p++;
    size_t i = 0;
    while (*p && *p != '"' && i + 1 < n)
        out[i++] = *p++;
    out[i] = 0;
    return 0;
}

static int is_null(const char *json, const char *key)
{
    const char *p = find_key(json, key);
    return !p || strncmp(p, "null", 4) == 0;
}

static double get_number(const char *json, const char *key, double fallback)
{
    const char *p = find_key(json, key);
    return p ? strtod(p, NULL) : fallback;
}

/* every number of a (nested) array, null -> NaN; *nrows: arrays one level in */
static double *get_numbers(const char *json, const char *key, long *count, long *nrows)
{
    const char *p = find_key(json, key);
    *count = 0;
    if (nrows)
        *nrows = 0;
    if (!p || *p != '[')
        return NULL;
    long cap = 64;
    double *v = malloc(cap * sizeof *v);
    int depth = 0;
    do {
        if (*p == '[') {
            depth++;
            if (depth == 2 && nrows)
                (*nrows)++;
            p++;
        } else if (*p == ']') {
            depth--;
            p++;
        } else if (*p == ',' || *p == ' ' || *p == '\n' || *p == '\t' || *p == '\r') {
            p++;
        } else {
            if (*count == cap)
                v = realloc(v, (cap *= 2) * sizeof *v);
            if (strncmp(p, "null", 4) == 0) {
                v[(*count)++] = NAN;
                p += 4;
            } else {
                char *end;
                v[(*count)++] = strtod(p, &end);
                if (end == p)
                    return free(v), NULL;
                p = end;
            }
        }
    } while (depth > 0 && *p);
    return v;
}

/* a float32 .npy with n values: a pointer to them (inside *buf) */
static float *read_npy_f4(const char *path, long n, char **buf)
{
    size_t size;
    *buf = read_file(path, &size);
    if (!*buf)
        return NULL;
    const unsigned char *b = (const unsigned char *)*buf;
    if (size < 10 || memcmp(b, "\x93NUMPY", 6) != 0) {
        snprintf(reason, sizeof reason, "'%s' is not a .npy file", path);
        return NULL;
    }
    size_t hlen, off;
    if (b[6] == 1) {
        hlen = b[8] | (b[9] << 8);
        off = 10;
    } else {
        hlen = b[8] | (b[9] << 8) | ((size_t)b[10] << 16) | ((size_t)b[11] << 24);
        off = 12;
    }
    if (!strstr(*buf + off, "'<f4'") || strstr(*buf + off, "'fortran_order': True") ||
        size < off + hlen + (size_t)n * 4) {
        snprintf(reason, sizeof reason, "'%s': expected %ld little-endian float32 in C order",
                 path, n);
        return NULL;
    }
    return (float *)(*buf + off + hlen);
}

/* ---- terrain scenes (protocol version 3): camval's rays against the height field ---- */

/* a .npy array of dtype descr ("<f8", "<f4", ...) and 1 or 2 dimensions: a pointer to its
   data (inside *buf); shape in dims[0..1] (dims[1] = 1 for one dimension) */
static void *read_npy(const char *path, const char *descr, long dims[2], char **buf)
{
    size_t size;
    *buf = read_file(path, &size);
    if (!*buf)
        return NULL;
    const unsigned char *b = (const unsigned char *)*buf;
    if (size < 12 || memcmp(b, "\x93NUMPY", 6) != 0) {
        snprintf(reason, sizeof reason, "'%s' is not a .npy file", path);
        return NULL;
    }
    size_t hlen = b[6] == 1 ? (size_t)(b[8] | (b[9] << 8))
                            : (b[8] | (b[9] << 8) | ((size_t)b[10] << 16) | ((size_t)b[11] << 24));
    size_t off = b[6] == 1 ? 10 : 12;
    char want[16];
    snprintf(want, sizeof want, "'%s'", descr);
    const char *shape = strstr(*buf + off, "'shape': (");
    if (!strstr(*buf + off, want) || strstr(*buf + off, "'fortran_order': True") || !shape) {
        snprintf(reason, sizeof reason, "'%s': expected %s in C order", path, descr);
        return NULL;
    }
    char *end;
    dims[0] = strtol(shape + 10, &end, 10);
    dims[1] = 1;
    if (*end == ',' && end[1] == ' ' && end[2] != ')')
        dims[1] = strtol(end + 2, NULL, 10);
    size_t item = descr[2] == '8' ? 8 : descr[2] == '4' ? 4 : 1;
    if (size < off + hlen + (size_t)(dims[0] * dims[1]) * item) {
        snprintf(reason, sizeof reason, "'%s' is shorter than its shape", path);
        return NULL;
    }
    return *buf + off + hlen;
}

static int write_npy(const char *path, const char *descr, const void *v, long n, size_t item)
{
    char header[128];
    int len = snprintf(header, sizeof header,
                       "{'descr': '%s', 'fortran_order': False, 'shape': (%ld,), }", descr, n);
    int total = 10 + len + 1;
    int pad = (64 - total % 64) % 64;
    FILE *f = fopen(path, "wb");
    if (!f) {
        snprintf(reason, sizeof reason, "cannot write '%s': %s", path, strerror(errno));
        return -1;
    }
    uint16_t hl = (uint16_t)(len + pad + 1);
    fwrite("\x93NUMPY\x01\x00", 1, 8, f);
    fputc(hl & 0xff, f);
    fputc(hl >> 8, f);
    fwrite(header, 1, len, f);
    for (int i = 0; i < pad; i++)
        fputc(' ', f);
    fputc('\n', f);
    size_t w = fwrite(v, item, (size_t)n, f);
    return fclose(f) == 0 && w == (size_t)n ? 0 : -1;
}

typedef struct {
    const double *h;          /* heights[j * nx + i], node (i, j) */
    long nx, ny;              /* nodes */
    double x0, y0, cell, zlo, zhi, tol;
    double *cmax;             /* highest node of each cell, (ny-1) x (nx-1) */
    const float *albedo;
    long tx, ty;
    double sun[3], ambient, exposure, sky;
    int shadows;
} terrain_t;

/* the nearest t >= 0 where the ray (grid units: x = u0 + t du cells from node 0, z = oz +
   t dz) meets the two triangles of cell (i, j) (targets/terrain.py's split), or INFINITY;
   *tri: 0 (u >= v) or 1 */
static double cell_hit(const terrain_t *T, double u0, double v0, double oz, double du,
                       double dv, double dz, long i, long j, int *tri)
{
    const double *h = T->h;
    long nx = T->nx;
    double h00 = h[j * nx + i], h10 = h[j * nx + i + 1];
    double h01 = h[(j + 1) * nx + i], h11 = h[(j + 1) * nx + i + 1];
    double eps = 1e-9, best = INFINITY;
    u0 -= i;
    v0 -= j;
    for (int k = 0; k < 2; k++) {
        double a = h00, b = k == 0 ? h10 - h00 : h11 - h01, c = k == 0 ? h11 - h10 : h01 - h00;
        double den = dz - b * du - c * dv, num = a + b * u0 + c * v0 - oz;
        if (den == 0.0)
            continue;
        double t = num / den;
        if (!(t >= 0.0) || t >= best)
            continue;
        double u = u0 + t * du, v = v0 + t * dv;
        if (u < -eps || u > 1 + eps || v < -eps || v > 1 + eps)
            continue;
        if ((k == 0 && u - v < -eps) || (k == 1 && v - u < -eps))
            continue;
        best = t;
        *tri = k;
    }
    return best;
}

/* walk the cells under the ray in order (2-D DDA), skipping those it passes above; the
   first hit (the nearest, as the cells come in order of t): t, and cell/triangle */
static double trace(const terrain_t *T, const double o[3], const double d[3], long *ci,
                    long *cj, int *tri)
{
    double ic = 1.0 / T->cell;
    double gx = (o[0] - T->x0) * ic, gy = (o[1] - T->y0) * ic, gdx = d[0] * ic, gdy = d[1] * ic;
    double t0 = 0.0, t1 = INFINITY, g = T->tol * ic;
    double lo[3] = {-g, -g, T->zlo - T->tol}, hi[3] = {T->nx - 1 + g, T->ny - 1 + g,
                                                      T->zhi + T->tol};
    double p[3] = {gx, gy, o[2]}, v[3] = {gdx, gdy, d[2]};
    for (int a = 0; a < 3; a++) {       /* clip to the grid's box and the height range */
        if (v[a] == 0.0) {
            if (p[a] < lo[a] || p[a] > hi[a])
                return INFINITY;
            continue;
        }
        double ta = (lo[a] - p[a]) / v[a], tb = (hi[a] - p[a]) / v[a];
        if (ta > tb) {
            double s = ta;
            ta = tb;
            tb = s;
        }
        t0 = ta > t0 ? ta : t0;
        t1 = tb < t1 ? tb : t1;
    }
    if (!(t0 <= t1))
        return INFINITY;
    long i = (long)floor(gx + t0 * gdx), j = (long)floor(gy + t0 * gdy);
    i = i < 0 ? 0 : i > T->nx - 2 ? T->nx - 2 : i;
    j = j < 0 ? 0 : j > T->ny - 2 ? T->ny - 2 : j;
    long si = gdx > 0 ? 1 : -1, sj = gdy > 0 ? 1 : -1;
    double tx = gdx != 0 ? ((gdx > 0 ? i + 1 : i) - gx) / gdx : INFINITY;
    double ty = gdy != 0 ? ((gdy > 0 ? j + 1 : j) - gy) / gdy : INFINITY;
    double dtx = gdx != 0 ? fabs(1.0 / gdx) : INFINITY, dty = gdy != 0 ? fabs(1.0 / gdy) : INFINITY;
    double tin = t0;
    for (;;) {
        double tout = tx < ty ? tx : ty;
        if (tout > t1)
            tout = t1;
        double za = o[2] + tin * d[2], zb = o[2] + tout * d[2];
        if ((za < zb ? za : zb) <= T->cmax[j * (T->nx - 1) + i] + T->tol) {
            double t = cell_hit(T, gx, gy, o[2], gdx, gdy, d[2], i, j, tri);
            if (t < INFINITY) {
                *ci = i;
                *cj = j;
                return t;
            }
        }
        if (tout >= t1)
            return INFINITY;
        tin = tout;
        if (tx < ty) {
            i += si;
            tx += dtx;
        } else {
            j += sj;
            ty += dty;
        }
        if (i < 0 || i > T->nx - 2 || j < 0 || j > T->ny - 2)
            return INFINITY;
    }
}

static double terrain_albedo(const terrain_t *T, double x, double y)
{
    double w = (T->nx - 1) * T->cell, hg = (T->ny - 1) * T->cell;
    double fx = (x - T->x0) / w * T->tx - 0.5, fy = (y - T->y0) / hg * T->ty - 0.5;
    fx = fx < 0 ? 0 : fx > T->tx - 1.0 ? T->tx - 1.0 : fx;
    fy = fy < 0 ? 0 : fy > T->ty - 1.0 ? T->ty - 1.0 : fy;
    long i = (long)fx, j = (long)fy;
    long imax = T->tx - 2 > 0 ? T->tx - 2 : 0, jmax = T->ty - 2 > 0 ? T->ty - 2 : 0;
    i = i < imax ? i : imax;
    j = j < jmax ? j : jmax;
    long i1 = i + 1 < T->tx ? i + 1 : T->tx - 1, j1 = j + 1 < T->ty ? j + 1 : T->ty - 1;
    double u = fx - i, v = fy - j;
    const float *a = T->albedo;
    return (1 - v) * ((1 - u) * a[j * T->tx + i] + u * a[j * T->tx + i1]) +
           v * ((1 - u) * a[j1 * T->tx + i] + u * a[j1 * T->tx + i1]);
}

/* one ray (terrain frame): the value it sees, its range (NaN: sky) and shadow code */
static void shade(const terrain_t *T, const double o[3], const double d[3], float *value,
                  double *range, unsigned char *code)
{
    long i, j;
    int tri = 0;
    double t = trace(T, o, d, &i, &j, &tri);
    if (t == INFINITY) {
        *value = (float)T->sky;
        *range = NAN;
        *code = 255;
        return;
    }
    double p[3] = {o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]};
    const double *h = T->h;
    long nx = T->nx;
    double ic = 1.0 / T->cell, b, c;
    if (tri == 0) {
        b = (h[j * nx + i + 1] - h[j * nx + i]) * ic;
        c = (h[(j + 1) * nx + i + 1] - h[j * nx + i + 1]) * ic;
    } else {
        b = (h[(j + 1) * nx + i + 1] - h[(j + 1) * nx + i]) * ic;
        c = (h[(j + 1) * nx + i] - h[j * nx + i]) * ic;
    }
    double s = 1.0 / sqrt(b * b + c * c + 1.0), n[3] = {-b * s, -c * s, s};
    double cosi = n[0] * T->sun[0] + n[1] * T->sun[1] + n[2] * T->sun[2];
    *code = 0;
    if (cosi <= 0.0) {
        *code = 1;
        cosi = 0.0;
    } else if (T->shadows) {
        /* leave the surface along its normal by a hair, towards the sun */
        double off = 1e-7 * T->cell, q[3] = {p[0] + off * n[0], p[1] + off * n[1],
                                             p[2] + off * n[2]};
        long si, sj;
        int st;
        if (trace(T, q, T->sun, &si, &sj, &st) < INFINITY) {
            *code = 2;
            cosi = 0.0;
        }
    }
    double val = T->exposure * terrain_albedo(T, p[0], p[1]) * (T->ambient + cosi);
    *value = (float)(val < 0 ? 0 : val > 1 ? 1 : val);
    *range = t;
}

/* a terrain request in rays mode: values.npy, and the optional outputs range.npy and
   shadow.npy; 0 done, 1 failed */
static int answer_terrain(const char *dir, const char *req, const char *scene, long n,
                          const float *dirs, const float *orgs, const double origin[3])
{
    char path[8192], s[1024];
    char *hbuf = NULL, *abuf = NULL;
    double *rt = NULL, *org = NULL, *sun = NULL, *rng = NULL;
    float *out = NULL;
    unsigned char *code = NULL;
    terrain_t T = {0};
    long dims[2], cnt, k;
    int status = 1;
    const char *p;

    if (!(p = find_key(scene, "heights")) || get_string(p, "file", s, sizeof s) != 0) {
        snprintf(reason, sizeof reason, "terrain scene: no heights file");
        goto done;
    }
    snprintf(path, sizeof path, "%s/%s", dir, s);
    if (!(T.h = read_npy(path, "<f8", dims, &hbuf)))
        goto done;
    T.ny = dims[0];
    T.nx = dims[1];
    if (!(p = find_key(scene, "albedo")) || get_string(p, "file", s, sizeof s) != 0) {
        snprintf(reason, sizeof reason, "terrain scene: no albedo file");
        goto done;
    }
    snprintf(path, sizeof path, "%s/%s", dir, s);
    if (!(T.albedo = read_npy(path, "<f4", dims, &abuf)))
        goto done;
    T.ty = dims[0];
    T.tx = dims[1];
    org = get_numbers(scene, "origin", &cnt, NULL);
    sun = get_numbers(scene, "direction", &k, NULL);
    rt = get_numbers(scene, "Rt_cam_terrain", &cnt, NULL);
    if (T.nx < 2 || T.ny < 2 || !org || !sun || k != 3 || !rt || cnt != 12) {
        snprintf(reason, sizeof reason, "terrain scene: a grid of at least 2x2 nodes, origin, "
                 "sun direction and Rt_cam_terrain needed");
        goto done;
    }
    T.x0 = org[0];
    T.y0 = org[1];
    memcpy(T.sun, sun, sizeof T.sun);
    T.cell = get_number(scene, "cell", NAN);
    T.ambient = get_number(scene, "ambient", NAN);
    T.exposure = get_number(scene, "exposure", 1.0);
    T.sky = get_number(scene, "sky", 0.0);
    p = find_key(scene, "shadows");
    T.shadows = !p || strncmp(p, "true", 4) == 0;
    T.zlo = INFINITY;
    T.zhi = -INFINITY;
    for (long a = 0; a < T.nx * T.ny; a++) {
        T.zlo = T.h[a] < T.zlo ? T.h[a] : T.zlo;
        T.zhi = T.h[a] > T.zhi ? T.h[a] : T.zhi;
    }
    double span = T.zhi - T.zlo > T.cell ? T.zhi - T.zlo : T.cell;
    T.tol = 1e-9 * (span > 1 ? span : 1);
    T.cmax = malloc((size_t)((T.nx - 1) * (T.ny - 1)) * sizeof *T.cmax);
    for (long j = 0; j + 1 < T.ny; j++)
        for (long i = 0; i + 1 < T.nx; i++) {
            const double *h = T.h;
            double m = h[j * T.nx + i];
            m = h[j * T.nx + i + 1] > m ? h[j * T.nx + i + 1] : m;
            m = h[(j + 1) * T.nx + i] > m ? h[(j + 1) * T.nx + i] : m;
            m = h[(j + 1) * T.nx + i + 1] > m ? h[(j + 1) * T.nx + i + 1] : m;
            T.cmax[j * (T.nx - 1) + i] = m;
        }

    /* p_cam = R p_terrain + t (rows of Rt: R, then t): p_terrain = R^T (p_cam - t) */
    const double *R = rt, *t = rt + 9;
    out = malloc((size_t)n * sizeof *out);
    rng = malloc((size_t)n * sizeof *rng);
    code = malloc((size_t)n);
    for (long r = 0; r < n; r++) {
        double oc[3], ot[3] = {0, 0, 0}, dt[3] = {0, 0, 0};
        for (int a = 0; a < 3; a++)
            oc[a] = (orgs ? orgs[3 * r + a] : origin[a]) - t[a];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                ot[b] += R[3 * a + b] * oc[a];
                dt[b] += R[3 * a + b] * dirs[3 * r + a];
            }
        shade(&T, ot, dt, out + r, rng + r, code + r);
    }
    if (get_string(req, "output", s, sizeof s) != 0) {
        snprintf(reason, sizeof reason, "no output in the request");
        goto done;
    }
    snprintf(path, sizeof path, "%s/%s", dir, s);
    if (write_npy(path, "<f4", out, n, 4) != 0)
        goto done;
    /* the optional outputs the request names */
    if ((p = find_key(req, "outputs"))) {
        const char *q;
        if ((q = find_key(p, "range")) && get_string(q, "file", s, sizeof s) == 0) {
            snprintf(path, sizeof path, "%s/%s", dir, s);
            if (write_npy(path, "<f8", rng, n, 8) != 0)
                goto done;
        }
        if ((q = find_key(p, "shadow")) && get_string(q, "file", s, sizeof s) == 0) {
            snprintf(path, sizeof path, "%s/%s", dir, s);
            if (write_npy(path, "|u1", code, n, 1) != 0)
                goto done;
        }
    }
    status = 0;

done:
    free(hbuf), free(abuf), free(rt), free(org), free(sun), free(rng), free(out), free(code);
    free(T.cmax);
    return status;
}

static int write_npy_f4(const char *path, const float *v, long n)
{
    return write_npy(path, "<f4", v, n, 4);
}

typedef struct {
    double extent[4], board, background, cell_origin[2], cell_size, circle_value;
    double *cells, *circles;
    long nx, ny, ncircles;
} pattern_t;

static double albedo(const pattern_t *pt, double x, double y)
{
    int inside = x >= pt->extent[0] && x < pt->extent[1] && y >= pt->extent[2] &&
                 y < pt->extent[3];
    if (!inside)
        return pt->background;
    double a = pt->board;
    if (pt->cells) {
        long ix = (long)floor((x - pt->cell_origin[0]) / pt->cell_size);
        long iy = (long)floor((y - pt->cell_origin[1]) / pt->cell_size);
        if (ix >= 0 && ix < pt->nx && iy >= 0 && iy < pt->ny) {
            double v = pt->cells[iy * pt->nx + ix];
            if (isfinite(v))
                a = v;
        }
    }
    for (long k = 0; k < pt->ncircles; k++) {
        const double *c = pt->circles + 3 * k;
        double dx = x - c[0], dy = y - c[1];
        if (dx * dx + dy * dy <= c[2] * c[2])
            return pt->circle_value;
    }
    return a;
}

/* 0 done, EXIT_NOT_APPLICABLE, 1 failed; reason[] says why */
static int answer(const char *request_path)
{
    char dir[4096], path[8192], s[1024];
    int status = 1;
    char *req = NULL, *scene = NULL, *dbuf = NULL, *obuf = NULL;
    double *ext = NULL, *rt = NULL, *org = NULL, *co = NULL;
    pattern_t pt = {0};
    float *out = NULL;
    long n, k;

    snprintf(dir, sizeof dir, "%s", request_path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = 0;
    else
        strcpy(dir, ".");
    if (!(req = read_file(request_path, NULL)))
        goto done;
    if (get_string(req, "mode", s, sizeof s) != 0 || strcmp(s, "rays") != 0) {
        snprintf(reason, sizeof reason, "rays_renderer renders only \"rays\" requests; got "
                 "mode \"%s\"", s);
        status = EXIT_NOT_APPLICABLE;
        goto done;
    }
    n = (long)get_number(req, "count", -1);
    if (get_string(req, "scene_file", s, sizeof s) != 0 || n <= 0) {
        snprintf(reason, sizeof reason, "'%s': no scene_file or ray count", request_path);
        goto done;
    }
    snprintf(path, sizeof path, "%s/%s", dir, s);
    if (!(scene = read_file(path, NULL)))
        goto done;
    long cnt, rows;
    int terrain = get_string(scene, "kind", s, sizeof s) == 0 && strcmp(s, "terrain") == 0;
    if (!terrain) {
        ext = get_numbers(scene, "extent", &cnt, NULL);
        rt = get_numbers(scene, "Rt_cam_board", &k, NULL);
        co = get_numbers(scene, "cell_origin", &cnt, NULL);
        if (!ext || !rt || k != 12 || !co) {
            snprintf(reason, sizeof reason, "'%s': no extent, cell_origin or Rt_cam_board", path);
            goto done;
        }
        memcpy(pt.extent, ext, sizeof pt.extent);
        memcpy(pt.cell_origin, co, sizeof pt.cell_origin);
        pt.board = get_number(scene, "board_value", NAN);
        pt.background = get_number(scene, "background_value", NAN);
        pt.cell_size = get_number(scene, "cell_size", NAN);
        pt.circle_value = get_number(scene, "circle_value", NAN);
        if (!is_null(scene, "cells")) {
            pt.cells = get_numbers(scene, "cells", &cnt, &rows);
            pt.ny = rows;
            pt.nx = rows ? cnt / rows : 0;
        }
        if (!is_null(scene, "circles")) {
            pt.circles = get_numbers(scene, "circles", &cnt, NULL);
            pt.ncircles = cnt / 3;
        }
    }

    if (get_string(req, "directions", s, sizeof s) != 0) {
        snprintf(reason, sizeof reason, "'%s': no rays directions", request_path);
        goto done;
    }
    snprintf(path, sizeof path, "%s/%s", dir, s);
    const float *d = read_npy_f4(path, 3 * n, &dbuf);
    if (!d)
        goto done;
    const float *o = NULL;
    double origin[3] = {0, 0, 0};
    if (!is_null(req, "origins")) {
        get_string(req, "origins", s, sizeof s);
        snprintf(path, sizeof path, "%s/%s", dir, s);
        if (!(o = read_npy_f4(path, 3 * n, &obuf)))
            goto done;
    } else if ((org = get_numbers(req, "origin", &cnt, NULL)) && cnt == 3) {
        memcpy(origin, org, sizeof origin);
    }

    if (terrain) {
        status = answer_terrain(dir, req, scene, n, d, o, origin);
        goto done;
    }
    /* p_cam = R p_board + t, Rt rows: R (3 rows), t; so p_board = R^T (p_cam - t) */
    const double *R = rt, *t = rt + 9;
    out = malloc((size_t)n * sizeof *out);
    for (long i = 0; i < n; i++) {
        double oc[3], ob[3] = {0, 0, 0}, db[3] = {0, 0, 0};
        for (int a = 0; a < 3; a++)
            oc[a] = (o ? o[3 * i + a] : origin[a]) - t[a];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                ob[b] += R[3 * a + b] * oc[a];
                db[b] += R[3 * a + b] * d[3 * i + a];
            }
        double sv = -ob[2] / db[2];
        out[i] = (float)(isfinite(sv) && sv > 0
                             ? albedo(&pt, ob[0] + sv * db[0], ob[1] + sv * db[1])
                             : pt.background);
    }
    if (get_string(req, "output", s, sizeof s) != 0) {
        snprintf(reason, sizeof reason, "'%s': no output", request_path);
        goto done;
    }
    snprintf(path, sizeof path, "%s/%s", dir, s);
    status = write_npy_f4(path, out, n) == 0 ? 0 : 1;

done:
    free(req), free(scene), free(dbuf), free(obuf), free(ext), free(rt), free(org), free(co);
    free(pt.cells), free(pt.circles), free(out);
    return status;
}

/* a JSON string: quotes, backslashes and control characters escaped */
static void print_json_string(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        if (*s == '"' || *s == '\\')
            printf("\\%c", *s);
        else if ((unsigned char)*s < 0x20)
            printf("\\u%04x", *s);
        else
            putchar(*s);
    }
    putchar('"');
}

int main(int argc, char **argv)
{
    if (argc > 1) {
        int status = answer(argv[1]);
        if (status != 0)
            fprintf(stderr, "rays_renderer: %s\n", reason);
        return status;
    }
    static char line[16384];
    char path[8192];
    while (fgets(line, sizeof line, stdin)) {
        if (get_string(line, "request", path, sizeof path) != 0) {
            printf("{\"status\": \"failed\", \"reason\": \"not a request line\"}\n");
        } else {
            int status = answer(path);
            if (status == 0)
                printf("{\"status\": \"ok\"}\n");
            else {
                printf("{\"status\": \"%s\", \"reason\": ",
                       status == EXIT_NOT_APPLICABLE ? "not-applicable" : "failed");
                print_json_string(reason);
                printf("}\n");
            }
        }
        fflush(stdout);
    }
    return 0;
}
