/* stid wire protocol v1 codec for C firmware (Arduino, pico-sdk) and tools.
 * Spec: firmware/PROTOCOL.md. No allocation, no dependencies beyond libc. */
#ifndef STID_FRAME_H
#define STID_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define STID_VERSION 1u
#define STID_HELLO 1u
#define STID_SAMPLES 2u
#define STID_STATUS 3u
#define STID_MOD (1ul << 30)
#define STID_HEADER_SIZE 10u
#define STID_CRC_SIZE 4u
#define STID_MAX_FRAME 1024u
#define STID_MAX_WIRE (STID_MAX_FRAME + STID_MAX_FRAME / 254u + 2u)
#define STID_SAMPLE_SIZE 22u
#define STID_STATUS_SIZE 28u
#define STID_MISSING 0xFFFFu

typedef struct {
    uint32_t t_us;
    uint16_t ax, ay, az, yaw;
    uint16_t steer_us;
    uint16_t wheel_count;
    uint32_t wheel_t_us;
    uint16_t vbat;
} stid_sample_t;

typedef struct {
    uint8_t type;
    uint32_t seq;
    uint32_t t_us;
    const uint8_t *body; /* points into the decoder's buffer; valid until the next byte */
    size_t body_len;
} stid_frame_t;

typedef enum {
    STID_ERR_COBS = 0,
    STID_ERR_SHORT,
    STID_ERR_CRC,
    STID_ERR_VERSION,
    STID_ERR_TYPE,
    STID_ERR_LENGTH,
    STID_ERR_TOO_LONG,
    STID_ERR_COUNT
} stid_error_t;

extern const char *const stid_error_names[STID_ERR_COUNT];

uint32_t stid_crc32(const uint8_t *data, size_t len);

/* COBS-encode src into dst and append the 0x00 delimiter. dst must hold
 * len + len/254 + 2 bytes. Returns the number of bytes written. */
size_t stid_cobs_encode(const uint8_t *src, size_t len, uint8_t *dst);

/* Decode one COBS block (no delimiter) in place-safe fashion into dst.
 * Returns decoded length, or -1 if the block is malformed. */
long stid_cobs_decode(const uint8_t *src, size_t len, uint8_t *dst);

/* Build a complete wire frame (COBS + delimiter) into wire (STID_MAX_WIRE bytes).
 * Returns its length, or 0 if the body is too long. */
size_t stid_encode_frame(uint8_t type, uint32_t seq, uint32_t t_us, const uint8_t *body,
                         size_t body_len, uint8_t *wire);

/* Pack n samples into a SAMPLES body (5 + 22 n bytes). Returns the body length. */
size_t stid_pack_samples(uint32_t index, const stid_sample_t *s, uint8_t n, uint8_t *body);
void stid_unpack_sample(const uint8_t *rec, stid_sample_t *out);

/* Streaming decoder: feed bytes one at a time; it never fails on bad input. */
typedef struct {
    uint8_t buf[STID_MAX_WIRE];
    uint8_t frame[STID_MAX_WIRE];
    size_t len;
    int overflow;
    uint32_t errors[STID_ERR_COUNT];
    uint32_t accepted;
} stid_decoder_t;

void stid_decoder_init(stid_decoder_t *d);
/* Returns 1 and fills *out when byte b completes a valid frame, else 0. */
int stid_decoder_push(stid_decoder_t *d, uint8_t b, stid_frame_t *out);

#endif
