/* Reference firmware for a Hapkit-style 1-DOF paddle on an ATmega328P (Arduino Uno/Nano, 16 MHz).
 *
 * Speaks protocol 1.0 of docs/protocol.md over the UART at 1 Mbaud (U2X, exact at 16 MHz; the
 * host opens the port at any nominal baud the USB-serial bridge maps to 1 Mbaud, or use a
 * native-USB board). Same behaviour as the Python emulator (devices/firmware/emulator.py +
 * devices/firmware/logic.py): hello/INFO, streaming (one CURRENT in -> one STATE out),
 * on-device rendering of wall + pulse / decaying sinusoid / host re-armed sampled transient
 * with a steady-state and a peak current limit (thesis Fig. 4.9), contact events, and a
 * watchdog that zeroes the motor while the host is quiet (reported; output resumes with the host).
 *
 * Hardware (pins as on an Uno; change the #defines for another board):
 *   quadrature encoder A/B on INT0 (PD2) / INT1 (PD3), x4 decoding in the interrupts;
 *   motor driver PWM on OC2B (PD3 is taken, so OC2A = PB3 / D11), direction on PB0 (D8),
 *   current = duty * PWM_FULL_SCALE_A (open-loop current drive through a current-mode driver);
 *   accelerometer (analog, e.g. ADXL321) on ADC0, force-sensing resistor divider on ADC1.
 * Servo tick: Timer1 CTC at SERVO_HZ; the main loop runs one tick per interrupt flag and
 * services the UART between ticks. The AVR hardware watchdog (60 ms) resets a hung board.
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
#define REARM_MAX 128                    /* sampled transient buffer (floats): 512 of the 2048 bytes of RAM */
#define VEL_WINDOW 4
#define FORCE_PER_AMP (GEAR_RATIO * KT_NM_A / HANDLE_LENGTH_M)
#define POS_RES_M (2.0f * 3.14159265f * HANDLE_LENGTH_M / (4.0f * ENCODER_LINES * GEAR_RATIO))

/* ---- UART ring buffers ------------------------------------------------------------ */
#define RX_SIZE 256
#define TX_SIZE 256
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint16_t tx_head, tx_tail;

ISR(USART_RX_vect) {
    uint8_t c = UDR0;
    uint8_t next = (uint8_t)(rx_head + 1);
    if (next != rx_tail) {
        rx_buf[rx_head] = c;
        rx_head = next;
    }
}

ISR(USART_UDRE_vect) {
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint16_t)((tx_tail + 1) % TX_SIZE);
}

static void uart_init(void) {
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / (8UL * UART_BAUD) - 1);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

/* Queue bytes; a frame that does not fit is dropped whole (the host sees a sequence gap). */
static void uart_write(const uint8_t *data, uint16_t n) {
    uint16_t used = (uint16_t)((tx_head + TX_SIZE - tx_tail) % TX_SIZE);
    if (used + n >= TX_SIZE) return;
    for (uint16_t i = 0; i < n; i++) {
        tx_buf[tx_head] = data[i];
        tx_head = (uint16_t)((tx_head + 1) % TX_SIZE);
    }
    UCSR0B |= _BV(UDRIE0);
}

/* ---- encoder (x4 quadrature on INT0/INT1) ---------------------------------------- */
static volatile int32_t encoder_count;
static volatile uint8_t enc_prev;
static const int8_t QDEC[16] = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};

static inline void encoder_update(void) {
    uint8_t ab = (uint8_t)((PIND >> 2) & 0x03);
    encoder_count += QDEC[(enc_prev << 2) | ab];
    enc_prev = ab;
}
ISR(INT0_vect) { encoder_update(); }
ISR(INT1_vect) { encoder_update(); }

/* ---- time, ADC, motor -------------------------------------------------------------- */
static volatile uint8_t tick_flag;
static volatile uint32_t tick_count;
ISR(TIMER1_COMPA_vect) {
    tick_count++;
    tick_flag = 1;
}

static uint16_t adc_read(uint8_t channel) {
    ADMUX = _BV(REFS0) | (channel & 0x07);
    ADCSRA |= _BV(ADSC);
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}

static float applied_A;
static void motor_set(float amps) {
    if (!(amps == amps)) amps = 0.0f; /* NaN never reaches the motor */
    if (amps > I_AMP_A) amps = I_AMP_A;
    if (amps < -I_AMP_A) amps = -I_AMP_A;
    applied_A = amps;
    if (amps >= 0) PORTB &= (uint8_t)~_BV(PB0); else PORTB |= _BV(PB0);
    float duty = fabsf(amps) / PWM_FULL_SCALE_A;
    OCR2A = (uint8_t)(duty >= 1.0f ? 255 : duty * 255.0f);
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
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS10);
    OCR1A = (uint16_t)(F_CPU / SERVO_HZ - 1);
    TIMSK1 = _BV(OCIE1A);
}

/* ---- protocol state ------------------------------------------------------------------- */
static hfam_parser_t parser;
static uint8_t tx_seq, cmd_seq;
static uint8_t mode_on_device, rendering, decimation = 1;
static uint8_t tripped, trip_report, ev_tripped, fault_latched, watchdog_armed;
static uint16_t watchdog_ms = WATCHDOG_MS_DEFAULT;
static uint32_t last_cmd_tick;

/* calibration uploaded by the host */
static int32_t cal_zero;
static int8_t cal_sign = 1;
static float cal_a_scale = ACCEL_SCALE_M_S2_PER_COUNT, cal_a_off = ACCEL_OFFSET_COUNTS;
static float cal_g_scale = GRIP_SCALE_N_PER_COUNT, cal_g_off = GRIP_OFFSET_COUNTS;

/* renderer (devices/firmware/logic.py) */
static float wall_h, wall_k, wall_b, wall_rearm = 0.001f, lim_cont, lim_peak;
static uint8_t tr_kind; /* 0 none, 1 pulse, 2 sinusoid, 4 re-armed buffer */
static float tr_amp, tr_dur, tr_freq;
static uint16_t tr_param_n;
static float rearm_buf[REARM_MAX];
static uint16_t rearm_n, rearm_pending_n;
static uint8_t rearm_pending;
static float vel_ring[VEL_WINDOW];
static uint8_t vel_i, vel_filled;
static uint8_t armed, in_event, ev_clipped, ev_kind, clipping, over_temp;
static float temp_rise_K; /* first-order winding model: dT = (i^2 R_w R_th - T) dt / tau */
static uint16_t tr_k, tr_n, ev_index;
static float tr_scale, ev_v, ev_grip, ev_pen, ev_peak;
static uint32_t ev_t_us;

#define MAX_TX_PAYLOAD 120 /* INFO is the longest frame the firmware sends; PONG echoes are truncated */
static void send(uint8_t type, const uint8_t *payload, uint8_t n) {
    uint8_t frame[MAX_TX_PAYLOAD + HFAM_OVERHEAD];
    if (n > MAX_TX_PAYLOAD) n = MAX_TX_PAYLOAD;
    uint16_t len = hfam_encode(frame, type, tx_seq++, payload, n);
    uart_write(frame, len);
}

static void ack(uint8_t type, uint8_t seq) {
    uint8_t p[2] = {type, seq};
    send(MSG_ACK, p, 2);
}

static void nak(uint8_t type, uint8_t seq, uint8_t code) {
    uint8_t p[3] = {type, seq, code};
    send(MSG_NAK, p, 3);
}

static uint32_t now_us(void) { return tick_count * (1000000UL / SERVO_HZ); }

static void send_info(void) {
    uint8_t p[120];
    uint8_t *q = p;
    *q++ = HFAM_PROTO_MAJOR; *q++ = HFAM_PROTO_MINOR; *q++ = FW_MAJOR; *q++ = FW_MINOR; *q++ = FW_PATCH;
    put_u32(q, ENCODER_LINES); q += 4;
    const float f1[9] = {GEAR_RATIO, HANDLE_LENGTH_M, KT_NM_A, I_CONT_A, I_PEAK_A, I_AMP_A, (float)SERVO_HZ,
                         ACCEL_RANGE_M_S2, ACCEL_SCALE_M_S2_PER_COUNT};
    for (uint8_t i = 0; i < 9; i++, q += 4) put_f32(q, f1[i]);
    put_u16(q, (uint16_t)ACCEL_OFFSET_COUNTS); q += 2;
    put_f32(q, GRIP_SCALE_N_PER_COUNT); q += 4;
    put_u16(q, (uint16_t)GRIP_OFFSET_COUNTS); q += 2;
    const float f2[6] = {0.0f, GRIP_MAX_N, R_WINDING_OHM, R_THERMAL_K_W, TAU_THERMAL_S, T_MAX_RISE_K};
    for (uint8_t i = 0; i < 6; i++, q += 4) put_f32(q, f2[i]);
    put_u16(q, watchdog_ms); q += 2;
    put_u16(q, CAP_STREAMING | CAP_ON_DEVICE | CAP_PARAM_TRANSIENT | CAP_REARM_TRANSIENT); q += 2;
    put_u32(q, REARM_MAX); q += 4;
    put_u16(q, 0); q += 2; /* flags: not simulated */
    *q++ = sizeof(DEVICE_NAME) - 1; memcpy(q, DEVICE_NAME, sizeof(DEVICE_NAME) - 1); q += sizeof(DEVICE_NAME) - 1;
    *q++ = sizeof(SERIAL_NUMBER) - 1; memcpy(q, SERIAL_NUMBER, sizeof(SERIAL_NUMBER) - 1);
    q += sizeof(SERIAL_NUMBER) - 1;
    send(MSG_INFO, p, (uint8_t)(q - p));
}

static void send_state(uint32_t t_us, int32_t enc, uint16_t accel_raw, uint16_t grip_raw) {
    uint8_t p[16];
    put_u32(p, t_us);
    put_u32(p + 4, (uint32_t)enc);
    put_u16(p + 8, accel_raw); /* raw ADC counts; the host subtracts the INFO/calibration offset */
    put_u16(p + 10, grip_raw);
    p[12] = (uint8_t)(((tripped || trip_report) ? ST_WATCHDOG_TRIPPED : 0) | (fault_latched ? ST_FAULT : 0) |
                      (clipping ? ST_CLIPPING : 0) | (over_temp ? ST_OVER_TEMPERATURE : 0));
    p[13] = cmd_seq;
    trip_report = 0;
    put_u16(p + 14, (uint16_t)(int16_t)lroundf(applied_A * 1000.0f));
    send(MSG_STATE, p, 16);
}

static void finish_event(void) {
    uint8_t p[24];
    in_event = 0;
    ev_index++;
    put_u32(p, ev_t_us);
    put_f32(p + 4, ev_v);
    put_f32(p + 8, ev_grip);
    put_f32(p + 12, ev_pen);
    put_f32(p + 16, ev_peak);
    p[20] = (uint8_t)((ev_clipped ? 1 : 0) | (ev_tripped ? 2 : 0));
    ev_tripped = 0;
    p[21] = ev_kind;
    put_u16(p + 22, ev_index);
    send(MSG_EVENT, p, 24);
}

/* One on-device servo tick: same algorithm as FirmwareRenderer.tick. */
static float render_tick(uint32_t t_us, int32_t enc, uint16_t accel_raw, uint16_t grip_raw) {
    float x = (float)cal_sign * (float)(enc - cal_zero) * POS_RES_M;
    float old = vel_ring[vel_i];
    vel_ring[vel_i] = x;
    vel_i = (uint8_t)((vel_i + 1) % VEL_WINDOW);
    float v = 0.0f;
    if (vel_filled < VEL_WINDOW) vel_filled++;
    else v = (x - old) * (float)SERVO_HZ / VEL_WINDOW;
    float pen = wall_h - x;
    if (rearm_pending && !in_event && tr_k >= tr_n) {
        rearm_n = rearm_pending_n;
        rearm_pending = 0;
    }
    if (pen > 0.0f && armed) {
        armed = 0;
        if (in_event) finish_event();
        in_event = 1;
        ev_t_us = t_us;
        ev_v = v < 0.0f ? -v : 0.0f;
        ev_grip = ((float)grip_raw - cal_g_off) * cal_g_scale;
        ev_pen = 0.0f; ev_peak = 0.0f; ev_clipped = 0; ev_kind = tr_kind;
        tr_k = 0;
        if (tr_kind == 1 || tr_kind == 2) { tr_n = tr_param_n; tr_scale = tr_amp * ev_v / FORCE_PER_AMP; }
        else if (tr_kind == 4) tr_n = rearm_n;
        else tr_n = 0;
    } else if (!armed && pen < -wall_rearm) {
        armed = 1;
        if (in_event) finish_event();
    }
    float i_cmd = 0.0f;
    uint8_t clipped = 0;
    if (pen > 0.0f) {
        float f = wall_k * pen - wall_b * v;
        if (f > 0.0f) {
            i_cmd = f / FORCE_PER_AMP;
            if (i_cmd > lim_cont) { i_cmd = lim_cont; clipped = 1; }
        }
    }
    if (tr_k < tr_n) {
        if (ev_kind == 1) i_cmd += tr_scale;
        else if (ev_kind == 2) {
            float t = (float)(tr_k + 1) / (float)SERVO_HZ;
            i_cmd += tr_scale * expf(-4.6051702f * t / tr_dur) * sinf(6.2831853f * tr_freq * t);
        } else if (ev_kind == 4) i_cmd += rearm_buf[tr_k];
        tr_k++;
    }
    if (i_cmd > lim_peak) { i_cmd = lim_peak; clipped = 1; }
    else if (i_cmd < -lim_peak) { i_cmd = -lim_peak; clipped = 1; }
    if (temp_rise_K > T_ATTENUATE_K) {
        over_temp = 1;
        float k = (T_END_K - temp_rise_K) / (T_END_K - T_ATTENUATE_K);
        i_cmd *= k > 0.0f ? k : 0.0f;
    } else {
        over_temp = 0;
    }
    temp_rise_K += (R_WINDING_OHM * R_THERMAL_K_W * i_cmd * i_cmd - temp_rise_K) / (TAU_THERMAL_S * SERVO_HZ);
    clipping = clipped;
    if (in_event) {
        if (pen > ev_pen) ev_pen = pen;
        float a = fabsf(((float)accel_raw - cal_a_off) * cal_a_scale);
        if (a > ev_peak) ev_peak = a;
        if (clipped) ev_clipped = 1;
    }
    return i_cmd;
}

static void stop_render(void) {
    if (!rendering) return;
    rendering = 0;
    if (in_event) finish_event();
    motor_set(0.0f);
    watchdog_armed = 0;
}

static uint8_t finite4(const uint8_t *p, uint8_t n) {
    for (uint8_t i = 0; i < n; i++) {
        float f = get_f32(p + 4 * i);
        if (!(f == f) || f > 1e30f || f < -1e30f) return 0;
    }
    return 1;
}

static void handle_frame(void) {
    uint8_t type = parser.buf[3], seq = parser.buf[4], n = parser.buf[2];
    const uint8_t *p = parser.buf + 5;
    if ((!mode_on_device && type == MSG_CURRENT) || rendering) {
        last_cmd_tick = tick_count;
        if (tripped) { tripped = 0; trip_report = 1; } /* host back: resume, report the trip once */
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
        if (!(amps == amps)) { fault_latched = 1; amps = 0.0f; }
        if (fault_latched) amps = 0.0f;
        motor_set(amps);
        uint16_t acc = adc_read(0), grip = adc_read(1);
        int32_t enc;
        cli(); enc = encoder_count; sei();
        send_state(now_us(), enc, acc, grip);
        break;
    }
    case MSG_KEEPALIVE:
        break;
    case MSG_PING:
        send(MSG_PONG, p, n);
        break;
    case MSG_SET_MODE:
        if (n != 3 || p[0] > 1 || get_u16(p + 1) < 1) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        if (p[0] == 0) stop_render();
        mode_on_device = p[0];
        decimation = (uint8_t)(get_u16(p + 1) > 255 ? 255 : get_u16(p + 1));
        ack(type, seq);
        break;
    case MSG_SET_WATCHDOG:
        if (n != 2 || get_u16(p) < 1) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        watchdog_ms = get_u16(p);
        ack(type, seq);
        break;
    case MSG_CLEAR_FAULTS:
        tripped = 0; fault_latched = 0; last_cmd_tick = tick_count;
        ack(type, seq);
        break;
    case MSG_SET_CALIBRATION:
        if (n != 21 || !finite4(p + 5, 4) || get_f32(p + 5) <= 0 || get_f32(p + 13) <= 0 ||
            ((int8_t)p[4] != 1 && (int8_t)p[4] != -1)) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        cal_zero = (int32_t)get_u32(p); cal_sign = (int8_t)p[4];
        cal_a_scale = get_f32(p + 5); cal_a_off = get_f32(p + 9);
        cal_g_scale = get_f32(p + 13); cal_g_off = get_f32(p + 17);
        ack(type, seq);
        break;
    case MSG_WALL:
        if (n != 16 || !finite4(p, 4) || get_f32(p + 4) < 0 || get_f32(p + 8) < 0 || get_f32(p + 12) < 0) {
            nak(type, seq, NAK_BAD_PAYLOAD); break;
        }
        wall_h = get_f32(p); wall_k = get_f32(p + 4); wall_b = get_f32(p + 8); wall_rearm = get_f32(p + 12);
        ack(type, seq);
        break;
    case MSG_LIMITS:
        if (n != 12 || !finite4(p, 3) || get_f32(p) < 0 || get_f32(p + 4) < get_f32(p)) {
            nak(type, seq, NAK_BAD_PAYLOAD); break;
        }
        lim_cont = fminf(get_f32(p), I_CONT_A);
        lim_peak = fminf(fminf(get_f32(p + 4), get_f32(p + 8)), I_PEAK_A);
        ack(type, seq);
        break;
    case MSG_TRANSIENT_PARAM:
        if (n != 17 || p[0] > 2 || !finite4(p + 1, 4) ||
            (p[0] && (get_f32(p + 1) < 0 || get_f32(p + 5) <= 0)) ||
            (p[0] == 2 && !(get_f32(p + 9) > 0 && get_f32(p + 9) < SERVO_HZ / 2))) {
            nak(type, seq, NAK_BAD_PAYLOAD); break;
        }
        tr_kind = p[0];
        tr_amp = get_f32(p + 1); tr_dur = get_f32(p + 5); tr_freq = get_f32(p + 9);
        tr_param_n = (uint16_t)floorf(tr_dur * SERVO_HZ + 1e-3f);
        ack(type, seq);
        break;
    case MSG_REARM_DATA: {
        uint32_t off = get_u32(p);
        uint8_t k = (uint8_t)((n - 4) / 4);
        if (n < 4 || (n - 4) % 4 || !finite4(p + 4, k)) { nak(type, seq, NAK_BAD_PAYLOAD); break; }
        if (off + k > REARM_MAX) { nak(type, seq, NAK_TOO_LARGE); break; }
        if (in_event && tr_k < tr_n && ev_kind == 4) { nak(type, seq, NAK_BAD_STATE); break; } /* playing */
        for (uint8_t i = 0; i < k; i++) rearm_buf[off + i] = get_f32(p + 4 + 4 * i);
        ack(type, seq);
        break;
    }
    case MSG_REARM_COMMIT:
        if (n != 4 || get_u32(p) > REARM_MAX) { nak(type, seq, NAK_TOO_LARGE); break; }
        rearm_pending_n = (uint16_t)get_u32(p);
        rearm_pending = 1;
        tr_kind = 4;
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
        rendering = 1; watchdog_armed = 1; last_cmd_tick = tick_count;
        armed = 0; in_event = 0; tr_k = tr_n = 0; vel_filled = 0;
        break;
    case MSG_RENDER_STOP:
        stop_render();
        ack(type, seq);
        break;
    default:
        nak(type, seq, NAK_UNKNOWN_TYPE);
    }
}

/* One servo period (Timer1 flag): watchdog, then on-board rendering and telemetry. */
static uint8_t dec_count;
static void servo_tick(void) {
    uint32_t t_us = now_us();
    /* device-side watchdog: no command within watchdog_ms -> zero current, latched, reported */
    if (watchdog_armed && !tripped && (tick_count - last_cmd_tick) * 1000UL > (uint32_t)watchdog_ms * SERVO_HZ) {
        tripped = 1;
        if (in_event) ev_tripped = 1;
        motor_set(0.0f);
        if (!rendering) {
            int32_t enc;
            cli(); enc = encoder_count; sei();
            send_state(t_us, enc, adc_read(0), adc_read(1));
        }
    }
    if (!rendering) return;
    uint16_t acc = adc_read(0), grip = adc_read(1);
    int32_t enc;
    cli(); enc = encoder_count; sei();
    float amps = render_tick(t_us, enc, acc, grip);
    motor_set(tripped || fault_latched ? 0.0f : amps);
    if (++dec_count >= decimation) {
        dec_count = 0;
        send_state(t_us, enc, acc, grip);
    }
}

static void service_uart(void) {
    while (rx_tail != rx_head) {
        uint8_t c = rx_buf[rx_tail];
        rx_tail = (uint8_t)(rx_tail + 1);
        if (hfam_parse_byte(&parser, c)) handle_frame();
    }
}

#ifndef HFAM_HOST_HARNESS
int main(void) {
    wdt_enable(WDTO_60MS);
    hw_init();
    uart_init();
    motor_set(0.0f);
    sei();
    for (;;) {
        wdt_reset();
        service_uart();
        if (!tick_flag) continue;
        tick_flag = 0;
        servo_tick();
    }
}
#endif
