/* Runs the real firmware code (hfam_fw.c) on the host for tests: protocol bytes in on stdin,
 * everything the firmware transmits out on stdout. After the input ends, if the host started
 * on-board rendering, N_TICKS servo ticks run with the encoder following a scripted tap
 * (from +2 mm down to -1.5 mm at a constant speed and back) so contact events can be checked. */
#define HFAM_HOST_HARNESS 1
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "hfam_fw.c"

uint8_t UDR0, UCSR0A, UCSR0B, UCSR0C, PIND, PORTB, DDRB, OCR2A, TCCR2A, TCCR2B, EICRA, EIMSK, ADMUX, ADCSRA,
    TCCR1A, TCCR1B, TIMSK1, TIFR1, GPIOR0;
uint16_t UBRR0, ADC, OCR1A, TCNT1;

static void drain_tx(void) {
    while (tx_head != tx_tail) {
        putchar(tx_buf[tx_tail]);
        tx_tail = (uint16_t)((tx_tail + 1) % TX_SIZE);
    }
}

/* --q24-check STRIDE: the REARM_DATA conversion in integers (q24_of_bits) against the float one it replaced
 * (q24_of: f * 2^24, lroundf, saturated at +/-1e9) for every finite float |f| <= 1e30 (what finite4 lets through)
 * among the bit patterns k * STRIDE, plus the rounding edges of every exponent */
static int q24_check(unsigned stride) {
    unsigned long n = 0, bad = 0;
    for (uint64_t b = 0; b < 0x100000000ULL; b += stride) {
        for (int k = 0; k < 4; k++) { /* the pattern, and the significands just around a rounding half */
            uint32_t bits = (uint32_t)b;
            if (k) bits = (bits & 0xFF800000UL) | (k == 1 ? 0 : k == 2 ? 0x7FFFFFUL : 0x400000UL);
            if ((bits & 0x7FFFFFFFUL) > 0x7149F2CAUL) continue;
            union { uint32_t u; float f; } c;
            c.u = bits;
            n++;
            if (q24_of(c.f) != q24_of_bits(bits) && bad++ < 5)
                fprintf(stderr, "bits %08x: q24_of %ld, q24_of_bits %ld\n", (unsigned)bits, (long)q24_of(c.f), (long)q24_of_bits(bits));
        }
    }
    printf("checked %lu mismatches %lu\n", n, bad);
    return bad != 0;
}

int main(int argc, char **argv) {
    if (argc > 2 && !strcmp(argv[1], "--q24-check")) return q24_check((unsigned)atol(argv[2]));
    long n_ticks = argc > 1 ? atol(argv[1]) : 0;
    hw_init();
    uart_init();
    int c;
    while ((c = getchar()) != EOF) {
        UDR0 = (uint8_t)c;
        USART_RX_vect();
        service_uart();
        drain_tx();
    }
    /* scripted tap: counts per tick so that the handle moves at -0.1 m/s, then back up */
    const float step = -0.1f / (float)SERVO_HZ / POS_RES_M;
    float pos_counts = 0.002f / POS_RES_M;
    ADC = 600; /* accelerometer raw counts; grip reads the same ADC stand-in */
    for (long k = 0; k < n_ticks; k++) {
        if (pos_counts < -0.0015f / POS_RES_M) pos_counts = 0.0025f / POS_RES_M; /* lift (instantly) */
        pos_counts += step;
        encoder_count = (int32_t)lroundf(pos_counts);
        TIMER1_COMPA_vect(); /* the servo tick runs in the timer interrupt */
        flush_telemetry();   /* the main loop frames what it posted */
        drain_tx();
    }
    return 0;
}
