/* Host unit test of the C codec against firmware/vectors/vectors.txt.
 * Build and run: make -C firmware/c test */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stid_frame.h"

#define MAX_CASE_BYTES 8192
#define MAX_FRAMES 8

typedef struct {
    uint8_t type;
    uint32_t seq, t_us;
    uint8_t body[STID_MAX_FRAME];
    size_t body_len;
} expected_frame_t;

static int failures = 0;
static int checks = 0;

#define CHECK(cond, ...)                          \
    do {                                          \
        checks++;                                 \
        if (!(cond)) {                            \
            failures++;                           \
            fprintf(stderr, "FAIL: " __VA_ARGS__); \
            fputc('\n', stderr);                  \
        }                                         \
    } while (0)

static size_t unhex(const char *s, uint8_t *out, size_t cap) {
    size_t n = 0;
    while (s[0] && s[1] && s[0] != '\n' && n < cap) {
        unsigned v;
        if (sscanf(s, "%2x", &v) != 1) break;
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

static void run_case(const char *name, unsigned version, const uint8_t *wire, size_t wire_len,
                     expected_frame_t *exp, int n_exp, const uint32_t *exp_err) {
    static stid_decoder_t d;
    stid_decoder_init(&d);
    stid_frame_t f;
    int got = 0;
    for (size_t i = 0; i < wire_len; i++) {
        if (stid_decoder_push(&d, wire[i], &f)) {
            CHECK(got < n_exp, "%s: more frames than expected", name);
            if (got < n_exp) {
                expected_frame_t *e = &exp[got];
                CHECK(f.type == e->type && f.seq == e->seq && f.t_us == e->t_us && f.version == version,
                      "%s: frame %d header differs", name, got);
                CHECK(f.body_len == e->body_len && memcmp(f.body, e->body, e->body_len) == 0,
                      "%s: frame %d body differs", name, got);
                if (f.type == STID_SAMPLES || f.type == STID_SAMPLES4) { /* unpack every sample record */
                    uint8_t n = f.body[4];
                    size_t rs = stid_record_size(f.version, f.type);
                    static stid_sample_t s[40];
                    uint8_t again[STID_MAX_FRAME];
                    uint32_t index = f.body[0] | f.body[1] << 8 | f.body[2] << 16 | (uint32_t)f.body[3] << 24;
                    CHECK(rs > 0 && n <= 40, "%s: record layout", name);
                    for (uint8_t k = 0; k < n && k < 40; k++) stid_unpack_sample(f.version, f.type, f.body + 5 + k * rs, &s[k]);
                    if (f.version >= 2u) { /* and repack them: version 3 records are version 2's */
                        size_t bl = stid_pack_samples(f.type, index, s, n, again);
                        CHECK(bl == f.body_len && memcmp(again, f.body, bl) == 0, "%s: sample repack differs", name);
                    } else { /* an old record: unknown steer time, no extra wheels */
                        CHECK(n == 0 || (s[0].steer_t_us == STID_STEER_T_UNKNOWN && s[0].wheel[2].t_us == 0xFFFFFFFFul),
                              "%s: version 1 record's absent fields", name);
                    }
                    if (f.type == STID_SAMPLES4 && n > 0) /* the last field of the record: wheel 3's edge time */
                        CHECK(s[n - 1].wheel[2].t_us == (uint32_t)(f.body[5 + (n - 1) * rs + 40] |
                                                                   f.body[5 + (n - 1) * rs + 41] << 8 |
                                                                   f.body[5 + (n - 1) * rs + 42] << 16 |
                                                                   (uint32_t)f.body[5 + (n - 1) * rs + 43] << 24),
                              "%s: wheel 3 edge time", name);
                }
            }
            got++;
        }
    }
    CHECK(got == n_exp, "%s: %d frames decoded, %d expected", name, got, n_exp);
    for (int k = 0; k < STID_ERR_COUNT; k++)
        CHECK(d.errors[k] == exp_err[k], "%s: %s errors %u, expected %u", name, stid_error_names[k],
              d.errors[k], exp_err[k]);
}

static void check_encoder(const char *name, const uint8_t *wire, size_t wire_len, expected_frame_t *exp,
                          int n_exp) {
    uint8_t out[MAX_CASE_BYTES];
    size_t n = 0;
    for (int i = 0; i < n_exp; i++)
        n += stid_encode_frame(exp[i].type, exp[i].seq, exp[i].t_us, exp[i].body, exp[i].body_len, out + n);
    CHECK(n == wire_len && memcmp(out, wire, n) == 0, "%s: encoder output differs from the vector", name);
}

int main(int argc, char **argv) {
    const char *path = argc > 1 ? argv[1] : "../vectors/vectors.txt";
    FILE *fp = fopen(path, "r");
    if (!fp) {
        fprintf(stderr, "cannot open %s\n", path);
        return 2;
    }
    CHECK(stid_crc32((const uint8_t *)"123456789", 9) == 0xCBF43926u, "CRC-32 check value");
    {   /* a frame holds 1 to the most records (PROTOCOL.md): none, or one more, is refused */
        static stid_sample_t none[STID_MAX_BATCH + 1];
        static uint8_t body[STID_MAX_FRAME];
        CHECK(stid_pack_samples(STID_SAMPLES, 0, none, 0, body) == 0, "a SAMPLES body of no records");
        CHECK(stid_pack_samples(STID_SAMPLES, 0, none, STID_MAX_BATCH + 1, body) == 0, "a SAMPLES body of 39");
        CHECK(stid_pack_samples(STID_SAMPLES, 0, none, 1, body) == 5u + STID_SAMPLE_SIZE, "a SAMPLES body of 1");
    }

    static char line[2 * MAX_CASE_BYTES + 64];
    static uint8_t wire[MAX_CASE_BYTES];
    static expected_frame_t exp[MAX_FRAMES];
    char name[128] = "";
    size_t wire_len = 0;
    int n_exp = 0, cases = 0, encode = 0;
    unsigned version = STID_VERSION;
    uint32_t exp_err[STID_ERR_COUNT];
    while (fgets(line, sizeof line, fp)) {
        if (strncmp(line, "case ", 5) == 0) {
            sscanf(line + 5, "%127s", name);
            n_exp = 0;
            encode = 0;
            version = STID_VERSION;
            wire_len = 0;
            memset(exp_err, 0, sizeof exp_err);
        } else if (strncmp(line, "version ", 8) == 0) {
            sscanf(line + 8, "%u", &version);
        } else if (strncmp(line, "wire ", 5) == 0) {
            wire_len = unhex(line + 5, wire, sizeof wire);
        } else if (strncmp(line, "frame ", 6) == 0) {
            expected_frame_t *e = &exp[n_exp++];
            unsigned type;
            unsigned long seq, t;
            char hex[2 * STID_MAX_FRAME + 2];
            sscanf(line + 6, "%u %lu %lu %2049s", &type, &seq, &t, hex);
            e->type = (uint8_t)type;
            e->seq = (uint32_t)seq;
            e->t_us = (uint32_t)t;
            e->body_len = unhex(hex, e->body, sizeof e->body);
        } else if (strncmp(line, "errors", 6) == 0) {
            char *tok = strtok(line + 6, " \n");
            while (tok) {
                char key[32];
                unsigned v;
                if (sscanf(tok, "%31[^=]=%u", key, &v) == 2) {
                    int known = 0;
                    for (int k = 0; k < STID_ERR_COUNT; k++)
                        if (strcmp(key, stid_error_names[k]) == 0) exp_err[k] = v, known = 1;
                    CHECK(known, "%s: vector names unknown error kind %s", name, key);
                }
                tok = strtok(NULL, " \n");
            }
        } else if (strncmp(line, "encode", 6) == 0) {
            encode = 1; /* the wire is exactly the encoding of the frames listed */
        } else if (strncmp(line, "end", 3) == 0) {
            run_case(name, version, wire, wire_len, exp, n_exp, exp_err);
            if (encode && version == STID_VERSION) check_encoder(name, wire, wire_len, exp, n_exp);
            cases++;
        }
    }
    fclose(fp);
    printf("%d passed, %d failed\n", checks - failures, failures);
    return failures || cases == 0 ? 1 : 0;
}
