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

static int write_npy_f4(const char *path, const float *v, long n)
{
    char header[128];
    int len = snprintf(header, sizeof header,
                       "{'descr': '<f4', 'fortran_order': False, 'shape': (%ld,), }", n);
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
    size_t w = fwrite(v, sizeof *v, (size_t)n, f);
    return fclose(f) == 0 && w == (size_t)n ? 0 : -1;
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
