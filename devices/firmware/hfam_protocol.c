/* Framing and CRC of docs/protocol.md; mirrors devices/hardware/wire_protocol.py (FrameParser, crc16_bitwise). */
#include "hfam_protocol.h"

uint16_t hfam_crc16(uint16_t crc, const uint8_t *data, uint16_t n) {
    while (n--) {
        crc ^= (uint16_t)(*data++) << 8;
        for (uint8_t i = 0; i < 8; i++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

uint16_t hfam_encode(uint8_t *out, uint8_t type, uint8_t seq, const uint8_t *payload, uint8_t n) {
    out[0] = HFAM_SYNC0;
    out[1] = HFAM_SYNC1;
    out[2] = n;
    out[3] = type;
    out[4] = seq;
    for (uint8_t i = 0; i < n; i++) out[5 + i] = payload[i];
    put_u16(out + 5 + n, hfam_crc16(0xFFFF, out + 2, (uint16_t)n + 3));
    return (uint16_t)n + HFAM_OVERHEAD;
}

static uint8_t known_type(uint8_t t) {
    return (t >= MSG_HELLO && t <= MSG_SET_CALIBRATION) || (t >= MSG_WALL && t <= MSG_KEEPALIVE) ||
           (t >= MSG_INFO && t <= MSG_PONG);
}

/* 0: need more bytes, 1: complete CRC-valid frame, 2: not a frame (bad sync/type/CRC). */
static uint8_t check(hfam_parser_t *p) {
    const uint8_t *b = p->buf;
    uint16_t pos = p->pos;
    if (pos >= 2 && b[1] != HFAM_SYNC1) return 2;
    if (pos >= 4 && !known_type(b[3])) return 2;
    if (pos < 5 || pos < (uint16_t)b[2] + HFAM_OVERHEAD) return 0;
    if (hfam_crc16(0xFFFF, b + 2, (uint16_t)b[2] + 3) == get_u16(b + 5 + b[2])) return 1;
    p->crc_errors++;
    return 2;
}

/* Byte-at-a-time version of the Python FrameParser: on a rejected candidate, resume the sync
 * search at the next 0xA5 inside it (in place, no recursion: 2 kB of RAM). A valid frame that
 * overlaps a rejected one may be lost; the host retries. */
uint8_t hfam_parse_byte(hfam_parser_t *p, uint8_t byte) {
    uint8_t *b = p->buf;
    if (p->pos == 0 && byte != HFAM_SYNC0) {
        p->garbage++;
        return 0;
    }
    b[p->pos++] = byte;
    for (;;) {
        uint8_t r = check(p);
        if (r == 0) return 0;
        if (r == 1) {
            p->pos = 0;
            return 1;
        }
        uint16_t n = p->pos, i = 1;
        while (i < n && b[i] != HFAM_SYNC0) i++;
        p->garbage += i;
        for (uint16_t j = i; j < n; j++) b[j - i] = b[j];
        p->pos = n - i;
        if (p->pos == 0) return 0;
    }
}
