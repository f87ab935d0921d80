/* Host build of the firmware's protocol code, for tests: reads a byte stream on stdin and prints
 * each frame the firmware parser accepts as "type seq payload-hex", then "crc_errors N". */
#include <stdio.h>
#include "hfam_protocol.h"

int main(void) {
    static hfam_parser_t p;
    int c;
    while ((c = getchar()) != EOF) {
        if (hfam_parse_byte(&p, (uint8_t)c)) {
            uint8_t out[HFAM_MAX_PAYLOAD + HFAM_OVERHEAD];
            uint16_t n = hfam_encode(out, p.buf[3], p.buf[4], p.buf + 5, p.buf[2]);
            printf("%02x %02x ", p.buf[3], p.buf[4]);
            for (uint16_t i = 5; i + 2 < n; i++) printf("%02x", out[i]);
            printf("\n");
        }
    }
    printf("crc_errors %u\n", p.crc_errors);
    return 0;
}
