/* stid wire protocol codec (encodes v3, decodes v1, v2 and v3). See stid_frame.h and firmware/PROTOCOL.md. */
#include "stid_frame.h"

#include <string.h>

const char *const stid_error_names[STID_ERR_COUNT] = {
    "cobs", "short", "crc", "version", "version_newer", "type", "length", "hello", "too_long"};

static void put_u16(uint8_t *p, uint16_t v) {
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v) {
    for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i));
}

static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }

static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

uint32_t stid_crc32(const uint8_t *data, size_t len) {
    /* Bitwise CRC-32 (IEEE, reflected): small code for MCUs; swap in a table if
     * the 8 iterations per byte matter on your target. */
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < len; i++) {
        crc ^= data[i];
        for (int k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return crc ^ 0xFFFFFFFFu;
}

size_t stid_cobs_encode(const uint8_t *src, size_t len, uint8_t *dst) {
    size_t code_i = 0, o = 1;
    uint8_t code = 1;
    int open_block = 1;
    for (size_t i = 0; i < len;) {
        uint8_t b = src[i++];
        if (b == 0) {
            dst[code_i] = code;
            code_i = o++;
            code = 1;
        } else {
            dst[o++] = b;
            if (++code == 0xFF) {
                dst[code_i] = code;
                if (i < len) {
                    code_i = o++;
                    code = 1;
                } else {
                    open_block = 0; /* like the reference: no code after a final full block */
                }
            }
        }
    }
    if (open_block) dst[code_i] = code;
    dst[o++] = 0;
    return o;
}

long stid_cobs_decode(const uint8_t *src, size_t len, uint8_t *dst) {
    size_t i = 0, o = 0;
    while (i < len) {
        uint8_t code = src[i++];
        if (code == 0) return -1;
        if (i + code - 1 > len) return -1;
        for (uint8_t k = 1; k < code; k++) {
            if (src[i] == 0) return -1;
            dst[o++] = src[i++];
        }
        if (code != 0xFF && i < len) dst[o++] = 0;
    }
    return (long)o;
}

size_t stid_encode_frame(uint8_t type, uint32_t seq, uint32_t t_us, const uint8_t *body,
                         size_t body_len, uint8_t *wire) {
    uint8_t raw[STID_MAX_FRAME];
    if (body_len > STID_MAX_FRAME - STID_HEADER_SIZE - STID_CRC_SIZE) return 0;
    raw[0] = STID_VERSION;
    raw[1] = type;
    put_u32(raw + 2, seq % STID_MOD);
    put_u32(raw + 6, t_us % STID_MOD);
    if (body_len) memcpy(raw + STID_HEADER_SIZE, body, body_len);
    size_t n = STID_HEADER_SIZE + body_len;
    put_u32(raw + n, stid_crc32(raw, n));
    return stid_cobs_encode(raw, n + STID_CRC_SIZE, wire);
}

size_t stid_record_size(uint8_t version, uint8_t type) {
    if (version == 1u && type == STID_SAMPLES) return STID_SAMPLE_V1_SIZE;
    if (version >= 2u && version <= 3u && type == STID_SAMPLES) return STID_SAMPLE_SIZE;
    if (version >= 2u && version <= 3u && type == STID_SAMPLES4) return STID_SAMPLE4_SIZE;
    return 0;
}

size_t stid_pack_samples(uint8_t type, uint32_t index, const stid_sample_t *s, uint8_t n, uint8_t *body) {
    size_t rs = stid_record_size(STID_VERSION, type);
    if (rs == 0 || n == 0 || n > (type == STID_SAMPLES4 ? STID_MAX_BATCH4 : STID_MAX_BATCH)) return 0;
    put_u32(body, index % STID_MOD);
    body[4] = n;
    uint8_t *p = body + 5;
    for (uint8_t i = 0; i < n; i++, p += rs) {
        put_u32(p, s[i].t_us);
        put_u16(p + 4, s[i].ax);
        put_u16(p + 6, s[i].ay);
        put_u16(p + 8, s[i].az);
        put_u16(p + 10, s[i].yaw);
        put_u16(p + 12, s[i].steer_us);
        put_u16(p + 14, s[i].wheel_count);
        put_u32(p + 16, s[i].wheel_t_us);
        put_u16(p + 20, s[i].vbat);
        put_u32(p + 22, s[i].steer_t_us);
        if (type == STID_SAMPLES4) {
            for (int k = 0; k < 3; k++) {
                put_u16(p + 26 + 6 * k, s[i].wheel[k].count);
                put_u32(p + 28 + 6 * k, s[i].wheel[k].t_us);
            }
        }
    }
    return 5u + (size_t)n * rs;
}

void stid_unpack_sample(uint8_t version, uint8_t type, const uint8_t *p, stid_sample_t *o) {
    o->t_us = get_u32(p);
    o->ax = get_u16(p + 4);
    o->ay = get_u16(p + 6);
    o->az = get_u16(p + 8);
    o->yaw = get_u16(p + 10);
    o->steer_us = get_u16(p + 12);
    o->wheel_count = get_u16(p + 14);
    o->wheel_t_us = get_u32(p + 16);
    o->vbat = get_u16(p + 20);
    o->steer_t_us = version >= 2u ? get_u32(p + 22) : STID_STEER_T_UNKNOWN;
    for (int k = 0; k < 3; k++) {
        int four = version >= 2u && type == STID_SAMPLES4;
        o->wheel[k].count = four ? get_u16(p + 26 + 6 * k) : (uint16_t)STID_MISSING;
        o->wheel[k].t_us = four ? get_u32(p + 28 + 6 * k) : (uint32_t)0xFFFFFFFFul;
    }
}

void stid_decoder_init(stid_decoder_t *d) { memset(d, 0, sizeof *d); }

static int check_frame(stid_decoder_t *d, stid_frame_t *out) {
    long n = stid_cobs_decode(d->buf, d->len, d->frame);
    if (n < 0) return d->errors[STID_ERR_COBS]++, 0;
    if ((size_t)n < STID_HEADER_SIZE + STID_CRC_SIZE) return d->errors[STID_ERR_SHORT]++, 0;
    size_t body_len = (size_t)n - STID_HEADER_SIZE - STID_CRC_SIZE;
    if (stid_crc32(d->frame, (size_t)n - 4) != get_u32(d->frame + n - 4))
        return d->errors[STID_ERR_CRC]++, 0;
    uint8_t version = d->frame[0];
    if (version > STID_VERSION) return d->errors[STID_ERR_VERSION_NEWER]++, 0;
    if (version < STID_VERSION_MIN) return d->errors[STID_ERR_VERSION]++, 0;
    uint8_t type = d->frame[1];
    if (type == STID_SAMPLES || type == STID_SAMPLES4) {
        size_t rs = stid_record_size(version, type);
        if (rs == 0) return d->errors[STID_ERR_TYPE]++, 0;
        if (body_len <= 5 || body_len != 5u + rs * d->frame[STID_HEADER_SIZE + 4]) /* n is 1 to the most */
            return d->errors[STID_ERR_LENGTH]++, 0;
    } else if (type == STID_STATUS) {
        if (body_len != (version >= 3u ? STID_STATUS_SIZE : STID_STATUS_V2_SIZE))
            return d->errors[STID_ERR_LENGTH]++, 0;
    } else if (type == STID_HELLO_COMPACT && version >= 3u) {
        const uint8_t *b = d->frame + STID_HEADER_SIZE;
        if (body_len < STID_HELLO_C_FIXED || body_len != STID_HELLO_C_FIXED + b[STID_HELLO_C_FIXED - 1u])
            return d->errors[STID_ERR_HELLO]++, 0;
    } else if (type != STID_HELLO) {
        return d->errors[STID_ERR_TYPE]++, 0;
    }
    out->version = version;
    out->type = type;
    out->seq = get_u32(d->frame + 2);
    out->t_us = get_u32(d->frame + 6);
    out->body = d->frame + STID_HEADER_SIZE;
    out->body_len = body_len;
    d->accepted++;
    return 1;
}

int stid_decoder_push(stid_decoder_t *d, uint8_t b, stid_frame_t *out) {
    if (b != 0) {
        if (d->overflow) return 0;
        if (d->len == sizeof d->buf) {
            d->overflow = 1;
            return 0;
        }
        d->buf[d->len++] = b;
        return 0;
    }
    int got = 0;
    if (d->overflow) {
        d->errors[STID_ERR_TOO_LONG]++;
    } else if (d->len > 0) {
        got = check_frame(d, out);
    }
    d->len = 0;
    d->overflow = 0;
    return got;
}
