/* hfam device protocol 1.1 (docs/protocol.md): framing, CRC-16/CCITT-FALSE, stream parser.
 * Platform independent (AVR firmware and the host-side check program share it). */
#ifndef HFAM_PROTOCOL_H
#define HFAM_PROTOCOL_H

#include <stdint.h>

#define HFAM_PROTO_MAJOR 1
#define HFAM_PROTO_MINOR 1 /* 1.1: WALL may carry the passivity observer's limit and leak; status bit 64 UNSTABLE */
#define HFAM_SYNC0 0xA5
#define HFAM_SYNC1 0x5A
#define HFAM_MAX_PAYLOAD 255
#define HFAM_OVERHEAD 7

/* host -> device */
#define MSG_HELLO 0x01
#define MSG_CURRENT 0x02
#define MSG_SET_MODE 0x03
#define MSG_SET_WATCHDOG 0x04
#define MSG_CLEAR_FAULTS 0x05
#define MSG_PING 0x06
#define MSG_SET_CALIBRATION 0x07
#define MSG_WALL 0x10
#define MSG_LIMITS 0x11
#define MSG_TRANSIENT_PARAM 0x12
#define MSG_TABLE_BEGIN 0x13
#define MSG_TABLE_DATA 0x14
#define MSG_TABLE_COMMIT 0x15
#define MSG_REARM_DATA 0x16
#define MSG_REARM_COMMIT 0x17
#define MSG_RENDER_START 0x18
#define MSG_RENDER_STOP 0x19
#define MSG_KEEPALIVE 0x1A
/* device -> host */
#define MSG_INFO 0x81
#define MSG_STATE 0x82
#define MSG_EVENT 0x83
#define MSG_ACK 0x84
#define MSG_NAK 0x85
#define MSG_PONG 0x86

#define CAP_STREAMING 1
#define CAP_ON_DEVICE 2
#define CAP_PARAM_TRANSIENT 4
#define CAP_TABLE_TRANSIENT 8
#define CAP_REARM_TRANSIENT 16

#define NAK_UNKNOWN_TYPE 1
#define NAK_BAD_PAYLOAD 2
#define NAK_BAD_STATE 3
#define NAK_TOO_LARGE 4

#define ST_FAULT 1
#define ST_OVER_TEMPERATURE 2
#define ST_WATCHDOG_TRIPPED 4
#define ST_CLIPPING 8
#define ST_UNSTABLE 64 /* the on-device wall's passivity observer stopped the rendering (with ST_FAULT) */

/* CRC-16/CCITT-FALSE update by one byte (polynomial 0x1021, no reflection; callers start at 0xFFFF).
 * On the AVR a table in flash; elsewhere the table-free shift-and-xor form of the same update. */
#ifdef __AVR__
#include <avr/pgmspace.h>
extern const uint16_t hfam_crc_table[256] PROGMEM; /* 512 bytes of flash: ~12 cycles per byte, inlined */
static inline uint16_t hfam_crc16_byte(uint16_t crc, uint8_t byte) {
    return (uint16_t)((crc << 8) ^ pgm_read_word(&hfam_crc_table[(uint8_t)(crc >> 8) ^ byte]));
}
#else
static inline uint16_t hfam_crc16_byte(uint16_t crc, uint8_t byte) {
    crc = (uint16_t)((crc >> 8) | (crc << 8));
    crc ^= byte;
    crc ^= (uint8_t)(crc & 0xFF) >> 4;
    crc ^= (uint16_t)(crc << 12);
    crc ^= (uint16_t)((uint16_t)(crc & 0xFF) << 5);
    return crc;
}
#endif
uint16_t hfam_crc16(uint16_t crc, const uint8_t *data, uint16_t n);

/* Build a frame into out (HFAM_OVERHEAD + n bytes); returns its length. */
uint16_t hfam_encode(uint8_t *out, uint8_t type, uint8_t seq, const uint8_t *payload, uint8_t n);

typedef struct {
    uint8_t buf[HFAM_MAX_PAYLOAD + HFAM_OVERHEAD];
    uint16_t pos;      /* bytes collected of the current candidate frame */
    uint16_t crc_errors;
    uint16_t garbage;
    uint16_t crc;      /* running CRC over buf[2 .. 5 + len) */
} hfam_parser_t;

/* Feed one byte; returns 1 when buf holds a complete CRC-valid frame
 * (type = buf[3], seq = buf[4], payload = buf + 5, length = buf[2]). */
uint8_t hfam_parse_byte(hfam_parser_t *p, uint8_t byte);

/* little-endian field access */
static inline void put_u16(uint8_t *b, uint16_t v) { b[0] = (uint8_t)v; b[1] = (uint8_t)(v >> 8); }
static inline void put_u32(uint8_t *b, uint32_t v) {
    b[0] = (uint8_t)v; b[1] = (uint8_t)(v >> 8); b[2] = (uint8_t)(v >> 16); b[3] = (uint8_t)(v >> 24);
}
static inline uint16_t get_u16(const uint8_t *b) { return (uint16_t)(b[0] | ((uint16_t)b[1] << 8)); }
static inline uint32_t get_u32(const uint8_t *b) {
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
}
static inline void put_f32(uint8_t *b, float f) { union { float f; uint32_t u; } c; c.f = f; put_u32(b, c.u); }
static inline float get_f32(const uint8_t *b) { union { float f; uint32_t u; } c; c.u = get_u32(b); return c.f; }

#endif
