/* Runs the real firmware code (hfam_fw.c) on the host for tests: protocol bytes in on stdin,
 * everything the firmware transmits out on stdout. After the input ends, if the host started
 * on-board rendering, N_TICKS servo ticks run with the encoder following a scripted tap
 * (from +2 mm down to -1.5 mm at a constant speed and back) so contact events can be checked. */
#define HFAM_HOST_HARNESS 1
#include <stdio.h>
#include <stdlib.h>
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

int main(int argc, char **argv) {
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
