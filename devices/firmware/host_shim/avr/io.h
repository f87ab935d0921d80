/* Host stand-ins for the AVR registers so hfam_fw.c compiles into the test harness (fw_harness.c).
 * ADSC is bit 8 of an 8-bit register: setting it is lost, so the ADC busy-wait ends at once. */
#ifndef HOST_SHIM_AVR_IO_H
#define HOST_SHIM_AVR_IO_H
#include <stdint.h>
#define _BV(b) (1u << (b))
extern uint8_t UDR0, UCSR0A, UCSR0B, UCSR0C, PIND, PORTB, DDRB, OCR2A, TCCR2A, TCCR2B, EICRA, EIMSK, ADMUX, ADCSRA,
    TCCR1A, TCCR1B, TIMSK1, TIFR1, GPIOR0;
extern uint16_t UBRR0, ADC, OCR1A, TCNT1;
enum { U2X0 = 1, RXEN0 = 4, TXEN0 = 3, RXCIE0 = 7, UDRIE0 = 5, UCSZ01 = 2, UCSZ00 = 1, PB0 = 0, PB3 = 3,
       COM2A1 = 7, WGM21 = 1, WGM20 = 0, CS20 = 0, ISC00 = 0, ISC10 = 2, INT0 = 0, INT1 = 1, REFS0 = 6,
       ADSC = 8, ADEN = 7, ADPS2 = 2, WGM12 = 3, CS10 = 0, OCIE1A = 1, OCF1A = 1 };
#endif
