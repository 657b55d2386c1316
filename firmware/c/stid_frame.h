/* stid wire protocol codec for C firmware (Arduino, pico-sdk) and tools.
 * Encodes version 3; decodes versions 1, 2 and 3.
 * Spec: firmware/PROTOCOL.md. No allocation, no dependencies beyond libc. */
#ifndef STID_FRAME_H
#define STID_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define STID_VERSION 3u    /* what the encoder writes */
#define STID_VERSION_MIN 1u /* oldest version the decoder reads */
#define STID_HELLO 1u
#define STID_SAMPLES 2u
#define STID_STATUS 3u
#define STID_SAMPLES4 4u /* version 2: samples with four hall sensors */
#define STID_HELLO_COMPACT 5u /* version 3: the configuration in a short binary body */
#define STID_MOD (1ul << 30)
#define STID_HEADER_SIZE 10u
#define STID_CRC_SIZE 4u
#define STID_MAX_FRAME 1024u
#define STID_MAX_WIRE (STID_MAX_FRAME + STID_MAX_FRAME / 254u + 2u)
#define STID_SAMPLE_SIZE 26u    /* versions 2 and 3, SAMPLES */
#define STID_SAMPLE4_SIZE 44u   /* versions 2 and 3, SAMPLES4 */
#define STID_SAMPLE_V1_SIZE 22u /* version 1, SAMPLES */
#define STID_MAX_BATCH 38u      /* SAMPLES records per frame */
#define STID_MAX_BATCH4 22u     /* SAMPLES4 records per frame */
#define STID_STATUS_SIZE 34u    /* version 3 (+ missed u32, late_max_us u16) */
#define STID_STATUS_V2_SIZE 28u /* versions 1 and 2 */
#define STID_HELLO_C_FIXED 57u  /* compact HELLO before its uid bytes; byte 56 is uid_len */
#define STID_MISSING 0xFFFFu
#define STID_STEER_T_UNKNOWN 0xFFFFFFFFul /* steer_t_us of a version 1 record */

typedef struct {
    uint16_t count;
    uint32_t t_us;
} stid_wheel_t;

typedef struct {
    uint32_t t_us;
    uint16_t ax, ay, az, yaw;
    uint16_t steer_us;
    uint16_t wheel_count;
    uint32_t wheel_t_us;
    uint16_t vbat;
    uint32_t steer_t_us;    /* ticks of the falling edge of the pulse whose width is steer_us */
    stid_wheel_t wheel[3];  /* hall sensors 1..3: SAMPLES4 only (count 0xFFFF, t_us 0xFFFFFFFF if absent) */
} stid_sample_t;

typedef struct {
    uint8_t version;
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
    STID_ERR_VERSION_NEWER, /* a valid frame of a newer protocol: this decoder is too old */
    STID_ERR_TYPE,
    STID_ERR_LENGTH,
    STID_ERR_HELLO, /* a compact HELLO whose length does not match its uid_len */
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

/* Record size of a (version, type), or 0 if that version has no such sample frame. */
size_t stid_record_size(uint8_t version, uint8_t type);

/* Pack n samples into a version 3 (= version 2) SAMPLES body (type STID_SAMPLES: 5 + 26 n bytes) or
 * SAMPLES4 body (STID_SAMPLES4: 5 + 44 n). Returns the body length, 0 if n is 0 or too large. */
size_t stid_pack_samples(uint8_t type, uint32_t index, const stid_sample_t *s, uint8_t n, uint8_t *body);
/* Unpack one record of a (version, type) frame; fields the layout lacks are set to
 * their "absent" values. */
void stid_unpack_sample(uint8_t version, uint8_t type, const uint8_t *rec, stid_sample_t *out);

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
