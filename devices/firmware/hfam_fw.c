/* Reference firmware for a Hapkit-style 1-DOF paddle on an ATmega328P (Arduino Uno/Nano, 16 MHz).
 *
 * Speaks protocol 1.1 of docs/protocol.md over the UART at 1 Mbaud (U2X, exact at 16 MHz; the
 * host opens the port at any nominal baud the USB-serial bridge maps to 1 Mbaud, or use a
 * native-USB board). Same behaviour as the Python emulator (devices/firmware/emulator.py +
 * devices/firmware/logic.py): hello/INFO, streaming (one CURRENT in -> one STATE out),
 * on-device rendering of wall + pulse / decaying sinusoid / host re-armed sampled transient
 * with a steady-state and a peak current limit (thesis Fig. 4.9), contact events, a passivity
 * observer that stops an unstable wall (FAULT + UNSTABLE, latched), and a watchdog that zeroes
 * the motor while the host is quiet (reported; output resumes with the host).
 *
 * Hardware (pins as on an Uno; change the #defines for another board):
 *   quadrature encoder A/B on INT0 (PD2) / INT1 (PD3), x4 decoding in the interrupts;
 *   motor driver PWM on OC2B (PD3 is taken, so OC2A = PB3 / D11), direction on PB0 (D8),
 *   current = duty * PWM_FULL_SCALE_A (open-loop current drive through a current-mode driver);
 *   accelerometer (analog, e.g. ADXL321) on ADC0, force-sensing resistor divider on ADC1.
 * Servo tick: Timer1 CTC at SERVO_HZ, run inside the compare interrupt with interrupts re-enabled
 * (encoder and UART interrupts nest in it), in fixed point (no soft-float in the tick); the main
 * loop parses host frames and sends the telemetry the tick posts. The AVR hardware watchdog
 * (60 ms) resets a hung board.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>
#include <math.h>
#include <string.h>

#include "hfam_protocol.h"

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#define SERVO_HZ 4000UL
#define UART_BAUD 1000000UL
#define FW_MAJOR 1
#define FW_MINOR 0
#define FW_PATCH 0
#define DEVICE_NAME "hapkit-paddle"
#define SERIAL_NUMBER "HK0001"
/* device constants reported in INFO (SI units; edit for your mechanism) */
#define ENCODER_LINES 500UL
#define GEAR_RATIO 10.0f
#define HANDLE_LENGTH_M 0.07f
#define KT_NM_A 0.0187f
#define I_CONT_A 0.8f
#define I_PEAK_A 2.0f
#define I_AMP_A 2.0f
#define PWM_FULL_SCALE_A 2.0f
#define ACCEL_RANGE_M_S2 176.6f          /* +/-18 g */
#define ACCEL_SCALE_M_S2_PER_COUNT 0.345f /* 10-bit ADC over +/-18 g */
#define ACCEL_OFFSET_COUNTS 512
#define GRIP_SCALE_N_PER_COUNT 0.0098f   /* 10 N over the FSR divider's 10-bit range */
#define GRIP_OFFSET_COUNTS 0
#define GRIP_MAX_N 10.0f
#define R_WINDING_OHM 10.6f
#define R_THERMAL_K_W 8.0f
#define TAU_THERMAL_S 30.0f
#define T_MAX_RISE_K 80.0f
#define T_ATTENUATE_K (0.7f * T_MAX_RISE_K) /* same fade-out as devices/firmware/logic.py */
#define T_END_K (0.9f * T_MAX_RISE_K)
#define WATCHDOG_MS_DEFAULT 100
#define REARM_MAX 128                    /* sampled transient buffer (Q24 A, int32): 512 of the 2048 bytes of RAM */
#define VEL_WINDOW 4
#define FORCE_PER_AMP (GEAR_RATIO * KT_NM_A / HANDLE_LENGTH_M)
#define POS_RES_M (2.0f * 3.14159265f * HANDLE_LENGTH_M / (4.0f * ENCODER_LINES * GEAR_RATIO))

/* ---- UART ring buffers ------------------------------------------------------------ */
/* RX ring: power of two. The main loop parses ~200 cycles per byte (was ~335), slower than
 * the 160-cycle byte time at 1 Mbaud, and handling a 24-sample data frame takes ~3,400 cycles of its own (~6,300
 * with the servo ticks and UART interrupts meanwhile, up to ~12,000; simavr): a
 * burst longer than the ring is lost whatever the ring size RAM allows. So the ring must hold one whole
 * frame with nothing drained (hosts send data frames of at most 24 samples = 107 bytes, and wait for each
 * one's ACK: wire_protocol.DATA_CHUNK_SAMPLES, docs/protocol.md "Receive buffer"); a byte that finds it
 * full is dropped and counted in rx_overruns (read by the simavr harness). */
#define RX_SIZE 128
#define TX_SIZE 256 /* must stay 256: the 8-bit indices wrap by themselves */
static volatile uint8_t rx_buf[RX_SIZE];
#ifdef __AVR__
/* the ring's indices in the general-purpose I/O registers GPIOR1/GPIOR2: `in`/`out` (1 cycle) instead of
 * `lds`/`sts` (2) in the receive interrupt, which nests in the servo tick once per byte while a frame arrives */
#define rx_head GPIOR1
#define rx_tail GPIOR2
#else
static volatile uint8_t rx_head, rx_tail;
#endif
volatile uint16_t rx_overruns; /* bytes dropped because the ring was full (not static: fw_sim.c reads it) */
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail; /* 8-bit: atomic on the AVR, wraps at TX_SIZE = 256 */
static void tx_commit(void);

#ifdef __AVR__
/* At 1 Mbaud a data frame arrives at one byte per 160 cycles and this interrupt nests in the servo tick:
 * avr-gcc's version (r0/r1/r18 saved for nothing) took ~67 cycles a byte, 40 % of the CPU, and a
 * tick overlapped by a frame ran ~3,800 of its 4,000 cycles (simavr). This one saves only what it
 * uses: ~51 cycles. Same logic as the C version below (the host build's). */
ISR(USART_RX_vect, ISR_NAKED) {
    __asm__ __volatile__(
        "push r24\n\t"
        "in   r24, __SREG__\n\t"
        "push r24\n\t"
        "push r25\n\t"
        "push r30\n\t"
        "push r31\n\t"
        "lds  r25, %[udr]\n\t"              /* the byte (clears RXC0) */
        "in   r30, %[head]\n\t"
        "mov  r24, r30\n\t"
        "subi r24, 0xFF\n\t"                /* next = (head + 1) & (RX_SIZE - 1) */
        "andi r24, %[mask]\n\t"
        "in   r31, %[tail]\n\t"
        "cp   r24, r31\n\t"
        "breq 1f\n\t"                       /* full: drop it, count it (out of line: no jump on the common path) */
        "ldi  r31, 0\n\t"
        "subi r30, lo8(-(%[buf]))\n\t"
        "sbci r31, hi8(-(%[buf]))\n\t"
        "st   Z, r25\n\t"
        "out  %[head], r24\n"
        "2:\n\t"
        "pop  r31\n\t"
        "pop  r30\n\t"
        "pop  r25\n\t"
        "pop  r24\n\t"
        "out  __SREG__, r24\n\t"
        "pop  r24\n\t"
        "reti\n"
        "1:\n\t"
        "lds  r24, %[ovr]\n\t"
        "lds  r25, %[ovr]+1\n\t"
        "adiw r24, 1\n\t"
        "sts  %[ovr]+1, r25\n\t"
        "sts  %[ovr], r24\n\t"
        "rjmp 2b\n\t"
        :: [udr] "n" (_SFR_MEM_ADDR(UDR0)), [head] "I" (_SFR_IO_ADDR(GPIOR1)), [tail] "I" (_SFR_IO_ADDR(GPIOR2)),
           [buf] "i" (rx_buf), [ovr] "i" (&rx_overruns), [mask] "M" (RX_SIZE - 1));
}
#else
ISR(USART_RX_vect) {
    uint8_t c = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) & (RX_SIZE - 1));
    if (next != rx_tail) {
        rx_buf[rx_head] = c;
        rx_head = next;
    } else {
        rx_overruns++;
    }
}
#endif

ISR(USART_UDRE_vect) {
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint8_t)(tx_tail + 1);
}

static void uart_init(void) {
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / (8UL * UART_BAUD) - 1);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

/* Frames are written straight into the TX ring with a running CRC (no frame buffer on the
 * 2 kB stack); a frame that does not fit is dropped whole (the host sees a sequence gap). */
static uint8_t tx_w;
static uint16_t tx_crc;
static uint8_t tx_begin(uint16_t n) {
    uint16_t used = (uint8_t)(tx_head - tx_tail);
    if (used + n >= TX_SIZE) return 0;
    tx_w = tx_head;
    tx_crc = 0xFFFF;
    return 1;
}
static inline __attribute__((always_inline)) void tx_put(uint8_t c, uint8_t crc) {
    tx_buf[tx_w] = c;
    tx_w = (uint8_t)(tx_w + 1);
    if (crc) tx_crc = hfam_crc16_byte(tx_crc, c);
}
static void tx_commit(void) {
    tx_put((uint8_t)tx_crc, 0);
    tx_put((uint8_t)(tx_crc >> 8), 0);
    tx_head = tx_w; /* publish the whole frame at once (one 8-bit store) */
    UCSR0B |= _BV(UDRIE0);
}

/* ---- encoder (x4 quadrature on INT0/INT1) ---------------------------------------- */
/* The interrupts add to a 16-bit delta (a 16-bit read-modify-write: ~half the cycles of a 32-bit
 * one, and fewer registers to save); encoder_read() folds it into the 32-bit count, every tick.
 * 68 counts per 250 us tick at 6 m/s: 480 ticks could pass before the delta overflowed (an 8-bit
 * one wrapped when interrupt storms at 3 m/s delayed a few ticks). */
static volatile int32_t encoder_count;
static volatile int16_t enc_delta;
static volatile uint8_t enc_prev;
static const int8_t QDEC[16] = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};

static inline void encoder_update(void) {
    uint8_t ab = (uint8_t)((PIND >> 2) & 0x03);
    enc_delta += QDEC[(enc_prev << 2) | ab];
    enc_prev = ab;
}
ISR(INT0_vect) { encoder_update(); }
/* One handler for both vectors. Two identical ISR bodies let avr-gcc -Os turn INT0's into a call of
 * INT1's, whose `reti` then re-enabled interrupts inside INT0's frame: nested encoder interrupts,
 * the stack ran into .bss under simavr within 2 ms of a steady low pin. */
ISR(INT1_vect, ISR_ALIASOF(INT0_vect));

/* the 32-bit count (main loop or tick; interrupts must be on when called) */
static int32_t encoder_read(void) {
    cli();
    int16_t d = enc_delta;
    enc_delta = 0;
    int32_t e = encoder_count + d;
    encoder_count = e;
    sei();
    return e;
}

/* ---- time, ADC, motor -------------------------------------------------------------- */
/* The servo tick runs inside the Timer1 compare interrupt, with interrupts re-enabled right after
 * its prologue (UDRIE0 off first, see below) so the encoder and UART receive interrupts nest in it: it starts within a few
 * dozen cycles of the compare match whatever the main loop is doing (parsing a long frame,
 * assembling telemetry). The main loop owns the UART: the tick leaves its STATE/EVENT payloads
 * in small slots (below) that the main loop frames and sends. Main-loop code that writes what
 * the tick reads does so with interrupts off (TICK_LOCK), a few stores at a time: each section is
 * far shorter than the UART receive deadline (two characters, 320 cycles), and a compare match
 * meanwhile is served as soon as it ends. */
static volatile uint32_t tick_count;
static volatile uint32_t tick_us; /* tick_count * 250 us, kept beside it (the product took ~40 cycles a tick) */
static volatile uint8_t tick_busy;
static volatile uint16_t tick_overruns; /* compare matches that found the previous tick still running */
static void servo_tick(void);
#define TICK_LOCK() cli()
#define TICK_UNLOCK() sei()
ISR(TIMER1_COMPA_vect) {
    /* the transmitter waits for the tick (one interrupt per byte would take ~40 % of the CPU
     * inside it); receive and encoder interrupts stay on: they have deadlines. UDRIE0 goes off before
     * interrupts come back on: with ISR_NOBLOCK (sei first) the ~35-cycle register-saving prologue ran
     * one instruction per nested interrupt while telemetry went out and a data frame came in, and
     * the tick started ~730 cycles late (simavr trace, 2026-11: a lost tick in the re-arm run). The
     * prologue with interrupts off delays the RX and encoder interrupts by at most ~40 cycles. */
    UCSR0B &= (uint8_t)~_BV(UDRIE0);
    sei();
    tick_count++;
    tick_us += 1000000UL / SERVO_HZ;
    if (tick_busy) { tick_overruns++; return; }
    tick_busy = 1;
    servo_tick();
    if (tx_head != tx_tail) UCSR0B |= _BV(UDRIE0);
    tick_busy = 0;
}

static void adc_start(uint8_t channel) {
    ADMUX = _BV(REFS0) | (channel & 0x07);
    ADCSRA |= _BV(ADSC);
}
static uint16_t adc_result(void) {
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}
static uint16_t adc_read(uint8_t channel) {
    adc_start(channel);
    return adc_result();
}

/* Currents in fixed point: Q24 amperes (int32, 1 LSB = 60 nA, range +/-128 A), so the servo tick
 * needs no soft-float (~100-150 cycles per operation on the AVR); its products are 16 x 16 -> 32-bit MULs
 * (mul_uu16, mul_su16, mul_ss16 below), with the ranges that allow it stated where they are used, and keep the
 * precision far below the 1 mA the host test allows against devices/firmware/logic.py (32 x 32 -> 64-bit ones
 * only beyond those ranges: 5.6 mm into a wall past its clamp, 1,400 m/s). */
#define Q24 16777216.0f
static volatile int32_t applied_q24;
static void motor_set_q24(int32_t q) {
    const int32_t amp = (int32_t)(I_AMP_A * Q24);
    if (q > amp) q = amp;
    if (q < -amp) q = -amp;
    applied_q24 = q;
    if (q >= 0) PORTB &= (uint8_t)~_BV(PB0); else PORTB |= _BV(PB0);
    /* duty = |i| / PWM_FULL_SCALE_A -> 0..255: |i| <= 2 A = 2^25 in Q24, so |i| >> 16 (bytes 2-3, no
     * shift loop) is 0..512 and that * 255 / 512 is the 8-bit duty */
    uint32_t a = (uint32_t)(q >= 0 ? q : -q);
    uint16_t hi = (uint16_t)(a >> 16);
    uint16_t d = (uint16_t)((hi >> 1) - (hi >> 9)); /* hi * 255 / 512 within one count, no multiply */
    OCR2A = (uint8_t)(d > 255 ? 255 : d);
}
static void hw_init(void) {
    DDRB |= _BV(PB0) | _BV(PB3);
    TCCR2A = _BV(COM2A1) | _BV(WGM21) | _BV(WGM20); /* fast PWM, 62.5 kHz */
    TCCR2B = _BV(CS20);
    OCR2A = 0;
    EICRA = _BV(ISC00) | _BV(ISC10); /* any edge */
    EIMSK = _BV(INT0) | _BV(INT1);
    enc_prev = (uint8_t)((PIND >> 2) & 0x03);
    ADCSRA = _BV(ADEN) | _BV(ADPS2); /* /16: 1 MHz ADC clock, ~13 us per conversion */
    /* the period before the clock starts: with OCR1A still 0, CTC mode matches at once (a spurious
     * first tick, and a compare flagged while interrupts are off) */
    OCR1A = (uint16_t)(F_CPU / SERVO_HZ - 1);
    TCNT1 = 0;
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS10);
    TIFR1 = _BV(OCF1A); /* nothing flagged while the timer was set up: the first tick is a full period away */
    TIMSK1 = _BV(OCIE1A);
}

/* ---- protocol state ------------------------------------------------------------------- */
static hfam_parser_t parser;
static uint8_t tx_seq, cmd_seq;
static uint8_t mode_on_device, rendering, decimation = 1;
static uint8_t tripped, trip_report, ev_tripped, fault_latched, watchdog_armed;
static uint16_t watchdog_ms = WATCHDOG_MS_DEFAULT;
static uint32_t watchdog_ticks = (uint32_t)WATCHDOG_MS_DEFAULT * (SERVO_HZ / 1000UL);
static uint32_t last_cmd_tick;

/* calibration uploaded by the host */
static int32_t cal_zero;
static int8_t cal_sign = 1;
static float cal_a_scale = ACCEL_SCALE_M_S2_PER_COUNT, cal_a_off = ACCEL_OFFSET_COUNTS;
static float cal_g_scale = GRIP_SCALE_N_PER_COUNT, cal_g_off = GRIP_OFFSET_COUNTS;
static int32_t cal_a_off_q8 = (int32_t)ACCEL_OFFSET_COUNTS * 256; /* accel offset in 1/256 ADC counts */

/* renderer (devices/firmware/logic.py), in fixed point: positions in 1/256 encoder count (Q8
 * counts), currents in Q24 A. The host's SI parameters are converted once, when they arrive. */
static int32_t wall_h_q8, wall_rearm_q8 = (int32_t)(0.001f / POS_RES_M * 256.0f);
static int32_t k_wall;              /* wall current per count of penetration, Q24 A (times pen in Q8, >> 8) */
static int32_t pen_c_max;           /* whole counts of penetration below which k_wall * counts fits 2^30 */
static int32_t b_wall[2 * VEL_WINDOW]; /* damping current per count moved over t ticks, Q24 A (t = 1..7) */
static int32_t b_wall_1;            /* the same for t = 1, divided by t for longer gaps */
static int32_t lim_cont_q24, lim_peak_q24;
static uint8_t tr_kind; /* 0 none, 1 pulse, 2 sinusoid, 4 re-armed buffer */
static int32_t tr_gain[2 * VEL_WINDOW]; /* transient amplitude per count moved over t ticks, Q24 A */
static int32_t tr_gain_1;
/* decaying sinusoid e^{-a t} sin(w t) at t = (k+1)/fs as the recurrence y_k = c1 y_{k-1} - c2 y_{k-2}
 * (c1 = 2 r cos(w/fs), c2 = r^2, r = e^{-a/fs}); c1/c2 in Q30, the first two samples s1, s2 in Q31 (set with
 * TRANSIENT_PARAM), instead of expf + sinf (~5,000 cycles). The recurrence is linear, so it runs on the current
 * itself, z_k = amplitude * y_k in Q24 A (sin_y1, sin_y2: z_{k-1}, z_{k-2}): two mulhi16 per tick and no
 * product by the amplitude (set once per contact from s1, s2) */
static int32_t sin_c1, sin_c2, sin_s1, sin_s2, sin_y1, sin_y2;
static uint16_t tr_param_n;
static int32_t rearm_buf[REARM_MAX]; /* Q24 A */
static uint16_t rearm_n, rearm_pending_n;
/* The wall's passivity observer (Hannaford & Ryu 2002; renderer/passivity.py, docs/renderer.md "Stopping an
 * unstable wall"), as the host-side law runs it: every tick E <- a E + F_{k-1} (x_k - x_{k-1}) + U(x_k) -
 * U(x_{k-1}), F the wall channel's current (proportional + damping, after the continuous clamp; no transient),
 * U the potential of the clamped spring, and the rendering stops (zero output, FAULT + UNSTABLE) once E
 * exceeds the host's limit. Energies in Q16 "A count" (one ampere over one encoder count is FORCE_PER_AMP *
 * POS_RES_M = 59 uJ; Q16 keeps 1 nJ), saturated at +/-SAT (16,384 A count, 0.96 J); F in Q16 A; the leak
 * 1 - a as a 16-bit multiplier po_leak_m 2^-(16 + 8 po_leak_sh). Set with WALL (protocol 1.1: limit 0 = off;
 * the 1.0 WALL turns it off). 22 bytes of RAM. */
#define PO_Q16_PER_J (65536.0f / (FORCE_PER_AMP * POS_RES_M))
#define PO_PEN_MAX (1L << 22) /* Q8: penetrations beyond 16,384 counts (36 cm) count as that much */
#define PO_U_MAX (1L << 29)   /* stored energy, Q16 A count (8,192 A count, 0.48 J: F_c over 10,000 counts) */
#define PO_DX_MAX 8191        /* counts per tick (720 m/s): the work term stays below 2^29 */
/* currents of the wall channel (<= the continuous limit, at most I_CONT_A) fit 16 bits in Q16 A */
_Static_assert(I_CONT_A < 1.0f, "the passivity observer keeps the wall current in 16 bits (Q16 A): I_CONT_A < 1 A");
int32_t po_e; /* not static: the simavr harness logs it per tick (fw_sim.c --sym-po-e) */
static int32_t po_limit, po_u;
static uint16_t po_f, po_leak_m, po_x16; /* F (Q16 A); the leak multiplier; the last position's low 16 bits */
static uint8_t po_leak_sh;
static int32_t po_ds_q8 = PO_PEN_MAX; /* penetration at which k * pen reaches the continuous limit, Q8 counts */
static uint8_t po_fresh = 1, po_unstable;
static uint8_t rearm_pending;
static int32_t vel_ring[VEL_WINDOW];  /* positions in counts */
static uint16_t vel_tick[VEL_WINDOW]; /* servo period number of each sample (low 16 bits) */
static uint16_t render_tick_n;        /* servo period number of the current tick (low 16 bits) */
static uint8_t vel_i, vel_filled;
static uint8_t armed, in_event, ev_clipped, ev_kind, clipping, over_temp;
/* first-order winding model dT = (i^2 R_w R_th - T) dt / tau, T in Q20 K */
#define T_Q20(k) ((int32_t)((k) * 1048576.0f))
static int32_t temp_q20;
/* The model is stepped every THERMAL_EVERY ticks with the mean i^2 over them (tau = 30 s is 120,000
 * ticks: the difference from a per-tick step is far below the model's own accuracy, and a Q20
 * temperature step of dt/tau per tick would round away differences below 0.11 K) */
#define THERMAL_EVERY 16
static int32_t heat_acc; /* sum of i^2 (Q24 A^2) since the last thermal step */
static uint8_t heat_n;
static void thermal_service(void);
static uint32_t heat_post; /* sums of i^2 over the blocks of THERMAL_EVERY ticks not yet stepped, Q16 A^2 (< 2^22 each) */
static uint8_t heat_posts;
static uint32_t temp_fade_q16; /* 0: below T_att, else the fade-out factor (Q16) + 1 (thermal_step) */
static uint16_t tr_k, tr_n, ev_index;
static int32_t tr_scale_q24;
/* the current event, in raw units (the main loop converts them to SI for the EVENT frame) */
static uint32_t ev_t_us;
static int32_t ev_dcounts, ev_pen_q8, ev_peak_q8;
static uint8_t ev_ticks;
static uint16_t ev_grip_raw;

/* ---- telemetry slots (tick -> main loop) ---------------------------------------------- */
typedef struct {
    uint32_t t_us;
    int32_t enc;
    uint16_t accel_raw, grip_raw;
    int32_t current_q24;
    uint8_t status, cmd_seq;
} state_slot_t;
typedef struct {
    uint32_t t_us;
    int32_t dcounts, pen_q8, peak_q8;
    uint16_t grip_raw, index;
    uint8_t ticks, flags, kind;
} event_slot_t;
static state_slot_t st_slot[2];
/* What the last tick read and commanded, for a debugger or the simavr harness's per-tick log (the
 * link carries a STATE every `decimation` ticks only); ~20 cycles per tick. */
volatile state_slot_t tick_probe;
static volatile uint8_t st_ready, st_latest, st_reading = 0xFF;
#define EV_QUEUE 2 /* power of two; events are 10s of ms apart, the main loop sends one within a tick */
static event_slot_t ev_queue[EV_QUEUE];
static volatile uint8_t evq_head, evq_tail;

#define MAX_TX_PAYLOAD 120 /* INFO is the longest frame the firmware sends; PONG echoes are truncated */
static void send(uint8_t type, const uint8_t *payload, uint8_t n) {
    if (n > MAX_TX_PAYLOAD) n = MAX_TX_PAYLOAD;
    uint8_t seq = tx_seq++;
    if (!tx_begin((uint16_t)n + HFAM_OVERHEAD)) return;
    tx_put(HFAM_SYNC0, 0);
    tx_put(HFAM_SYNC1, 0);
    tx_put(n, 1);
    tx_put(type, 1);
    tx_put(seq, 1);
    for (uint8_t i = 0; i < n; i++) tx_put(payload[i], 1);
    tx_commit();
}

static void ack(uint8_t type, uint8_t seq) {
    uint8_t p[2] = {type, seq};
    send(MSG_ACK, p, 2);
}

static void nak(uint8_t type, uint8_t seq, uint8_t code) {
    uint8_t p[3] = {type, seq, code};
    send(MSG_NAK, p, 3);
}

/* INFO is written straight into the TX ring, field by field: no 100-byte frame buffer on the stack
 * that the tick interrupt (and the UART and encoder interrupts in it) nest on */
static void info_bytes(const uint8_t *b, uint8_t n) { for (uint8_t i = 0; i < n; i++) tx_put(b[i], 1); }
static void info_f32(float f) { uint8_t b[4]; put_f32(b, f); info_bytes(b, 4); }
static void info_u16(uint16_t v) { uint8_t b[2]; put_u16(b, v); info_bytes(b, 2); }
static void info_u32(uint32_t v) { uint8_t b[4]; put_u32(b, v); info_bytes(b, 4); }
#ifdef __AVR__
#include <avr/pgmspace.h>
#define INFO_FLASH PROGMEM
#define INFO_FLOAT(p) pgm_read_float(p)
#else
#define INFO_FLASH
#define INFO_FLOAT(p) (*(p))
#endif
#define INFO_LEN (5 + 4 + 9 * 4 + 2 + 4 + 2 + 6 * 4 + 2 + 2 + 4 + 2 + 1 + sizeof(DEVICE_NAME) - 1 + 1 + sizeof(SERIAL_NUMBER) - 1)
static void send_info(void) {
    /* in flash (60 bytes of RAM in .data otherwise) */
    static const float f1[9] INFO_FLASH = {GEAR_RATIO, HANDLE_LENGTH_M, KT_NM_A, I_CONT_A, I_PEAK_A, I_AMP_A,
                                           (float)SERVO_HZ, ACCEL_RANGE_M_S2, ACCEL_SCALE_M_S2_PER_COUNT};
    static const float f2[6] INFO_FLASH = {0.0f, GRIP_MAX_N, R_WINDING_OHM, R_THERMAL_K_W, TAU_THERMAL_S, T_MAX_RISE_K};
    static const uint8_t version[5] = {HFAM_PROTO_MAJOR, HFAM_PROTO_MINOR, FW_MAJOR, FW_MINOR, FW_PATCH};
    uint8_t seq = tx_seq++;
    if (!tx_begin((uint16_t)INFO_LEN + HFAM_OVERHEAD)) return;
    tx_put(HFAM_SYNC0, 0);
    tx_put(HFAM_SYNC1, 0);
    tx_put((uint8_t)INFO_LEN, 1);
    tx_put(MSG_INFO, 1);
    tx_put(seq, 1);
    info_bytes(version, 5);
    info_u32(ENCODER_LINES);
    for (uint8_t i = 0; i < 9; i++) info_f32(INFO_FLOAT(&f1[i]));
    info_u16((uint16_t)ACCEL_OFFSET_COUNTS);
    info_f32(GRIP_SCALE_N_PER_COUNT);
    info_u16((uint16_t)GRIP_OFFSET_COUNTS);
    for (uint8_t i = 0; i < 6; i++) info_f32(INFO_FLOAT(&f2[i]));
    info_u16(watchdog_ms);
    info_u16(CAP_STREAMING | CAP_ON_DEVICE | CAP_PARAM_TRANSIENT | CAP_REARM_TRANSIENT);
    info_u32(REARM_MAX);
    info_u16(0); /* flags: not simulated */
    tx_put(sizeof(DEVICE_NAME) - 1, 1);
    info_bytes((const uint8_t *)DEVICE_NAME, sizeof(DEVICE_NAME) - 1);
    tx_put(sizeof(SERIAL_NUMBER) - 1, 1);
    info_bytes((const uint8_t *)SERIAL_NUMBER, sizeof(SERIAL_NUMBER) - 1);
    tx_commit();
}

static uint8_t status_bits(void) {
    uint8_t b = (uint8_t)(((tripped || trip_report) ? ST_WATCHDOG_TRIPPED : 0) | (fault_latched ? ST_FAULT : 0) |
                          (clipping ? ST_CLIPPING : 0) | (over_temp ? ST_OVER_TEMPERATURE : 0) |
                          (po_unstable ? ST_UNSTABLE : 0));
    trip_report = 0;
    return b;
}

static void send_state_slot(const state_slot_t *s) {
    uint8_t p[16];
    put_u32(p, s->t_us);
    put_u32(p + 4, (uint32_t)s->enc);
    put_u16(p + 8, s->accel_raw); /* raw ADC counts; the host subtracts the INFO/calibration offset */
    put_u16(p + 10, s->grip_raw);
    p[12] = s->status;
    p[13] = s->cmd_seq;
    /* mA, rounded half away from zero (as lroundf): Q24 A -> 2^-16 A -> mA */
    int32_t q = s->current_q24;
    uint32_t a = (uint32_t)(q >= 0 ? q : -q) >> 8;
    int16_t mA = (int16_t)((a * 1000UL + 32768UL) >> 16);
    put_u16(p + 14, (uint16_t)(q >= 0 ? mA : -mA));
    send(MSG_STATE, p, 16);
}

/* the tick's telemetry: fill the slot the main loop is not reading, publish it */
static void post_state(uint32_t t_us, int32_t enc, uint16_t accel_raw, uint16_t grip_raw) {
    uint8_t w = st_latest ^ 1;
    if (w == st_reading) w ^= 1; /* never the slot being copied (then the newest unsent one is replaced) */
    state_slot_t *s = &st_slot[w];
    s->t_us = t_us; s->enc = enc; s->accel_raw = accel_raw; s->grip_raw = grip_raw;
    s->current_q24 = applied_q24; s->status = status_bits(); s->cmd_seq = cmd_seq;
    st_latest = w;
    st_ready = 1;
}

static void finish_event(void) {
    in_event = 0;
    ev_index++;
    uint8_t next = (uint8_t)((evq_head + 1) & (EV_QUEUE - 1));
    if (next != evq_tail) { /* full (the main loop far behind): the event is dropped, its index shows it */
        event_slot_t *e = &ev_queue[evq_head];
        e->t_us = ev_t_us; e->dcounts = ev_dcounts; e->ticks = ev_ticks; e->grip_raw = ev_grip_raw;
        e->pen_q8 = ev_pen_q8; e->peak_q8 = ev_peak_q8; e->index = ev_index; e->kind = ev_kind;
        e->flags = (uint8_t)((ev_clipped ? 1 : 0) | (ev_tripped ? 2 : 0));
        evq_head = next;
    }
    ev_tripped = 0;
}

static void send_event_slot(const event_slot_t *e) {
    uint8_t p[24];
    put_u32(p, e->t_us);
    /* incoming speed = -v at contact, v = counts moved * resolution * fs / ticks (as logic.py) */
    float v = e->dcounts < 0 ? (float)(-e->dcounts) * POS_RES_M * (float)SERVO_HZ / (float)e->ticks : 0.0f;
    put_f32(p + 4, v);
    put_f32(p + 8, ((float)e->grip_raw - cal_g_off) * cal_g_scale);
    put_f32(p + 12, (float)e->pen_q8 * (POS_RES_M / 256.0f));
    put_f32(p + 16, (float)e->peak_q8 * (1.0f / 256.0f) * cal_a_scale);
    p[20] = e->flags;
    p[21] = e->kind;
    put_u16(p + 22, e->index);
    send(MSG_EVENT, p, 24);
}

/* main loop: frame and send what the tick posted (and step the thermal model) */
static void flush_telemetry(void) {
    thermal_service();
    while (evq_tail != evq_head) {
        send_event_slot(&ev_queue[evq_tail]);
        evq_tail = (uint8_t)((evq_tail + 1) & (EV_QUEUE - 1));
    }
    if (st_ready) {
        state_slot_t s;
        TICK_LOCK(); /* a few cycles: the tick must not publish between these two stores */
        uint8_t r = st_latest;
        st_reading = r;
        st_ready = 0;
        TICK_UNLOCK();
        s = st_slot[r];
        st_reading = 0xFF;
        send_state_slot(&s);
    }
}

/* 32x32 -> 64-bit products (libgcc's __mulsidi3) with the result taken by bytes: avr-gcc shifts an
 * int64 with a bit-by-bit library loop (__ashrdi3, ~10 cycles per bit), a byte offset costs nothing.
 * Results are saturated to +/-(2^30 - 1) (64 A in Q24): far beyond any current limit. Only the fallbacks
 * beyond the 16-bit products' ranges use them now (~150-250 cycles each on simavr). */
typedef union { int64_t q; struct { uint32_t lo; int32_t hi; } w; uint8_t b[8]; } prod_t;
#define SAT 0x3FFFFFFFL
static inline int32_t mul_sat(int32_t a, int32_t b) { /* a * b, saturated */
    prod_t u;
    u.q = (int64_t)a * b;
    if (u.w.hi >= 0) return (u.w.hi != 0 || u.w.lo > (uint32_t)SAT) ? SAT : (int32_t)u.w.lo;
    return (u.w.hi != -1 || (int32_t)u.w.lo < -SAT) ? -SAT : (int32_t)u.w.lo;
}
static inline int32_t mul_sh8_sat(int32_t a, int32_t b) { /* (a * b) >> 8, saturated */
    prod_t u;
    int32_t r;
    u.q = (int64_t)a * b;
    int32_t top = u.w.hi >> 6; /* bits 38..63: all equal <=> |result| < 2^30 */
    if (top != 0 && top != -1) return u.w.hi < 0 ? -SAT : SAT;
    memcpy(&r, &u.b[1], 4);
    return r;
}

/* 16 x 16 -> 32-bit products for the passivity observer. avr-gcc turns a product of 16-bit operands inside
 * a longer expression into a 32 x 32 one (__mulsi3, register shuffling around a call): inline MULs instead. */
static inline __attribute__((always_inline)) uint32_t mul_uu16(uint16_t a, uint16_t b) {
#ifdef __AVR__
    uint32_t r;
    __asm__("mul  %A1, %A2\n\t"
            "movw %A0, r0\n\t"
            "mul  %B1, %B2\n\t"
            "movw %C0, r0\n\t"
            "mul  %B1, %A2\n\t"
            "add  %B0, r0\n\t"
            "adc  %C0, r1\n\t"
            "clr  r1\n\t" /* the zero register again; clr keeps the carry */
            "adc  %D0, r1\n\t"
            "mul  %A1, %B2\n\t"
            "add  %B0, r0\n\t"
            "adc  %C0, r1\n\t"
            "clr  r1\n\t"
            "adc  %D0, r1\n\t"
            : "=&r"(r) : "r"(a), "r"(b));
    return r;
#else
    return (uint32_t)a * b;
#endif
}
/* signed x unsigned and signed x signed 16 x 16 -> 32 with the AVR's MULSU / MULS (Atmel AVR201): no sign
 * branches or 32-bit negations (~15 cycles instead of ~35 with mul_uu16 on magnitudes). After a MULSU/MULS the
 * carry is the 16-bit product's sign bit: `sbc top, zero` sign-extends a partial product added at byte 1. */
static inline __attribute__((always_inline)) int32_t mul_su16(int16_t a, uint16_t b) { /* a b, |a b| < 2^31 */
#ifdef __AVR__
    int32_t r;
    uint8_t z;
    __asm__("clr   %[z]\n\t"
            "mulsu %B[a], %B[b]\n\t"
            "movw  %C[r], r0\n\t"
            "mul   %A[a], %A[b]\n\t"
            "movw  %A[r], r0\n\t"
            "mulsu %B[a], %A[b]\n\t"
            "sbc   %D[r], %[z]\n\t"
            "add   %B[r], r0\n\t"
            "adc   %C[r], r1\n\t"
            "adc   %D[r], %[z]\n\t"
            "mul   %B[b], %A[a]\n\t"
            "add   %B[r], r0\n\t"
            "adc   %C[r], r1\n\t"
            "adc   %D[r], %[z]\n\t"
            "clr   r1\n\t"
            : [r] "=&r"(r), [z] "=&r"(z) : [a] "a"(a), [b] "a"(b));
    return r;
#else
    return (int32_t)a * b;
#endif
}

static inline __attribute__((always_inline)) int32_t mul_ss16(int16_t a, int16_t b) { /* a b, |a b| <= 2^30 */
#ifdef __AVR__
    int32_t r;
    uint8_t z;
    __asm__("clr   %[z]\n\t"
            "muls  %B[a], %B[b]\n\t"
            "movw  %C[r], r0\n\t"
            "mul   %A[a], %A[b]\n\t"
            "movw  %A[r], r0\n\t"
            "mulsu %B[a], %A[b]\n\t"
            "sbc   %D[r], %[z]\n\t"
            "add   %B[r], r0\n\t"
            "adc   %C[r], r1\n\t"
            "adc   %D[r], %[z]\n\t"
            "mulsu %B[b], %A[a]\n\t"
            "sbc   %D[r], %[z]\n\t"
            "add   %B[r], r0\n\t"
            "adc   %C[r], r1\n\t"
            "adc   %D[r], %[z]\n\t"
            "clr   r1\n\t"
            : [r] "=&r"(r), [z] "=&r"(z) : [a] "a"(a), [b] "a"(b));
    return r;
#else
    return (int32_t)a * b;
#endif
}
/* floor(a b / 2^16) for any int32 a and b < 2^16, exact: a = ah 2^16 + al (ah = a >> 16 in [-2^15, 2^15), al
 * unsigned), so a b / 2^16 = ah b + al b / 2^16 and only the second term needs the floor; |result| < 2^31 */
static inline __attribute__((always_inline)) int32_t mul_s32u16_sh16(int32_t a, uint16_t b) {
    return mul_su16((int16_t)(a >> 16), b) + (int32_t)(mul_uu16((uint16_t)a, b) >> 16);
}
/* a * b saturated to +/-SAT, exact, for any int32 a and |b| < 2^16 (the 64-bit mul_sat otherwise): two 16 x 16
 * products. |a| b = ah b 2^16 + al b (ah, al: the 16-bit halves of |a|); ah b >= 2^14 means |a b| >= 2^30 > SAT,
 * else ah b 2^16 <= 0x3FFF0000 and a carry out of the 32-bit sum also means > SAT. Same values as mul_sat. */
static __attribute__((noinline)) int32_t mul_sat64(int32_t a, int32_t b) { return mul_sat(a, b); }
static inline __attribute__((always_inline)) int32_t mul_sat16(int32_t a, int32_t b) {
    if (b <= -65536 || b >= 65536) return mul_sat64(a, b); /* out of line: its 64-bit registers stay out of the tick */
    uint32_t ua = a >= 0 ? (uint32_t)a : 0U - (uint32_t)a, ub = b >= 0 ? (uint32_t)b : 0U - (uint32_t)b;
    uint32_t hi = mul_uu16((uint16_t)(ua >> 16), (uint16_t)ub), lo = mul_uu16((uint16_t)ua, (uint16_t)ub), r;
    if (hi > ((uint32_t)SAT >> 16)) r = SAT;
    else {
        r = (hi << 16) + lo;
        if (r < lo || r > (uint32_t)SAT) r = SAT;
    }
    return (a < 0) != (b < 0) ? -(int32_t)r : (int32_t)r;
}
/* (a * b) >> 32 of the sinusoid recurrence from three 16 x 16 products (a = ah 2^16 + al, b likewise; ah, bh
 * signed, al, bl unsigned): ah bh + (ah bl >> 16) + (al bh >> 16), the al bl term and the carries between the
 * partial sums dropped: 0 to 2 LSB below the exact floor (Q31 y: < 1e-9 of full scale a step; the recurrence's
 * gain, ~1 / (1 - r) ~ 50 for the report's 50 ms decay, keeps the sum far below the 1 mA tolerance). Replaces
 * libgcc's 32 x 32 -> 64-bit __mulsidi3 (~250 cycles each in the worst tick, simavr). |result| <= 2^30 + 2^16. */
static inline __attribute__((always_inline)) int32_t mulhi16(int32_t a, int32_t b) {
    int16_t ah = (int16_t)(a >> 16), bh = (int16_t)(b >> 16);
    return mul_ss16(ah, bh) + (mul_su16(ah, (uint16_t)b) >> 16) + (mul_su16(bh, (uint16_t)a) >> 16);
}

/* One step of the wall's passivity observer (po_e above; FirmwareRenderer._observe in logic.py does the same
 * integer arithmetic). x: position (counts); pen: penetration (Q8 counts); ip: k * pen before the clamp (Q24 A,
 * 0 outside the wall); f: this tick's wall current (Q24 A, 0..lim_cont_q24), the F of the next step. Only
 * 16 x 16 -> 32-bit products and byte shifts (a first version with 32-bit products and bit shifts took ~430
 * cycles), every intermediate bounded below 2^31 (comments). Returns 1 when E exceeds the limit: latched in
 * po_unstable and fault_latched until CLEAR_FAULTS. */
static inline __attribute__((always_inline)) uint8_t po_step(int32_t x, int32_t pen, int32_t ip, int32_t f) {
    if (pen <= 0 && po_f == 0 && po_u == 0 && !po_fresh) {
        /* outside the wall after a tick without wall force (most ticks): F dx = 0, dU = 0, f = 0, and the leak
         * only takes E towards 0, never above the limit: the full step below, without the arithmetic */
        po_x16 = (uint16_t)x;
        int16_t eh = (int16_t)(po_e >> 16);
        if (eh) {
            int32_t lk = mul_su16(eh, po_leak_m);
            if (po_leak_sh) lk >>= 8;
            po_e -= lk;
        }
        return 0;
    }
    /* stored energy U = s m / 2 with s = min(k pen, F_c) and m = 2 pen - min(pen, d_s): k pen^2 / 2 below the
     * clamp, F_c (pen - d_s / 2) beyond it (renderer.passivity.wall_energy) */
    int32_t u = 0;
    if (pen > 0) {
        int32_t s = ip, m = pen > PO_PEN_MAX ? PO_PEN_MAX : pen; /* Q8 counts */
        if (s > lim_cont_q24) { /* clamped: m = 2 pen - d_s, 0 <= m < 2^23 (po_ds_q8 <= pen + 1 LSB here) */
            s = lim_cont_q24;
            m += m - po_ds_q8;
            if (m < 0) m = 0;
        }
        uint16_t s16 = (uint16_t)(s >> 8); /* Q16 A: 0 <= s <= lim_cont_q24 < 2^24 (_Static_assert above) */
        if (m < (1L << 17)) /* Q16 A x m / 2 in Q8 (< 2^16) = Q24 -> Q16 */
            u = (int32_t)(mul_uu16(s16, (uint16_t)(m >> 1)) >> 8);
        else { /* m beyond 512 counts: whole counts of m / 2 (< 2^14); U within 0.8 A count, no drift (U is a state) */
            u = (int32_t)mul_uu16(s16, (uint16_t)(m >> 8) >> 1);
            if (u > PO_U_MAX) u = PO_U_MAX;
        }
    }
    uint16_t x16 = (uint16_t)x; /* the position's low 16 bits: a tick moves far less than 2^15 counts */
    if (po_fresh) { /* first tick after RENDER_START / CLEAR_FAULTS / WALL: nothing moved yet */
        po_fresh = 0;
        po_x16 = x16;
        po_u = u;
    }
    int16_t dx = (int16_t)(x16 - po_x16);
    if (dx > PO_DX_MAX) dx = PO_DX_MAX;
    else if (dx < -PO_DX_MAX) dx = -PO_DX_MAX;
    /* leak (1 - a) E as floor(E / 2^16) po_leak_m >> 8 po_leak_sh: one 16 x 16 product. The part of E below one
     * A count (2^16) does not leak: E stays within 1 A count (1-3 % of the limits of 340-2e5 N/m walls) above
     * the exactly leaked sum, on the safe side. */
    int32_t e = po_e; /* -2^30 <= e <= SAT */
    int32_t lk = mul_su16((int16_t)(e >> 16), po_leak_m);
    if (po_leak_sh) lk >>= 8;
    /* |F dx| < 2^16 * 2^13 = 2^29, |dU| <= 2^29: |inc| < 2^30, so |e - lk + inc| < 2^31 before the clamp */
    e += mul_su16(dx, po_f) + (u - po_u) - lk;
    int8_t top = (int8_t)(e >> 24); /* clamp to [-2^30, SAT] by the top byte (a byte move) */
    if (top >= 0x40) e = SAT;
    else if (top < -0x40) e = -SAT;
    po_e = e;
    po_x16 = x16;
    po_u = u;
    po_f = (uint16_t)(f >> 8); /* Q16 A: 0 <= f <= lim_cont_q24 < 2^24 */
    if (e > po_limit) {
        po_unstable = 1;
        fault_latched = 1;
        return 1;
    }
    return 0;
}

/* the clamp's penetration F_c / k in Q8 counts (WALL, LIMITS; 32-bit: F_c < 2^24 in Q24 A), at most PO_PEN_MAX */
static int32_t po_clamp_q8(int32_t lim_q24, int32_t k) {
    if (k <= 0) return PO_PEN_MAX;
    uint32_t l = (uint32_t)(lim_q24 > 0xFFFFFF ? 0xFFFFFF : (lim_q24 < 0 ? 0 : lim_q24));
    uint32_t d = (l * 256UL + (uint32_t)k / 2) / (uint32_t)k;
    return d > (uint32_t)PO_PEN_MAX ? PO_PEN_MAX : (int32_t)d;
}

/* One on-device servo tick: same algorithm as FirmwareRenderer.tick, in fixed point. The two ADC
 * conversions (13 us each) run while the position and wall current are computed. */
static int32_t render_tick(uint32_t t_us, int32_t enc, uint16_t *accel_out, uint16_t *grip_out) {
    adc_start(0);
    int32_t counts = enc - cal_zero;
    int32_t x = cal_sign < 0 ? -counts : counts; /* handle position in counts */
    int32_t old = vel_ring[vel_i];
    uint16_t tick_now = render_tick_n, ticks = (uint16_t)(tick_now - vel_tick[vel_i]);
    vel_ring[vel_i] = x;
    vel_tick[vel_i] = tick_now;
    vel_i = (uint8_t)(vel_i + 1 < VEL_WINDOW ? vel_i + 1 : 0);
    int32_t dc = 0;      /* counts moved over the window (velocity = dc * res * fs / ticks) */
    uint8_t dt = VEL_WINDOW;
    if (vel_filled < VEL_WINDOW) vel_filled++;
    else {
        dc = x - old;
        if (ticks != 0 && ticks != VEL_WINDOW) dt = (uint8_t)(ticks > 255 ? 255 : ticks); /* late ticks */
    }
    int32_t pen = wall_h_q8 - (x << 8); /* penetration, Q8 counts */
    if (rearm_pending && !in_event && tr_k >= tr_n) {
        rearm_n = rearm_pending_n;
        rearm_pending = 0;
    }
    uint8_t start = 0;
    if (pen > 0 && armed) {
        armed = 0;
        if (in_event) finish_event();
        start = 1;
    } else if (!armed && pen < -wall_rearm_q8) {
        armed = 1;
        if (in_event) finish_event();
    }
    /* wall: proportional + damping, pushes only, steady-state limit */
    int32_t i_cmd = 0, ip = 0;
    uint8_t clipped = 0;
    if (pen > 0) {
        int32_t bd = dt < 2 * VEL_WINDOW ? b_wall[dt] : b_wall_1 / dt;
        /* k * pen = (k_wall * pen) >> 8 exactly (logic.py the same), from 16 x 16 products: 0 <= k_wall < 2^30
         * (sat_round) = kh 2^16 + kl, and below the clamp's reach (pc < pen_c_max = SAT / k - 1) the result is below
         * SAT - k. Up to 256 counts (5.6 mm): pen < 2^16, (k pen) >> 8 = (kh pen << 8) + (kl pen >> 8), two products
         * and byte moves; up to 65,536 counts: k pc + (k p8 >> 8) with p8 = pen & 255, four; beyond (or past the
         * clamp's reach) the saturated 64-bit product. (Before: k pc + (k >> 8) p8, two __mulsi3, ~200 cycles.) */
        int32_t pc = pen >> 8;
        uint16_t kh = (uint16_t)((uint32_t)k_wall >> 16), kl = (uint16_t)k_wall;
        if (pc < pen_c_max && pen < 65536L)
            ip = (int32_t)((mul_uu16(kh, (uint16_t)pen) << 8) + (mul_uu16(kl, (uint16_t)pen) >> 8));
        else if (pc < pen_c_max && pc < 65536L) {
            uint16_t p8 = (uint16_t)(pen & 255);
            ip = (int32_t)((mul_uu16(kh, (uint16_t)pc) << 16) + mul_uu16(kl, (uint16_t)pc) + (mul_uu16(kh, p8) << 8) +
                           (mul_uu16(kl, p8) >> 8));
        } else ip = mul_sh8_sat(k_wall, pen);
        /* bd dc saturated, from two 16 x 16 products while |dc| < 2^16 counts per window (the 64-bit product
         * beyond: 1,400 m/s); it had taken the 64-bit product (~150 cycles) above 1.4 m/s, __mulsi3 below */
        int32_t id = mul_sat16(bd, dc);
        int32_t f = ip - id;
        if (f > 0) {
            i_cmd = f;
            if (i_cmd > lim_cont_q24) { i_cmd = lim_cont_q24; clipped = 1; }
        }
    }
    uint16_t accel_raw = adc_result();
    adc_start(1);
    if (start) {
        in_event = 1;
        ev_t_us = t_us;
        ev_dcounts = dc; ev_ticks = dt;
        ev_pen_q8 = 0; ev_peak_q8 = 0; ev_clipped = 0; ev_kind = tr_kind;
        tr_k = 0;
        if (tr_kind == 1 || tr_kind == 2) {
            tr_n = tr_param_n;
            int32_t g = dt < 2 * VEL_WINDOW ? tr_gain[dt] : tr_gain_1 / dt;
            tr_scale_q24 = dc < 0 ? mul_sat16(g, -dc) : 0; /* amplitude * incoming speed / (N/A) */
            /* the sinusoid's first two currents z_0, z_1 (Q24 A x Q31 >> 31; |s| < 1, 0 <= amplitude <= SAT), kept
             * in sin_y1 and sin_y2 until the recurrence takes over at tr_k = 2 */
            if (tr_kind == 2) {
                sin_y1 = mulhi16(tr_scale_q24, sin_s1) << 1;
                sin_y2 = mulhi16(tr_scale_q24, sin_s2) << 1;
            }
        }
        else if (tr_kind == 4) tr_n = rearm_n;
        else tr_n = 0;
    }
    if (po_limit && po_step(x, pen, ip, i_cmd)) { /* the wall generates energy: stop, zero output */
        i_cmd = 0;
        clipped = 0;
        tr_n = tr_k;
        if (in_event) finish_event();
    }
    /* transient overlay */
    if (tr_k < tr_n) {
        if (ev_kind == 1) i_cmd += tr_scale_q24;
        else if (ev_kind == 2) {
            /* z_k = (c1 z_{k-1} - c2 z_{k-2}) >> 30 (Q30 x Q24 -> Q24): |z| <= amplitude <= SAT < 2^30 (|y| <= 1),
             * so each mulhi16 is below 2^29 and their difference below 2^28 before the << 2. Each mulhi16 is 0..2
             * LSB (Q22) low: < 0.5 uA a step, ~25 uA summed through the recurrence's gain (~50): far inside 1 mA */
            int32_t z;
            if (tr_k >= 2) {
                z = (mulhi16(sin_c1, sin_y1) - mulhi16(sin_c2, sin_y2)) << 2;
                sin_y2 = sin_y1;
                sin_y1 = z;
            } else if (tr_k == 0) z = sin_y1; /* z_0 */
            else { /* z_1: from now on sin_y1 = z_{k-1}, sin_y2 = z_{k-2} */
                z = sin_y2;
                sin_y2 = sin_y1;
                sin_y1 = z;
            }
            i_cmd += z;
        } else if (ev_kind == 4) i_cmd += rearm_buf[tr_k];
        tr_k++;
    }
    if (i_cmd > lim_peak_q24) { i_cmd = lim_peak_q24; clipped = 1; }
    else if (i_cmd < -lim_peak_q24) { i_cmd = -lim_peak_q24; clipped = 1; }
    /* protect the winding: fade out between 70 % and 90 % of the rise; the factor (Q16) changes with the
     * temperature, at the thermal steps only */
    over_temp = temp_fade_q16 != 0;
    if (over_temp) i_cmd = mul_s32u16_sh16(i_cmd, (uint16_t)(temp_fade_q16 - 1));
    /* Q12 A, floor(i / 2^12) from bytes: the top 16 bits (Q8) times 16 plus bits 12..15 (a 12-bit shift of an
     * int32 is a loop on the AVR: ~85 cycles on simavr); |i12| <= 2^13 for |i| <= 2 A (peak limit), i12^2 <= 2^26,
     * 16 of them fit */
    int16_t i12 = (int16_t)(((uint16_t)(i_cmd >> 16) << 4) | ((uint8_t)(i_cmd >> 8) >> 4));
    heat_acc += mul_ss16(i12, i12);
    if (++heat_n >= THERMAL_EVERY) { /* the block's sum (Q16 A^2: a byte move) to the main loop, which steps the model */
        if (heat_posts < 255) { heat_post += (uint32_t)heat_acc >> 8; heat_posts++; }
        heat_acc = 0;
        heat_n = 0;
    }
    clipping = clipped;
    uint16_t grip_raw = adc_result();
    if (start) ev_grip_raw = grip_raw;
    if (in_event) {
        if (pen > ev_pen_q8) ev_pen_q8 = pen;
        int32_t a = ((int32_t)accel_raw << 8) - cal_a_off_q8;
        if (a < 0) a = -a;
        if (a > ev_peak_q8) ev_peak_q8 = a;
        if (clipped) ev_clipped = 1;
    }
    *accel_out = accel_raw;
    *grip_out = grip_raw;
    return i_cmd;
}

/* The thermal model, stepped by the main loop (thermal_service, from flush_telemetry) once per block of
 * THERMAL_EVERY ticks the tick posted (heat_post, heat_posts): the tick only sums i^2 (it had stepped the model
 * itself every 16th tick with two 64-bit products, ~400 cycles, in the worst tick on simavr). tau is 30 s: a
 * main loop behind by a frame's handling (~1 ms) changes nothing; blocks it did not take yet are stepped with
 * their mean. heat = mean i^2 R_w R_th in Q20 K: the block sum b (Q16 A^2 over 16 ticks, < 2^22) times
 * R_w R_th / 16 in Q20 = (b << 8) HEAT_Q8 >> 16 (R_w R_th in Q8, 16 bits, within 2e-5 of itself). T += (heat - T)
 * alpha with alpha in Q24 (12 bits, within 2e-5: tau 30 s -> 29.9995 s), |heat - T| < 2^30: floor((heat - T)
 * alpha_q24 / 2^16) >> 8, the Q20 step as before (T settles within 0.007 K of heat). The fade-out factor
 * (T_end - T) / (T_end - T_att) in Q16 (within 2^-16 of the Q20 one the tick had computed, 30 uA at 2 A) for the
 * ticks to come; temp_fade_q16 is 0 below T_att (no fade), else factor + 1 (1..65536). */
#define ALPHA_Q24 ((uint16_t)(16777216.0 * THERMAL_EVERY / (TAU_THERMAL_S * SERVO_HZ) + 0.5))
_Static_assert(16777216.0 * THERMAL_EVERY / (TAU_THERMAL_S * SERVO_HZ) < 65535.0, "alpha in Q24 fits 16 bits");
#define HEAT_Q8 ((uint16_t)(R_WINDING_OHM * R_THERMAL_K_W * 256.0f + 0.5f)) /* K/A^2, Q8 */
_Static_assert(R_WINDING_OHM * R_THERMAL_K_W * 256.0f < 65535.0f, "R_w R_th in Q8 fits 16 bits (below 256 K/A^2)");
_Static_assert(THERMAL_EVERY == 16, "the block sum of 16 ticks' i^2 times R_w R_th / 16 is the mean's heat");
/* (T_end - T) / (T_end - T_att) in Q16 = ((T_end - T) in Q20 >> FADE_SH) * FADE_INV >> 16 */
#define FADE_Q20 (T_Q20(T_END_K) - T_Q20(T_ATTENUATE_K))
#define FADE_SH 8 /* (T_end - T) >> 8: Q12 K, below 2^16 for a fade range up to 16 K */
#define FADE_INV_Q ((uint32_t)(4294967296.0 / FADE_Q20 * 256.0 + 0.5)) /* 2^40 / range: factor Q16 = x * inv >> 16 */
_Static_assert((T_END_K - T_ATTENUATE_K) <= 16.0f && 4294967296.0 / FADE_Q20 * 256.0 < 4294967296.0,
               "the fade range (T_end - T_att) is at most 16 K: Q12 K fits 16 bits");
static void thermal_step(uint32_t block_q16) {
    int32_t heat = mul_s32u16_sh16((int32_t)(block_q16 << 8), HEAT_Q8); /* < 2^30 * 2^16 / 2^16 */
    int32_t temp = temp_q20;
    temp += mul_s32u16_sh16(heat - temp, ALPHA_Q24) >> 8;
    temp_q20 = temp;
    uint32_t f = 0;
    if (temp > T_Q20(T_ATTENUATE_K)) {
        int32_t k = T_Q20(T_END_K) - temp; /* 0 .. range */
        if (k < 0) k = 0;
        uint16_t x = (uint16_t)((uint32_t)k >> FADE_SH); /* < 2^16: range <= 16 K (assert) and T > T_att */
        f = 1 + ((mul_uu16(x, (uint16_t)FADE_INV_Q) >> 16) + (uint32_t)x * (uint16_t)(FADE_INV_Q >> 16));
    }
    TICK_LOCK(); /* the tick reads it */
    temp_fade_q16 = f;
    TICK_UNLOCK();
}
static void thermal_service(void) { /* main loop */
    if (!heat_posts) return;
    TICK_LOCK();
    uint32_t sum = heat_post;
    uint8_t n = heat_posts;
    heat_post = 0;
    heat_posts = 0;
    TICK_UNLOCK();
    uint32_t block = n == 1 ? sum : sum / n;
    while (n--) thermal_step(block);
}

static void stop_render(void) { /* main loop, tick locked */
    if (!rendering) return;
    rendering = 0;
    if (in_event) finish_event();
    motor_set_q24(0);
    watchdog_armed = 0;
}

/* every float finite and within +/-1e30: compare the bit patterns (|f| <= 1e30 <=> bits <= 0x7149F2CA;
 * NaN and inf are above), ~20 cycles per value instead of three soft-float compares */
static uint8_t finite4(const uint8_t *p, uint8_t n) {
    for (uint8_t i = 0; i < n; i++)
        if ((get_u32(p + 4 * i) & 0x7FFFFFFFUL) > 0x7149F2CAUL) return 0;
    return 1;
}

/* float -> int32 without overflow (the host's values are finite but may be huge) */
static int32_t sat_round(float f) {
    if (f > 1.0e9f) return 1000000000L;
    if (f < -1.0e9f) return -1000000000L;
    return (int32_t)lroundf(f);
}
static int32_t q24_of(float amps) { return sat_round(amps * Q24); }

/* q24_of() of a float given by its IEEE-754 bits, in integers (REARM_DATA: the soft-float product and lroundf
 * took ~175 cycles a sample more; a 24-sample frame's own handling 7,600 -> 3,400 cycles on simavr), the same
 * value for every finite float: f 2^24 is
 * exact in float (finite4: |f| <= 1e30, so no overflow), = m 2^(e - 126) with m the 24-bit significand (normal
 * numbers; subnormals are below 2^-126 and give 0), rounded half away from zero as lroundf, saturated at +/-1e9 as
 * sat_round. (tests/devices/firmware/test_c_firmware.py compares the two over all exponents.) */
static int32_t q24_of_bits(uint32_t bits) {
    /* the exponent from the top two bytes (a 23-bit shift of an int32 is a ~125-cycle loop on the AVR) */
    uint8_t e = (uint8_t)((uint8_t)(bits >> 24) << 1 | (uint8_t)(bits >> 16) >> 7);
    if (e < 126 - 24) return 0; /* |f 2^24| < 2^-1 (and zero, subnormals): rounds to 0 */
    uint32_t m = (bits & 0x7FFFFFUL) | 0x800000UL, v;
    if (e >= 126 + 7) v = 1000000001UL; /* >= 2^30: beyond the saturation */
    else if (e >= 126) v = m << (e - 126); /* < 2^30 */
    else {
        uint8_t r = (uint8_t)(126 - e); /* 1..24 */
        v = m + (1UL << (r - 1)); /* half away from zero (on the magnitude), then >> r: whole bytes first */
        if (r >= 16) { v >>= 16; r -= 16; }
        if (r >= 8) { v >>= 8; r -= 8; }
        v >>= r;
    }
    if (v > 1000000000UL) v = 1000000000UL;
    return (bits & 0x80000000UL) ? -(int32_t)v : (int32_t)v;
}

/* per-window-length gains: value per count moved over t ticks = per_count_per_s * fs / t */
static void window_gains(int32_t *table, int32_t *one, float q24_per_count_at_1_tick) {
    for (uint8_t t = 1; t < 2 * VEL_WINDOW; t++) table[t] = sat_round(q24_per_count_at_1_tick / (float)t);
    table[0] = 0;
    *one = sat_round(q24_per_count_at_1_tick);
}

static void handle_frame(void) {
    uint8_t type = parser.buf[3], seq = parser.buf[4], n = parser.buf[2];
    const uint8_t *p = parser.buf + 5;
    if ((!mode_on_device && type == MSG_CURRENT) || rendering) {
        TICK_LOCK();
        last_cmd_tick = tick_count;
        if (tripped) { tripped = 0; trip_report = 1; } /* host back: resume, report the trip once */
        TICK_UNLOCK();
    }
    switch (type) {
    case MSG_HELLO:
        if (n != 2) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        send_info();
        break;
    case MSG_CURRENT: {
        watchdog_armed = 1;
        cmd_seq = seq;
        if (rendering) break;
        if (n != 4) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        float amps = get_f32(p);
        state_slot_t s;
        /* NaN or +-inf (exponent bits all ones) latches FAULT; a finite value beyond the amplifier is clamped */
        if ((get_u32(p) & 0x7F800000UL) == 0x7F800000UL) fault_latched = 1;
        if (fault_latched) amps = 0.0f;
        /* streaming: the command just reset the watchdog, so the tick leaves the motor and the ADC alone
         * meanwhile. On-device mode (not rendering) a CURRENT arms the watchdog but does not feed it: once it
         * has tripped the output stays zero until CLEAR_FAULTS (emulator.py _on_current); `tripped` is read
         * with the tick locked, so a trip between here and the write cannot be undone by it. */
        int32_t q = (int32_t)((amps > I_AMP_A ? I_AMP_A : (amps < -I_AMP_A ? -I_AMP_A : amps)) * Q24);
        TICK_LOCK();
        motor_set_q24(tripped ? 0 : q);
        TICK_UNLOCK();
        s.accel_raw = adc_read(0);
        s.grip_raw = adc_read(1);
        TICK_LOCK();
        s.t_us = tick_count * (1000000UL / SERVO_HZ);
        s.current_q24 = applied_q24; s.status = status_bits(); s.cmd_seq = cmd_seq;
        TICK_UNLOCK();
        s.enc = encoder_read();
        send_state_slot(&s);
        break;
    }
    case MSG_KEEPALIVE:
        break;
    case MSG_PING:
        send(MSG_PONG, p, n);
        break;
    case MSG_SET_MODE:
        if (n != 3 || p[0] > 1 || get_u16(p + 1) < 1) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        TICK_LOCK();
        if (p[0] == 0) stop_render();
        mode_on_device = p[0];
        decimation = (uint8_t)(get_u16(p + 1) > 255 ? 255 : get_u16(p + 1));
        TICK_UNLOCK();
        ack(type, seq);
        break;
    case MSG_SET_WATCHDOG:
        if (n != 2 || get_u16(p) < 1) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        TICK_LOCK();
        watchdog_ms = get_u16(p);
        watchdog_ticks = (uint32_t)watchdog_ms * (SERVO_HZ / 1000UL);
        TICK_UNLOCK();
        ack(type, seq);
        break;
    case MSG_CLEAR_FAULTS:
        TICK_LOCK();
        tripped = 0; fault_latched = 0; last_cmd_tick = tick_count;
        po_unstable = 0; po_e = 0; po_fresh = 1; /* a fresh observer: the energy that tripped it is gone */
        TICK_UNLOCK();
        ack(type, seq);
        break;
    case MSG_SET_CALIBRATION: {
        if (n != 21 || !finite4(p + 5, 4) || get_f32(p + 5) <= 0 || get_f32(p + 13) <= 0 ||
            ((int8_t)p[4] != 1 && (int8_t)p[4] != -1)) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        float a_off = get_f32(p + 9);
        int32_t a_off_q8 = sat_round(a_off * 256.0f);
        TICK_LOCK();
        cal_zero = (int32_t)get_u32(p); cal_sign = (int8_t)p[4];
        cal_a_scale = get_f32(p + 5); cal_a_off = a_off; cal_a_off_q8 = a_off_q8;
        cal_g_scale = get_f32(p + 13); cal_g_off = get_f32(p + 17);
        TICK_UNLOCK();
        ack(type, seq);
        break;
    }
    case MSG_WALL: {
        /* 16 bytes (protocol 1.0: no observer) or 24 (1.1: + observer limit J >= 0, 0 = off, and leak 0..1) */
        if ((n != 16 && n != 24) || !finite4(p, n / 4) || get_f32(p + 4) < 0 || get_f32(p + 8) < 0 ||
            get_f32(p + 12) < 0 || (n == 24 && (get_f32(p + 16) < 0 || get_f32(p + 20) < 0 || get_f32(p + 20) >= 1))) {
            nak(type, seq, NAK_BAD_PAYLOAD); break;
        }
        int32_t plim = 0, lm = 0;
        uint8_t lsh = 0;
        if (n == 24 && get_f32(p + 16) > 0) {
            plim = sat_round(get_f32(p + 16) * PO_Q16_PER_J); /* J -> Q16 A count, at most 1e9 (0.9 J) */
            if (plim < 1) plim = 1;
            /* the leak as a 16-bit multiplier: Q24 while it fits (windows from 0.25 s at 4 kHz, >= 13 bits at
             * 1 s), else Q16 (shorter windows; a leak of 1 or more per tick is refused above) */
            lm = sat_round(get_f32(p + 20) * 16777216.0f);
            lsh = 1;
            if (lm > 65535) { lm = sat_round(get_f32(p + 20) * 65536.0f); lsh = 0; }
            if (lm > 65535) lm = 65535;
        }
        /* SI -> fixed point, once (soft-float here, never in the tick) */
        int32_t h = sat_round(get_f32(p) * (256.0f / POS_RES_M));
        int32_t k = sat_round(get_f32(p + 4) * (POS_RES_M / FORCE_PER_AMP) * Q24); /* Q24 A per count */
        int32_t rearm = sat_round(get_f32(p + 12) * (256.0f / POS_RES_M));
        int32_t bw[2 * VEL_WINDOW], b1;
        window_gains(bw, &b1, get_f32(p + 8) * (POS_RES_M * SERVO_HZ / FORCE_PER_AMP) * Q24);
        int32_t pcm = k > 0 ? SAT / k - 1 : 0x7FFFFFFFL;
        int32_t ds = po_clamp_q8(lim_cont_q24, k); /* lim_cont_q24: written by this (main-loop) code only */
        TICK_LOCK();
        wall_h_q8 = h; k_wall = k; pen_c_max = pcm; wall_rearm_q8 = rearm; b_wall_1 = b1;
        TICK_UNLOCK();
        TICK_LOCK();
        po_limit = plim; po_leak_m = (uint16_t)lm; po_leak_sh = lsh; po_ds_q8 = ds; po_e = 0; po_fresh = 1;
        TICK_UNLOCK();
        for (uint8_t t = 0; t < 2 * VEL_WINDOW; t++) { /* one entry at a time: each stays whole */
            TICK_LOCK();
            b_wall[t] = bw[t];
            TICK_UNLOCK();
        }
        ack(type, seq);
        break;
    }
    case MSG_LIMITS: {
        if (n != 12 || !finite4(p, 3)) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        /* as logic.set_limits after emulator._on_limits: clamp to the device's limits (peak also to the
         * amplifier limit), then require 0 <= continuous <= peak: a negative or too small amplifier_A is refused */
        float cf = fminf(get_f32(p), I_CONT_A), pf = fminf(fminf(get_f32(p + 4), get_f32(p + 8)), I_PEAK_A);
        if (!(cf >= 0.0f && pf >= cf)) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        int32_t c = q24_of(cf);
        int32_t pk = q24_of(pf);
        if (pk < 0) pk = 0; /* never a negative peak limit: render_tick would drive -peak with no contact */
        int32_t ds = po_clamp_q8(c, k_wall);
        TICK_LOCK();
        lim_cont_q24 = c; lim_peak_q24 = pk; po_ds_q8 = ds;
        TICK_UNLOCK();
        ack(type, seq);
        break;
    }
    case MSG_TRANSIENT_PARAM: {
        if (n != 17 || p[0] > 2 || !finite4(p + 1, 4) ||
            (p[0] && (get_f32(p + 1) < 0 || get_f32(p + 5) <= 0)) ||
            (p[0] == 2 && !(get_f32(p + 9) > 0 && get_f32(p + 9) < SERVO_HZ / 2))) {
            nak(type, seq, NAK_BAD_PAYLOAD); break;
        }
        float amp = get_f32(p + 1), dur = get_f32(p + 5), freq = get_f32(p + 9);
        uint16_t nn = (uint16_t)floorf(dur * SERVO_HZ + 1e-3f);
        int32_t g[2 * VEL_WINDOW], g1, c1 = 0, c2 = 0, s1 = 0, s2 = 0;
        window_gains(g, &g1, amp * (POS_RES_M * SERVO_HZ / FORCE_PER_AMP) * Q24);
        if (p[0] == 2) { /* once per upload, never in the servo tick */
            float r = expf(-4.6051702f / (dur * SERVO_HZ)), w = 6.2831853f * freq / SERVO_HZ;
            c1 = (int32_t)lroundf(2.0f * r * cosf(w) * 1073741824.0f);  /* Q30 */
            c2 = (int32_t)lroundf(r * r * 1073741824.0f);
            s1 = (int32_t)lroundf(r * sinf(w) * 2147483520.0f);          /* Q31 (largest float below 2^31) */
            s2 = (int32_t)lroundf(r * r * sinf(2.0f * w) * 2147483520.0f);
        }
        TICK_LOCK();
        tr_kind = p[0];
        tr_param_n = nn;
        tr_gain_1 = g1;
        sin_c1 = c1; sin_c2 = c2; sin_s1 = s1; sin_s2 = s2;
        TICK_UNLOCK();
        for (uint8_t t = 0; t < 2 * VEL_WINDOW; t++) {
            TICK_LOCK();
            tr_gain[t] = g[t];
            TICK_UNLOCK();
        }
        ack(type, seq);
        break;
    }
    case MSG_REARM_DATA: {
        uint32_t off = get_u32(p);
        uint8_t k = (uint8_t)((n - 4) / 4);
        if (n < 4 || (n - 4) % 4) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        /* no off + k: it wraps in 32 bits (off = 0xFFFFFFFF passed and wrote outside rearm_buf); the size
         * before the values, as logic.rearm_data */
        if (off > REARM_MAX || k > REARM_MAX - off) { nak(type, seq, NAK_TOO_LARGE); break; }
        if (!finite4(p + 4, k)) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        TICK_LOCK();
        uint8_t playing = in_event && tr_k < tr_n && ev_kind == 4;
        TICK_UNLOCK();
        if (playing) { nak(type, seq, NAK_BAD_STATE); break; }
        for (uint8_t i = 0; i < k; i++) { /* A -> Q24 A here, so the tick adds integers */
            int32_t q = q24_of_bits(get_u32(p + 4 + 4 * i)); /* = q24_of(the float), in integers */
            TICK_LOCK();
            rearm_buf[off + i] = q;
            TICK_UNLOCK();
        }
        ack(type, seq);
        break;
    }
    case MSG_REARM_COMMIT:
        if (n != 4 || get_u32(p) > REARM_MAX) { nak(type, seq, NAK_TOO_LARGE); break; }
        TICK_LOCK();
        rearm_pending_n = (uint16_t)get_u32(p);
        rearm_pending = 1;
        tr_kind = 4;
        TICK_UNLOCK();
        ack(type, seq);
        break;
    case MSG_TABLE_BEGIN:
    case MSG_TABLE_DATA:
    case MSG_TABLE_COMMIT:
        nak(type, seq, NAK_TOO_LARGE); /* 2 kB of RAM: the host re-arms a sampled transient instead */
        break;
    case MSG_RENDER_START:
        if (!mode_on_device) { nak(type, seq, NAK_BAD_STATE); break; }
        ack(type, seq);
        TICK_LOCK();
        if (rendering) { /* a repeat (the host retried: our ACK was late or lost): nothing restarts mid-run */
            last_cmd_tick = tick_count;
        } else {
            rendering = 1; watchdog_armed = 1; last_cmd_tick = tick_count;
            armed = 0; in_event = 0; tr_k = tr_n = 0; vel_filled = 0;
            po_e = 0; po_f = 0; po_fresh = 1; /* an UNSTABLE trip stays latched until CLEAR_FAULTS */
        }
        TICK_UNLOCK();
        break;
    case MSG_RENDER_STOP:
        TICK_LOCK();
        stop_render();
        TICK_UNLOCK();
        ack(type, seq);
        break;
    default:
        nak(type, seq, NAK_UNKNOWN_TYPE);
    }
}

/* Trace marks on the general-purpose I/O register GPIOR0 (one `out` instruction, no pin): the
 * simavr harness (fw_sim.c) times the servo tick and the frame handling from them. */
#define TRACE_MARK(v) (GPIOR0 = (v))
#define MARK_TICK_START 1
#define MARK_TICK_END 2
#define MARK_FRAME_START 3
#define MARK_FRAME_END 4

/* One servo period (in the Timer1 interrupt): watchdog, then on-board rendering and telemetry. */
static uint8_t dec_count;
static void servo_tick_body(void) {
    uint32_t tk, t_us;
    cli(); tk = tick_count; t_us = tick_us; sei(); /* 32-bit counters written by the timer interrupt: read whole */
    render_tick_n = (uint16_t)tk;
    int32_t enc = encoder_read(); /* every tick, so the delta stays small */
    /* device-side watchdog: no command within watchdog_ms -> zero current, latched, reported */
    if (watchdog_armed && !tripped && tk - last_cmd_tick > watchdog_ticks) {
        tripped = 1;
        if (in_event) ev_tripped = 1;
        motor_set_q24(0);
        if (!rendering) {
            uint16_t acc = adc_read(0), grip = adc_read(1);
            post_state(t_us, enc, acc, grip);
        }
    }
    if (!rendering) return;
    uint16_t acc, grip;
    int32_t q = 0;
    if (!po_unstable) q = render_tick(t_us, enc, &acc, &grip); /* the tick that trips returns 0 */
    else { acc = adc_read(0); grip = adc_read(1); } /* stopped by the observer: telemetry only, zero output */
    motor_set_q24(tripped || fault_latched ? 0 : q);
    tick_probe.t_us = t_us; tick_probe.enc = enc; tick_probe.accel_raw = acc; tick_probe.grip_raw = grip;
    tick_probe.current_q24 = applied_q24;
    if (++dec_count >= decimation) {
        dec_count = 0;
        post_state(t_us, enc, acc, grip);
    }
}

static void servo_tick(void) {
    TRACE_MARK(MARK_TICK_START);
    servo_tick_body();
    TRACE_MARK(MARK_TICK_END);
}

/* Parse received bytes, a bounded number per pass so the telemetry goes out between them. */
#define RX_MAX_PER_LOOP 32
static void service_uart(void) {
    uint8_t n = 0;
    while (rx_tail != rx_head && n < RX_MAX_PER_LOOP) {
        n++;
        uint8_t c = rx_buf[rx_tail];
        rx_tail = (uint8_t)((rx_tail + 1) & (RX_SIZE - 1));
        if (hfam_parse_byte(&parser, c)) {
            TRACE_MARK(MARK_FRAME_START);
            handle_frame();
            TRACE_MARK(MARK_FRAME_END);
            flush_telemetry();
        } else if ((n & 3) == 0) {
            flush_telemetry(); /* every 4th byte (~0.1 ms): per byte it took a quarter of the parse time */
        }
    }
}

#ifndef HFAM_HOST_HARNESS
int main(void) {
    wdt_enable(WDTO_60MS);
    hw_init();
    uart_init();
    motor_set_q24(0);
    sei();
    for (;;) {
        wdt_reset();
        service_uart();
        flush_telemetry();
    }
}
#endif
