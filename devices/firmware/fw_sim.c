/* The real firmware (hfam_fw.elf, built by avr-gcc) on simavr's cycle-accurate ATmega328P at 16 MHz.
 *
 * - UART0 is bridged to a pseudo-terminal: the host opens the printed slave name with the
 *   normal `serial:<pty>` device string (devices/firmware/fw_sim.py starts this program).
 * - A one-axis paddle-and-hand model, stepped in simulated time (every PHYS_CYCLES cycles),
 *   closes the physical loop: the motor current is read from the PWM compare register OCR2A
 *   and the direction pin PB0; the handle position drives the quadrature encoder pins PD2/PD3
 *   (INT0/INT1) with each count's edge placed at its exact cycle (linear interpolation within
 *   the physics step); the handle acceleration and the grip force drive ADC0/ADC1.
 * - Simulated time is the MCU's cycle count. --pace realtime keeps it on the wall clock
 *   (--speed X: X times real time); --pace fast runs as fast as the host drains the telemetry;
 *   --pace lockstep (streaming) advances the MCU one host period (--lockstep-ticks servo ticks) per
 *   host frame and waits for the next frame, so the host paces on the MCU's clock: the harness
 *   marks INFO's flags (bit 1 lockstep, bits 8-15 the ticks) and the host drops wall-clock pacing.
 * - Timing instrumentation: interrupt entry/exit of every vector (simavr's per-vector RUNNING
 *   IRQ), the servo tick's trace marks on GPIOR0 (1 start, 2 end, 3/4 frame handling), RAM
 *   high-water by stack painting, encoder counts of the firmware vs the true count, motor
 *   zeroing after host silence. Written as JSON to --stats (every 50 ms of wall time and at exit).
 * - --selfhost runs a scripted host inside the harness (no pty) for the timing report.
 * - --fault drop=P,corrupt=P,garbage=P,duplicate=P,disconnect_after_s=T acts on the
 *   device -> host frames, like the Python emulator's FaultSpec.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_interrupts.h"
#include "sim_io.h"
#include "sim_irq.h"
#include "sim_cycle_timers.h"

#include "hfam_protocol.h"

#define F_CPU_HZ 16000000UL
#define PHYS_CYCLES 160 /* physics step: 10 us */
#define SERVICE_CYCLES 1600 /* pty service / pacing every 100 us of simulated time */
#define HOST_BACKLOG 2048 /* fast pace: at most this many unread bytes in the pty */
#define RAM_START 0x100
#define RAM_END 0x8FF
#define PAINT 0xC5
/* device constants (must match hfam_fw.c; INFO reports them to the host) */
#define ENCODER_LINES 500.0
#define GEAR_RATIO 10.0
#define HANDLE_LENGTH_M 0.07
#define KT_NM_A 0.0187
#define PWM_FULL_SCALE_A 2.0
#define ACCEL_SCALE 0.345
#define ACCEL_OFFSET 512.0
#define GRIP_SCALE 0.0098
#define POS_RES_M (2.0 * M_PI * HANDLE_LENGTH_M / (4.0 * ENCODER_LINES * GEAR_RATIO))
#define FORCE_PER_AMP (GEAR_RATIO * KT_NM_A / HANDLE_LENGTH_M)
/* I/O data addresses on the ATmega328P */
#define A_PORTB 0x25
#define A_GPIOR0 0x3E
#define A_TCCR2A 0xB0
#define A_OCR2A 0xB3
/* interrupt vectors */
#define V_INT0 1
#define V_INT1 2
#define V_TIMER1_COMPA 11
#define V_USART_RX 18
#define V_USART_UDRE 19
#define V_WDT 6

static avr_t *avr;
static int profile;
static avr_cycle_count_t trace_from;
static uint32_t prof[0x4000];
static volatile sig_atomic_t quit;
static void on_signal(int s) { (void)s; quit = 1; }

/* ---- options ---------------------------------------------------------------------------- */
static const char *elf_path, *stats_path;
static int pace_realtime = 1, pace_lockstep, selfhost;
/* --pace lockstep: one host period of simulated time per host frame (see lockstep_* below) */
static unsigned lockstep_ticks = 4; /* host period in servo ticks (4 kHz Timer1): 4 = 1 ms, a 1 kHz host loop */
static double lockstep_free_run_s = 0.0; /* > 0: wall time at the horizon with no host frame after which the MCU
                                           * runs free in real time (0: never; simulated time waits for the host) */
static double speed = 1.0, max_sim_s = 0.0;
static uint16_t sym_encoder, sym_bss_end, sym_parser, sym_probe, sym_rx_overruns, sym_po_e, sym_tr_k, sym_ev_kind, sym_heat_n;
static FILE *tick_log; /* --tick-log: per rendered tick, the firmware's tick_probe (t_us, enc, adc, current)
                        * and its passivity observer's energy po_e (Q16 A count) */
static double f_drop, f_corrupt, f_garbage, f_duplicate, f_disconnect_s = -1.0;
static unsigned rng_state = 12345;
static double rnd(void) { rng_state = rng_state * 1103515245u + 12345u; return ((rng_state >> 8) & 0xFFFFFF) / 16777216.0; }

/* ---- physics: paddle (mass, friction) held by a hand (spring-damper to a target) ---------- */
enum { HAND_TAP, HAND_HOLD, HAND_SWEEP };
static int hand_mode = HAND_TAP;
static double taps[32] = {0.05, 0.1, 0.2};
static int n_taps = 3;
static double sweep_v[32];
static int n_sweep;
static double sweep_amp_m = 0.005, grip_N = 2.0, hold_m = 0.01;
static const double m_paddle = 0.03, b_paddle = 0.05, k_hand = 300.0, b_hand = 3.0;
static double x, v, a_meas, x_target, i_motor, t_sim;
/* tap script state */
static int tap_k, tap_phase;
static double phase_t;
/* sweep state */
static int sweep_k, sweep_dir = -1, sweep_hold;
static double sweep_hold_t;
static int64_t sweep_mark_true, sweep_mark_fw;
static struct { double v; int64_t moved, missed; } sweep_res[32];

/* encoder */
static avr_irq_t *pin_a, *pin_b, *adc_irq;
static int64_t enc_true, enc_c0;
static const uint8_t GRAY[4] = {0, 2, 3, 1}; /* AB for counts 0..3 (A = PD2 bit 0, B = PD3 bit 1) */
#define EQ 4096
static struct { avr_cycle_count_t when; int64_t count; } enc_q[EQ];
static unsigned enc_q_head, enc_q_tail;
static int64_t enc_emitted;
static int64_t enc_count_of(double pos) { return (int64_t)floor(pos / POS_RES_M + 0.5); }

/* raise only changes: a low level raised before the firmware selects any-edge mode (EICRA = 0 at
 * reset means low-level) would start simavr's level-trigger polling */
static uint8_t pins_ab;
static void set_pins(int64_t c) {
    uint8_t ab = GRAY[((c % 4) + 4) % 4];
    if ((ab ^ pins_ab) & 1) avr_raise_irq(pin_a, ab & 1);
    if ((ab ^ pins_ab) & 2) avr_raise_irq(pin_b, (ab >> 1) & 1);
    pins_ab = ab;
}

static avr_cycle_count_t enc_cb(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)param;
    while (enc_q_tail != enc_q_head && enc_q[enc_q_tail].when <= when) {
        enc_emitted = enc_q[enc_q_tail].count;
        set_pins(enc_emitted);
        enc_q_tail = (enc_q_tail + 1) % EQ;
    }
    return enc_q_tail != enc_q_head ? enc_q[enc_q_tail].when : 0;
}

static void enc_schedule(double x0, double x1, avr_cycle_count_t c0) {
    int64_t k0 = enc_count_of(x0), k1 = enc_count_of(x1);
    if (k0 == k1) return;
    int was_empty = enc_q_tail == enc_q_head;
    int step = k1 > k0 ? 1 : -1;
    for (int64_t k = k0 + step;; k += step) {
        double edge = (step > 0 ? (double)k - 0.5 : (double)k + 0.5) * POS_RES_M;
        double f = (edge - x0) / (x1 - x0);
        if (f < 0) f = 0;
        if (f > 1) f = 1;
        unsigned next = (enc_q_head + 1) % EQ;
        if (next != enc_q_tail) {
            enc_q[enc_q_head].when = c0 + 1 + (avr_cycle_count_t)(f * (PHYS_CYCLES - 1));
            enc_q[enc_q_head].count = k;
            enc_q_head = next;
        }
        if (k == k1) break;
    }
    enc_true = k1;
    if (was_empty) avr_cycle_timer_register(avr, enc_q[enc_q_tail].when - avr->cycle, enc_cb, NULL);
}

static void set_adc(int ch, double raw) {
    if (raw < 0) raw = 0;
    if (raw > 1023) raw = 1023;
    uint32_t mv = (uint32_t)ceil(floor(raw + 0.5) * 5000.0 / 1023.0);
    avr_raise_irq(adc_irq + ch, mv);
}

static int32_t fw_encoder(void) {
    if (!sym_encoder) return 0;
    uint8_t *d = avr->data + sym_encoder;
    return (int32_t)((uint32_t)d[0] | ((uint32_t)d[1] << 8) | ((uint32_t)d[2] << 16) | ((uint32_t)d[3] << 24));
}

/* the hand's target: taps at the given speeds down through the wall height (0) and back */
static void hand_target(double dt) {
    phase_t += dt;
    double v_tap = taps[tap_k % n_taps];
    switch (tap_phase) {
    case 0: /* lift from the power-up position to 10 mm */
        x_target += 0.05 * dt;
        if (x_target >= 0.01) { x_target = 0.01; tap_phase = 1; phase_t = 0; }
        break;
    case 1: /* pause above */
        if (phase_t > 0.15) { tap_phase = 2; phase_t = 0; }
        break;
    case 2: /* down at v_tap until the target is 3 mm below the wall */
        x_target -= v_tap * dt;
        if (x_target <= -0.003) { tap_phase = 3; phase_t = 0; }
        break;
    case 3: /* press */
        if (phase_t > 0.05) { tap_phase = 4; phase_t = 0; }
        break;
    case 4: /* back up */
        x_target += 0.05 * dt;
        if (x_target >= 0.01) { x_target = 0.01; tap_phase = 1; phase_t = 0; tap_k++; }
        break;
    }
}

static void sweep_step(double dt) {
    if (sweep_k >= n_sweep) { x_target = x; v = 0; return; }
    if (t_sim < 0.03) { /* boot and host set-up first: the paddle rests */
        v = 0;
        sweep_mark_true = enc_true; sweep_mark_fw = fw_encoder();
        return;
    }
    if (sweep_hold) {
        sweep_hold_t += dt;
        v = 0;
        if (sweep_hold_t > 0.003) { /* settled: compare the firmware's count with the true one */
            int64_t d_true = enc_true - sweep_mark_true, d_fw = (int64_t)fw_encoder() - sweep_mark_fw;
            sweep_res[sweep_k].v = sweep_v[sweep_k];
            sweep_res[sweep_k].moved += d_true > 0 ? d_true : -d_true;
            sweep_res[sweep_k].missed += (d_true - d_fw) > 0 ? d_true - d_fw : d_fw - d_true;
            sweep_mark_true = enc_true; sweep_mark_fw = fw_encoder();
            sweep_hold = 0;
            if (sweep_dir > 0) sweep_k++; /* one down-and-up pass per speed */
            sweep_dir = -sweep_dir;
        }
        return;
    }
    double vs = sweep_v[sweep_k] * sweep_dir;
    double nx = x + vs * dt;
    if ((sweep_dir < 0 && nx <= -sweep_amp_m) || (sweep_dir > 0 && nx >= sweep_amp_m)) {
        nx = sweep_dir < 0 ? -sweep_amp_m : sweep_amp_m;
        sweep_hold = 1; sweep_hold_t = 0;
    }
    v = (nx - x) / dt;
    x = nx;
}

static double motor_current(void) {
    uint8_t *d = avr->data;
    if (!(d[A_TCCR2A] & 0x80)) return 0.0; /* COM2A1: OC2A drives the pin */
    double i = d[A_OCR2A] / 255.0 * PWM_FULL_SCALE_A;
    return (d[A_PORTB] & 1) ? -i : i;
}

/* motor zeroing after host silence (the firmware watchdog), measured in MCU cycles */
static avr_cycle_count_t last_host_rx_cycle, motor_on_cycle;
static double wd_last_ms = -1;
static uint32_t motor_zeroings;
static double last_i;

static avr_cycle_count_t phys_cb(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)param;
    const double dt = PHYS_CYCLES / (double)F_CPU_HZ;
    double x0 = x;
    i_motor = motor_current();
    if (i_motor == 0.0 && last_i != 0.0) {
        motor_zeroings++;
        wd_last_ms = (when - last_host_rx_cycle) * 1e3 / F_CPU_HZ;
    }
    if (i_motor != 0.0 && last_i == 0.0) motor_on_cycle = when;
    last_i = i_motor;
    if (hand_mode == HAND_SWEEP) {
        double v0 = v;
        sweep_step(dt);
        a_meas = (v - v0) / dt;
    } else {
        if (hand_mode == HAND_TAP) hand_target(dt);
        else if (x_target < hold_m) x_target = fmin(hold_m, x_target + 0.05 * dt); /* lift from home, 5 cm/s */
        else x_target = fmax(hold_m, x_target - 0.05 * dt);
        double f = FORCE_PER_AMP * i_motor + k_hand * (x_target - x) - b_hand * v - b_paddle * v;
        double acc = f / m_paddle;
        v += acc * dt; /* semi-implicit Euler */
        x += v * dt;
        a_meas = acc;
    }
    t_sim += dt;
    enc_schedule(x0, x, when);
    set_adc(0, ACCEL_OFFSET + a_meas / ACCEL_SCALE);
    set_adc(1, grip_N / GRIP_SCALE);
    return when + PHYS_CYCLES;
}


/* simavr (1.6) times every UART character as 1 start + 8 data + 1 parity + stop bits, a parity bit
 * the ATmega328P sends only when UPM0 asks for one: at 1 Mbaud 8N1 that is 176 cycles per byte
 * instead of 160, 10 % less link than the real chip has (full-rate 4 kHz telemetry needs 92 % of
 * it). After the firmware sets the baud rate, the byte time is corrected to the frame it configured. */
static avr_uart_t *uart0;
static void uart_fix_byte_time(void) {
    if (!uart0) {
        for (avr_io_t *io = avr->io_port; io; io = io->next)
            if (io->kind && !strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0') uart0 = (avr_uart_t *)io;
        if (!uart0) return;
    }
    avr_cycle_count_t c = uart0->cycles_per_byte;
    if (c % 11) return; /* already corrected, or not simavr's 11-bit frame */
    uint8_t ucsr0c = avr->data[0xC2];
    if (ucsr0c & 0x30) return; /* parity enabled: simavr's count is right */
    int data_bits = 5 + ((ucsr0c >> 1) & 3), stop_bits = 1 + ((ucsr0c >> 3) & 1);
    if (data_bits != 8 || stop_bits != 1) return;
    uart0->cycles_per_byte = c / 11 * 10;
}

static avr_cycle_count_t uart_byte_cycles(void) { return uart0 && uart0->cycles_per_byte ? uart0->cycles_per_byte : 160; }

/* ---- timing instrumentation -------------------------------------------------------------- */
#define HIST 65536
static uint32_t tick_hist[HIST], body_hist[HIST], own_hist[HIST]; /* own: no latency, no nested interrupts */
static uint64_t ticks, tick_overruns, compare_matches;
static avr_cycle_count_t overrun_at[8]; /* MCU cycle of the first overruns, for the report */
static avr_cycle_count_t match_cycle, tick_start_cycle, frame_start_cycle;
static int tick_open;
static uint32_t frame_max, frames_handled;
static uint8_t frame_type;
static uint32_t rearm_frame_max, rearm_frames, rearm_own_max; /* REARM_DATA frames: handling cycles (FRAME marks) */
static uint64_t rearm_frame_total, rearm_own_total;
static int isr_depth, frame_open;
static uint64_t frame_isr_cycles; /* interrupts (outermost, nested ones inside them) while a frame was handled */
/* the worst tick, taken apart: compare match -> Timer1 entry, the interrupts that nested in it (count and
 * cycles per vector), and a cycles-per-instruction-address profile of everything that ran meanwhile */
#define NPC 0x4000
static uint32_t cur_pc[NPC], worst_pc[NPC];
static uint16_t cur_touched[NPC];
static unsigned n_touched;
static struct { uint32_t n, cycles; } cur_nest[8], worst_nest[8];
static uint64_t worst_total, worst_at, worst_latency, cur_latency;
static int tick_entered;
/* what each tick rendered, from the firmware's RAM at its end (tr_k advanced: a transient sample of kind ev_kind
 * played; heat_n back to 0: the thermal model stepped): per transient kind the ticks and their worst case */
static uint16_t last_tr_k;
static uint64_t tr_ticks[5], tr_rx_ticks[5], thermal_steps;
static uint32_t tr_max[5];
static int worst_kind = -1, worst_thermal;
static struct { const char *name; int vec; uint64_t n; avr_cycle_count_t pend, run; uint32_t max_dur, max_lat; avr_cycle_count_t max_lat_at; } isr[] = {
    {.name = "INT0", .vec = V_INT0}, {.name = "INT1", .vec = V_INT1}, {.name = "TIMER1_COMPA", .vec = V_TIMER1_COMPA},
    {.name = "USART_RX", .vec = V_USART_RX},
    {.name = "USART_UDRE", .vec = V_USART_UDRE}, {.name = "WDT", .vec = V_WDT}};
#define N_ISR (sizeof(isr) / sizeof(isr[0]))

static void isr_pending(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    size_t k = (size_t)param;
    if (!value) return;
    isr[k].pend = avr->cycle;
    if (isr[k].vec == V_TIMER1_COMPA) {
        compare_matches++;
        if (tick_open) { /* the previous tick had not finished */
            if (tick_overruns < 8) overrun_at[tick_overruns] = avr->cycle;
            tick_overruns++;
        }
        else match_cycle = avr->cycle;
        tick_open = 1;
    }
}

static void isr_running(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    size_t k = (size_t)param;
    if (value) {
        isr_depth++;
        isr[k].n++;
        isr[k].run = avr->cycle;
        uint32_t lat = (uint32_t)(avr->cycle - isr[k].pend);
        if (isr[k].vec == V_TIMER1_COMPA && tick_open) { cur_latency = lat; tick_entered = 1; }
        if (lat > isr[k].max_lat && ticks > 0) { isr[k].max_lat = lat; isr[k].max_lat_at = avr->cycle; } /* after boot */
    } else {
        uint32_t dur = (uint32_t)(avr->cycle - isr[k].run);
        if (dur > isr[k].max_dur) isr[k].max_dur = dur;
        if (isr_depth > 0 && --isr_depth == 0 && frame_open) frame_isr_cycles += dur;
        /* nested in the tick (an interrupt before the Timer1 entry is part of the latency) */
        if (tick_open && tick_entered && isr[k].vec != V_TIMER1_COMPA && k < 8) { cur_nest[k].n++; cur_nest[k].cycles += dur; }
    }
}

static void gpior0_write(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param) {
    (void)param;
    a->data[addr] = v;
    avr_cycle_count_t c = a->cycle;
    if (v == 1) tick_start_cycle = c;
    else if (v == 2) {
        if (tick_log && sym_probe) {
            /* state_slot_t: t_us u32, enc i32, accel u16, grip u16, current_q24 i32 (avr-gcc packs it) */
            const uint8_t *d = a->data + sym_probe;
            static uint32_t last_t = 0; /* the probe starts zeroed: tick 0 never renders (no host yet) */
            uint32_t t = (uint32_t)d[0] | (uint32_t)d[1] << 8 | (uint32_t)d[2] << 16 | (uint32_t)d[3] << 24;
            if (t != last_t) { /* only ticks that rendered */
                static const uint8_t zero[4];
                fwrite(d, 1, 16, tick_log);
                fwrite(sym_po_e ? a->data + sym_po_e : zero, 1, 4, tick_log);
                last_t = t;
            }
        }
        uint64_t total = tick_open ? c - match_cycle : c - tick_start_cycle, body = c - tick_start_cycle;
        tick_hist[total < HIST ? total : HIST - 1]++;
        uint64_t own = total - cur_latency; /* the tick's own code: what does not depend on how bytes line up */
        for (int j = 0; j < 8; j++) own -= cur_nest[j].cycles;
        own_hist[own < HIST ? own : HIST - 1]++;
        int kind = -1, thermal = 0;
        if (sym_tr_k && sym_ev_kind) {
            uint16_t k = (uint16_t)(a->data[sym_tr_k] | a->data[sym_tr_k + 1] << 8);
            if (k != last_tr_k && k != 0 && a->data[sym_ev_kind] < 5) {
                kind = a->data[sym_ev_kind];
                tr_ticks[kind]++;
                if (cur_nest[3].n) tr_rx_ticks[kind]++; /* isr[3]: USART_RX nested in it (a frame arriving) */
                if (total > tr_max[kind]) tr_max[kind] = (uint32_t)total;
            }
            last_tr_k = k;
        }
        if (sym_heat_n && a->data[sym_heat_n] == 0) { thermal = 1; thermal_steps++; }
        if (total > worst_total) {
            worst_total = total; worst_at = c; worst_latency = cur_latency; worst_kind = kind; worst_thermal = thermal;
            memset(worst_pc, 0, sizeof worst_pc);
            for (unsigned j = 0; j < n_touched; j++) worst_pc[cur_touched[j]] = cur_pc[cur_touched[j]];
            memcpy(worst_nest, cur_nest, sizeof cur_nest);
        }
        for (unsigned j = 0; j < n_touched; j++) cur_pc[cur_touched[j]] = 0;
        n_touched = 0;
        memset(cur_nest, 0, sizeof cur_nest);
        cur_latency = 0;
        tick_entered = 0;
        body_hist[body < HIST ? body : HIST - 1]++;
        ticks++;
        tick_open = 0;
    } else if (v == 3) {
        frame_start_cycle = c;
        frame_open = 1;
        frame_isr_cycles = 0;
        frame_type = sym_parser ? a->data[sym_parser + 3] : 0; /* parser.buf: sync, sync, length, type */
    } else if (v == 4) {
        uint32_t d = (uint32_t)(c - frame_start_cycle);
        if (d > frame_max) frame_max = d;
        frames_handled++;
        frame_open = 0;
        if (frame_type == MSG_REARM_DATA) {
            uint32_t own = d - (uint32_t)frame_isr_cycles; /* the main loop's own cycles, interrupts taken out */
            rearm_frames++;
            rearm_frame_total += d;
            rearm_own_total += own;
            if (d > rearm_frame_max) rearm_frame_max = d;
            if (own > rearm_own_max) rearm_own_max = own;
        }
    }
}

static void hist_stats(const uint32_t *h, uint64_t n, unsigned *mn, unsigned *med, unsigned *mx, unsigned *p99) {
    *mn = *med = *mx = *p99 = 0;
    if (!n) return;
    uint64_t acc = 0;
    int got_min = 0, got_med = 0, got_p99 = 0;
    for (unsigned i = 0; i < HIST; i++) {
        if (!h[i]) continue;
        if (!got_min) { *mn = i; got_min = 1; }
        acc += h[i];
        if (!got_med && acc * 2 >= n) { *med = i; got_med = 1; }
        if (!got_p99 && acc * 100 >= n * 99) { *p99 = i; got_p99 = 1; }
        *mx = i;
    }
}

static unsigned ram_high_water(void) {
    if (!sym_bss_end) return 0;
    unsigned a = sym_bss_end;
    while (a <= RAM_END && avr->data[a] == PAINT) a++;
    return RAM_END + 1 - a; /* stack bytes ever used */
}

/* ---- UART <-> host ------------------------------------------------------------------------- */
static int master_fd = -1, slave_fd = -1;
#define QN 65536
static uint8_t host_q[QN]; /* host -> MCU */
static unsigned hq_head, hq_tail;
static uint8_t out_q[QN]; /* MCU -> host, waiting for the pty */
static unsigned oq_head, oq_tail;
static int uart_xoff;
static avr_irq_t *uart_in;
static uint64_t bytes_to_mcu, bytes_from_mcu, pty_drops, frames_dropped, frames_corrupted, frames_garbage,
    frames_duplicated;
static hfam_parser_t out_parser;
static int disconnected;
static avr_cycle_count_t attach_cycle;
static int faults_on;
/* self-host: parse what the firmware sends */
static hfam_parser_t sh_parser;
static uint64_t sh_events_kind[5], sh_rearm_busy;
static uint64_t sh_states, sh_events, sh_gaps, sh_naks, sh_acks, sh_rearm_acks, sh_rearms, sh_rearm_timeouts;
static int sh_rearm_off = -1; /* next REARM_DATA offset of the upload under way (-1: none) */
static double sh_rearm_deadline, sh_rearm_t0, sh_rearm_max_s;
static void sh_rearm_next(void);
static void sh_sinusoid(void);
static double sh_next_t, sh_rearm_t;
static int sh_last_seq = -1;

static void out_push(const uint8_t *b, unsigned n) {
    for (unsigned i = 0; i < n; i++) {
        unsigned next = (oq_head + 1) % QN;
        if (next == oq_tail) { pty_drops++; return; }
        out_q[oq_head] = b[i];
        oq_head = next;
    }
}

/* ---- lockstep (--pace lockstep) ----------------------------------------------------------------
 * The MCU runs up to a horizon; a complete host frame is handed to the UART only once the MCU has
 * reached the horizon, and moves it one host period P on (plus the extra UART time of a frame longer
 * than a CURRENT). A streaming host answers each STATE with its next CURRENT, so consecutive CURRENTs
 * reach the MCU exactly P apart in MCU time, however slowly simavr runs or the host answers. The MCU
 * does not stop at the horizon while it owes the released frame its reply (or is sending a frame):
 * such a reply is late (counted) and the next period starts when it is out. Only the reply that answers
 * the released frame pays (ACK/NAK naming its type and sequence number, STATE its CURRENT's, INFO a HELLO,
 * PONG a PING): the reply to an earlier frame may still be on the line (a host that sent its HELLO twice
 * while the harness started: the second INFO takes 1.15 ms of the UART, longer than a period), and taking it
 * for the released frame's would stop the MCU with that frame's reply unsent in the firmware's TX ring,
 * each side then waiting for the other. While the firmware renders
 * on board (RENDER_START .. RENDER_STOP) the harness runs as --pace fast (telemetry back-pressure).
 * A host that sends nothing leaves the MCU waiting at the horizon (simulated time stands still, as
 * for a host paused by the scheduler: the servo loop's host was silent 10+ s after its first tick on a
 * loaded machine); with --lockstep-free-run-s T > 0 a host silent for T of wall time lets the MCU run free in
 * real time instead, so the firmware's watchdog zeroes the motor as on a board; the host's next frame
 * resumes lockstep. */
#define LS_CURRENT_FRAME (HFAM_OVERHEAD + 4)
#define LS_OWED_MAX_CYCLES (F_CPU_HZ / 10) /* a reply that never comes: stop waiting 100 ms of MCU time on */
static hfam_parser_t ls_in_parser;
static uint8_t ls_q[QN]; /* complete host frames not yet handed to the UART */
static unsigned ls_head, ls_tail;
static uint16_t ls_len[1024];
static unsigned ls_fhead, ls_ftail;
/* the MCU boots (10 ms of MCU time; its set-up takes well under 1 ms) before it waits for the host: a frame
 * handed to the UART before the firmware enables its receiver would be lost */
#define LS_BOOT_CYCLES (F_CPU_HZ / 100)
static avr_cycle_count_t ls_horizon = LS_BOOT_CYCLES, ls_released_at;
static int ls_owed, ls_render, ls_free;
static uint8_t ls_owed_type, ls_owed_seq; /* the released frame the MCU owes a reply */
static uint64_t ls_frames, ls_currents, ls_waits, ls_timeouts, ls_late, ls_dropped;
static double ls_wait_wall_s;
static avr_cycle_count_t ls_late_max;

static avr_cycle_count_t ls_period(void) { return (avr_cycle_count_t)lockstep_ticks * (F_CPU_HZ / 4000); }

static void ls_host_byte(uint8_t c) {
    if (!hfam_parse_byte(&ls_in_parser, c)) return;
    unsigned n = (unsigned)ls_in_parser.buf[2] + HFAM_OVERHEAD;
    if ((ls_fhead + 1) % 1024 == ls_ftail || (QN - 1 - (ls_head + QN - ls_tail) % QN) < n) { ls_dropped++; return; }
    for (unsigned i = 0; i < n; i++) { ls_q[ls_head] = ls_in_parser.buf[i]; ls_head = (ls_head + 1) % QN; }
    ls_len[ls_fhead] = (uint16_t)n;
    ls_fhead = (ls_fhead + 1) % 1024;
}

static void host_push(const uint8_t *b, unsigned n);

/* hand the next queued host frame to the UART if the MCU has reached the horizon; returns 1 if it did */
static int ls_release(void) {
    if (ls_ftail == ls_fhead) return 0;
    if (!ls_render && !ls_free && avr->cycle < ls_horizon) return 0;
    unsigned n = ls_len[ls_ftail];
    ls_ftail = (ls_ftail + 1) % 1024;
    uint8_t f[HFAM_MAX_PAYLOAD + HFAM_OVERHEAD] = {0};
    for (unsigned i = 0; i < n; i++) { f[i] = ls_q[ls_tail]; ls_tail = (ls_tail + 1) % QN; }
    uint8_t type = f[3];
    if (type == MSG_RENDER_START) ls_render = 1;
    else if (type == MSG_RENDER_STOP || (type == MSG_SET_MODE && f[2] >= 1 && f[5] == 0)) ls_render = 0;
    /* the period runs from the horizon when the frame was waiting there (no drift from overshoot) */
    avr_cycle_count_t start = (!ls_free && avr->cycle < ls_horizon + 2 * PHYS_CYCLES) ? ls_horizon : avr->cycle;
    avr_cycle_count_t extra = n > LS_CURRENT_FRAME ? (avr_cycle_count_t)(n - LS_CURRENT_FRAME) * uart_byte_cycles() : 0;
    ls_horizon = start + ls_period() + extra;
    ls_released_at = avr->cycle;
    ls_owed = type != MSG_KEEPALIVE; /* every other frame is answered (STATE, ACK, NAK, PONG or INFO) */
    ls_owed_type = type;
    ls_owed_seq = f[4];
    ls_free = 0;
    ls_frames++;
    if (type == MSG_CURRENT) ls_currents++;
    host_push(f, n);
    return 1;
}

/* whether a complete frame from the MCU answers the released frame (see the lockstep note above) */
static int ls_answers_owed(const uint8_t *frame) {
    uint8_t n = frame[2];
    const uint8_t *p = frame + 5;
    switch (frame[3]) {
    case MSG_ACK: case MSG_NAK: return n >= 2 && p[0] == ls_owed_type && p[1] == ls_owed_seq;
    case MSG_STATE: return ls_owed_type == MSG_CURRENT && n >= 14 && p[13] == ls_owed_seq; /* p[13]: cmd_seq */
    case MSG_INFO: return ls_owed_type == MSG_HELLO;
    case MSG_PONG: return ls_owed_type == MSG_PING;
    default: return 0;
    }
}

/* a complete frame from the MCU: INFO advertises lockstep; the reply to the released frame pays what it owed */
static void ls_device_frame(uint8_t *frame, unsigned n) {
    uint8_t type = frame[3];
    if (type == MSG_INFO && frame[2] >= 87) {
        uint8_t *flags = frame + 5 + 85;
        flags[0] |= 2;                         /* bit 1: lockstep, the host paces on the device clock */
        flags[1] = (uint8_t)lockstep_ticks;    /* bits 8-15: servo ticks per host period */
        uint8_t payload[HFAM_MAX_PAYLOAD];
        memcpy(payload, frame + 5, frame[2]);
        hfam_encode(frame, type, frame[4], payload, frame[2]);
    }
    (void)n;
    if (ls_owed && ls_answers_owed(frame)) {
        if (avr->cycle > ls_horizon) {
            ls_late++;
            if (avr->cycle - ls_horizon > ls_late_max) ls_late_max = avr->cycle - ls_horizon;
        }
        ls_owed = 0;
    }
}

/* the MCU must wait for the host: at the horizon, nothing owed, nothing on the way in or out */
static int ls_must_wait(void) {
    if (ls_render || ls_free || avr->cycle < ls_horizon) return 0;
    if (ls_owed && avr->cycle < ls_horizon + LS_OWED_MAX_CYCLES) return 0;
    return hq_tail == hq_head && out_parser.pos == 0;
}

static void selfhost_rx(uint8_t c) {
    if (!hfam_parse_byte(&sh_parser, c)) return;
    uint8_t type = sh_parser.buf[3], seq = sh_parser.buf[4];
    if (sh_last_seq >= 0) sh_gaps += (uint8_t)(seq - sh_last_seq - 1);
    sh_last_seq = seq;
    if (type == MSG_STATE) sh_states++;
    else if (type == MSG_EVENT) {
        sh_events++;
        if (sh_parser.buf[5 + 21] < 5) sh_events_kind[sh_parser.buf[5 + 21]]++;
    }
    else if (type == MSG_NAK) {
        /* a re-arm refused while the re-armed transient plays (the single buffer): expected, retried; others count */
        if (sh_parser.buf[5] == MSG_REARM_DATA && sh_parser.buf[7] == NAK_BAD_STATE) sh_rearm_busy++;
        else sh_naks++;
        if (sh_parser.buf[5] == MSG_REARM_DATA || sh_parser.buf[5] == MSG_REARM_COMMIT) sh_rearm_off = -1;
    } else if (type == MSG_ACK) {
        sh_acks++;
        if (sh_parser.buf[5] == MSG_REARM_DATA) { sh_rearm_acks++; sh_rearm_next(); } /* as the host: one frame in flight */
        else if (sh_parser.buf[5] == MSG_REARM_COMMIT) {
            sh_rearm_acks++; sh_rearms++; sh_rearm_off = -1;
            if (sh_rearms % 2 == 0) { /* every 2nd re-arm the sinusoid again: contacts play both kinds */
                sh_sinusoid();
                sh_rearm_t = avr->cycle / (double)F_CPU_HZ + 0.02; /* the next upload's frame not on its heels (RX ring) */
            }
            double d = avr->cycle / (double)F_CPU_HZ - sh_rearm_t0;
            if (d > sh_rearm_max_s) sh_rearm_max_s = d;
        }
    }
}

static void uart_out_hook(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)param;
    uint8_t c = (uint8_t)value;
    bytes_from_mcu++;
    if (selfhost) { selfhost_rx(c); return; }
    if (disconnected) return;
    if (!faults_on && !pace_lockstep) { out_push(&c, 1); return; }
    if (!hfam_parse_byte(&out_parser, c)) return;
    uint8_t frame[HFAM_MAX_PAYLOAD + HFAM_OVERHEAD + 64];
    unsigned n = (unsigned)out_parser.buf[2] + HFAM_OVERHEAD;
    memcpy(frame, out_parser.buf, n);
    if (pace_lockstep) ls_device_frame(frame, n);
    if (!faults_on) { out_push(frame, n); return; }
    if (f_drop > 0 && rnd() < f_drop) { frames_dropped++; return; }
    if (f_garbage > 0 && rnd() < f_garbage) {
        frames_garbage++;
        unsigned g = 1 + (unsigned)(rnd() * 23);
        uint8_t junk[24];
        for (unsigned i = 0; i < g; i++) junk[i] = (uint8_t)(rnd() * 256);
        out_push(junk, g);
    }
    if (f_corrupt > 0 && rnd() < f_corrupt) {
        frames_corrupted++;
        frame[2 + (unsigned)(rnd() * (n - 2))] ^= (uint8_t)(1u << (unsigned)(rnd() * 8));
    }
    out_push(frame, n);
    if (f_duplicate > 0 && rnd() < f_duplicate) { frames_duplicated++; out_push(frame, n); }
}

static void uart_xon_hook(avr_irq_t *irq, uint32_t value, void *param) { (void)irq; (void)value; (void)param; uart_xoff = 0; }
static void uart_xoff_hook(avr_irq_t *irq, uint32_t value, void *param) { (void)irq; (void)value; (void)param; uart_xoff = 1; }

static void host_push(const uint8_t *b, unsigned n) {
    for (unsigned i = 0; i < n; i++) {
        unsigned next = (hq_head + 1) % QN;
        if (next == hq_tail) return;
        host_q[hq_head] = b[i];
        hq_head = next;
    }
}

/* bytes waiting in simavr's UART input queue (its fifo's cursors, as uart_fifo_get_read_size counts them) */
static unsigned uart_queued(void) {
    if (!uart0) return 0;
    return ((unsigned)uart0->input.write + uart_fifo_fifo_size - uart0->input.read) & (uart_fifo_fifo_size - 1);
}

static void feed_uart(void) {
    while (!uart_xoff && hq_tail != hq_head) {
        avr_raise_irq(uart_in, host_q[hq_tail]);
        hq_tail = (hq_tail + 1) % QN;
        bytes_to_mcu++;
        /* when the byte reaches the MCU's receiver: simavr queues up to 64 input bytes at once and hands
         * them on one per byte time, so a burst of host frames (a host that was descheduled for a while)
         * arrives over up to ~0.6 ms after it was queued here, as on a real 1 Mbaud line */
        last_host_rx_cycle = avr->cycle + uart_queued() * uart_byte_cycles();
    }
}

static int pty_unread(void) {
    int n = 0;
    if (slave_fd >= 0 && ioctl(slave_fd, FIONREAD, &n) < 0) n = 0;
    return n;
}

static void pty_read(void) {
    if (master_fd < 0) return;
    uint8_t buf[4096];
    for (;;) {
        ssize_t n = read(master_fd, buf, sizeof buf);
        if (n <= 0) break;
        if (!attach_cycle) attach_cycle = avr->cycle ? avr->cycle : 1;
        if (pace_lockstep)
            for (ssize_t i = 0; i < n; i++) ls_host_byte(buf[i]);
        else
            host_push(buf, (unsigned)n);
    }
}

/* returns 1 if everything queued was written */
static int pty_flush(void) {
    if (master_fd < 0) { oq_tail = oq_head; return 1; }
    while (oq_tail != oq_head) {
        unsigned end = oq_head > oq_tail ? oq_head : QN;
        ssize_t n = write(master_fd, out_q + oq_tail, end - oq_tail);
        if (n <= 0) return 0;
        oq_tail = (oq_tail + (unsigned)n) % QN;
    }
    return 1;
}

/* ---- scripted host for the timing report --------------------------------------------------- */
static uint8_t sh_seq;
static void sh_send(uint8_t type, const uint8_t *p, uint8_t n) {
    uint8_t f[HFAM_MAX_PAYLOAD + HFAM_OVERHEAD];
    uint16_t len = hfam_encode(f, type, sh_seq++, p, n);
    host_push(f, len);
}
static int sh_stage, sh_decimation = 1;
/* a 128-sample re-arm the way serial_device.py sends one while rendering: 24-sample REARM_DATA frames
 * (107 bytes, wire_protocol.DATA_CHUNK_SAMPLES), each sent when the previous one's ACK is back, then the commit */
#define SH_CHUNK 24
static void sh_rearm_next(void) {
    if (sh_rearm_off < 0 || sh_rearm_off > 128) return;
    uint8_t p[4 + SH_CHUNK * 4];
    sh_rearm_deadline = avr->cycle / (double)F_CPU_HZ + 0.05;
    if (sh_rearm_off >= 128) {
        put_u32(p, 128); sh_send(MSG_REARM_COMMIT, p, 4);
        sh_rearm_off = 129; /* the commit in flight: the next upload waits for its ACK */
        return;
    }
    uint32_t off = (uint32_t)sh_rearm_off, k = 128 - off < SH_CHUNK ? 128 - off : SH_CHUNK;
    put_u32(p, off);
    for (uint32_t i = 0; i < k; i++) put_f32(p + 4 + 4 * i, 0.1f * (float)((off + i) % 7));
    sh_send(MSG_REARM_DATA, p, (uint8_t)(4 + 4 * k));
    sh_rearm_off = (int)(off + k);
}
static void sh_sinusoid(void) {
    uint8_t p[17];
    p[0] = 2; put_f32(p + 1, 20.0f); put_f32(p + 5, 0.05f); put_f32(p + 9, 300.0f); put_f32(p + 13, 0.0f);
    sh_send(MSG_TRANSIENT_PARAM, p, 17); /* decaying sinusoid: the costliest tick */
}
static void selfhost_step(void) {
    double t = avr->cycle / (double)F_CPU_HZ;
    uint8_t p[64];
    if (sh_stage == 0 && t > 0.002) {
        put_u16(p, 0x0001); sh_send(MSG_HELLO, p, 2);
        p[0] = 1; put_u16(p + 1, (uint16_t)sh_decimation); sh_send(MSG_SET_MODE, p, 3); /* on-device rendering */
        sh_send(MSG_CLEAR_FAULTS, p, 0);
        /* the encoder's zero at the physical wall height 0 (the firmware counts from its power-up position, the
         * sweep's +5 mm): each downward pass re-arms above 1 mm and contacts the wall, 5 mm deep */
        put_u32(p, (uint32_t)(int32_t)-enc_c0); p[4] = 1; put_f32(p + 5, (float)ACCEL_SCALE); put_f32(p + 9, (float)ACCEL_OFFSET);
        put_f32(p + 13, (float)GRIP_SCALE); put_f32(p + 17, 0.0f);
        sh_send(MSG_SET_CALIBRATION, p, 21);
        put_f32(p, 0.0f); put_f32(p + 4, 1000.0f); put_f32(p + 8, 1.0f); put_f32(p + 12, 0.001f);
        /* the passivity observer on (protocol 1.1) with a 1 s window, and a limit (0.5 J) the sweeps never reach:
         * every tick runs it and none stops */
        put_f32(p + 16, 0.5f); put_f32(p + 20, 2.4996876e-4f);
        sh_send(MSG_WALL, p, 24);
        put_f32(p, 0.8f); put_f32(p + 4, 2.0f); put_f32(p + 8, 2.0f); sh_send(MSG_LIMITS, p, 12);
        sh_sinusoid();
        sh_send(MSG_RENDER_START, p, 0);
        sh_stage = 1; sh_next_t = t + 0.02; sh_rearm_t = t + 0.02;
    }
    if (sh_stage >= 1 && t >= sh_next_t) { sh_send(MSG_KEEPALIVE, p, 0); sh_next_t = t + 0.02; }
    /* second half of the sweeps: host re-arms a 128-sample transient every 20 ms (the longest frames) */
    if (sh_stage == 1 && hand_mode == HAND_SWEEP && sweep_k >= n_sweep / 2) sh_stage = 2;
    if (sh_rearm_off >= 0 && t > sh_rearm_deadline) { sh_rearm_timeouts++; sh_rearm_off = -1; } /* no ACK: give up */
    if (sh_stage == 2 && t >= sh_rearm_t && sh_rearm_off < 0) { /* every 20 ms, one upload at a time */
        sh_rearm_off = 0;
        sh_rearm_t0 = t;
        sh_rearm_next();
        sh_rearm_t = t + 0.02;
    }
}

/* ---- stats ----------------------------------------------------------------------------------- */
static void write_stats(int final) {
    if (!stats_path) return;
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp", stats_path);
    FILE *f = fopen(tmp, "w");
    if (!f) return;
    unsigned mn, med, mx, p99, bmn, bmed, bmx, bp99;
    hist_stats(tick_hist, ticks, &mn, &med, &mx, &p99);
    hist_stats(body_hist, ticks, &bmn, &bmed, &bmx, &bp99);
    unsigned omn, omed, omx, op99;
    hist_stats(own_hist, ticks, &omn, &omed, &omx, &op99);
    fprintf(f, "{\"final\": %d, \"cycles\": %llu, \"sim_time_s\": %.6f, \"f_cpu_hz\": %lu,\n", final,
            (unsigned long long)avr->cycle, avr->cycle / (double)F_CPU_HZ, F_CPU_HZ);
    /* a tick still running when the run stopped is not a lost one: its compare match is left out */
    if (pace_lockstep)
        fprintf(f, " \"lockstep\": {\"ticks_per_period\": %u, \"period_cycles\": %llu, \"frames\": %llu, "
                "\"currents\": %llu, \"waits\": %llu, \"wait_wall_s\": %.3f, \"timeouts\": %llu, \"free\": %d, "
                "\"late_replies\": %llu, \"late_max_cycles\": %llu, \"frames_dropped\": %llu, \"render\": %d, "
                "\"host_garbage\": %u, \"host_crc_errors\": %u},\n",
                lockstep_ticks, (unsigned long long)ls_period(), (unsigned long long)ls_frames,
                (unsigned long long)ls_currents, (unsigned long long)ls_waits, ls_wait_wall_s,
                (unsigned long long)ls_timeouts, ls_free, (unsigned long long)ls_late,
                (unsigned long long)ls_late_max, (unsigned long long)ls_dropped, ls_render,
                ls_in_parser.garbage, ls_in_parser.crc_errors);
    fprintf(f, " \"ticks\": %llu, \"compare_matches\": %llu, \"tick_in_progress\": %d, \"tick_overruns\": %llu,\n",
            (unsigned long long)ticks, (unsigned long long)(compare_matches - (tick_open ? 1 : 0)), tick_open,
            (unsigned long long)tick_overruns);
    fprintf(f, " \"overrun_at_cycles\": [");
    for (unsigned k = 0; k < 8 && k < tick_overruns; k++) fprintf(f, "%s%llu", k ? ", " : "", (unsigned long long)overrun_at[k]);
    fprintf(f, "],\n");
    fprintf(f, " \"tick_cycles\": {\"min\": %u, \"median\": %u, \"p99\": %u, \"max\": %u},\n", mn, med, p99, mx);
    fprintf(f, " \"tick_own_cycles\": {\"min\": %u, \"median\": %u, \"p99\": %u, \"max\": %u},\n", omn, omed, op99, omx);
    fprintf(f, " \"tick_body_cycles\": {\"min\": %u, \"median\": %u, \"p99\": %u, \"max\": %u},\n", bmn, bmed, bp99, bmx);
    fprintf(f, " \"frame_handling_max_cycles\": %u, \"frames_handled\": %u,\n", frame_max, frames_handled);
    fprintf(f, " \"rearm_data_frames\": {\"n\": %u, \"max_cycles\": %u, \"mean_cycles\": %.0f, \"own_max_cycles\": %u, "
            "\"own_mean_cycles\": %.0f},\n", rearm_frames, rearm_frame_max,
            rearm_frames ? (double)rearm_frame_total / rearm_frames : 0.0, rearm_own_max,
            rearm_frames ? (double)rearm_own_total / rearm_frames : 0.0);
    fprintf(f, " \"worst_tick\": {\"cycles\": %llu, \"at_cycle\": %llu, \"latency\": %llu, \"nested\": {",
            (unsigned long long)worst_total, (unsigned long long)worst_at, (unsigned long long)worst_latency);
    for (size_t k = 0, first = 1; k < N_ISR && k < 8; k++)
        if (isr[k].vec != V_TIMER1_COMPA) {
            fprintf(f, "%s\"%s\": [%u, %u]", first ? "" : ", ", isr[k].name, worst_nest[k].n, worst_nest[k].cycles);
            first = 0;
        }
    fprintf(f, "}, \"transient_kind\": %d, \"thermal_step\": %d, \"pc_cycles\": [", worst_kind, worst_thermal);
    for (unsigned w = 0, first = 1; w < NPC; w++)
        if (worst_pc[w]) { fprintf(f, "%s[%u, %u]", first ? "" : ", ", w * 2, worst_pc[w]); first = 0; }
    fprintf(f, "]},\n");
    fprintf(f, " \"thermal_steps\": %llu, \"transient_ticks\": {", (unsigned long long)thermal_steps);
    for (int k = 0; k < 5; k++)
        fprintf(f, "%s\"%d\": {\"n\": %llu, \"with_rx\": %llu, \"max_cycles\": %u}", k ? ", " : "", k,
                (unsigned long long)tr_ticks[k], (unsigned long long)tr_rx_ticks[k], tr_max[k]);
    fprintf(f, "},\n");
    fprintf(f, " \"isr\": {");
    for (size_t k = 0; k < N_ISR; k++)
        fprintf(f, "%s\"%s\": {\"n\": %llu, \"max_cycles\": %u, \"max_latency_cycles\": %u, \"max_latency_at_cycle\": %llu}",
                k ? ", " : "", isr[k].name, (unsigned long long)isr[k].n, isr[k].max_dur, isr[k].max_lat,
                (unsigned long long)isr[k].max_lat_at);
    fprintf(f, "},\n \"ram_stack_high_water_bytes\": %u, \"bss_end\": %u,\n", ram_high_water(), sym_bss_end);
    fprintf(f, " \"encoder_true\": %lld, \"encoder_fw\": %d,\n", (long long)(enc_true - enc_c0), fw_encoder());
    fprintf(f, " \"sweeps\": [");
    for (int k = 0; k < n_sweep && k <= sweep_k && k < 32; k++)
        if (sweep_res[k].moved)
            fprintf(f, "%s{\"v_m_s\": %.4f, \"counts\": %lld, \"missed\": %lld}", k ? ", " : "", sweep_res[k].v,
                    (long long)sweep_res[k].moved, (long long)sweep_res[k].missed);
    fprintf(f, "], \"sweep_done\": %d,\n", hand_mode == HAND_SWEEP && sweep_k >= n_sweep);
    fprintf(f, " \"position_m\": %.7f, \"motor_A\": %.5f, \"motor_zeroings\": %u, \"zero_after_host_silence_ms\": %.4f,\n",
            x, i_motor, motor_zeroings, wd_last_ms);
    fprintf(f, " \"bytes_to_mcu\": %llu, \"bytes_from_mcu\": %llu, \"pty_drops\": %llu,\n",
            (unsigned long long)bytes_to_mcu, (unsigned long long)bytes_from_mcu, (unsigned long long)pty_drops);
    fprintf(f, " \"faults\": {\"dropped\": %llu, \"corrupted\": %llu, \"garbage\": %llu, \"duplicated\": %llu, \"disconnected\": %d},\n",
            (unsigned long long)frames_dropped, (unsigned long long)frames_corrupted, (unsigned long long)frames_garbage,
            (unsigned long long)frames_duplicated, disconnected);
    fprintf(f, " \"selfhost\": {\"states\": %llu, \"events\": %llu, \"seq_gaps\": %llu, \"naks\": %llu, \"acks\": %llu, "
            "\"rearm_acks\": %llu, \"rearms\": %llu, \"rearm_timeouts\": %llu, \"rearm_max_ms\": %.3f, "
            "\"events_sinusoid\": %llu, \"events_rearm\": %llu, \"rearm_busy\": %llu}",
            (unsigned long long)sh_states, (unsigned long long)sh_events, (unsigned long long)sh_gaps,
            (unsigned long long)sh_naks, (unsigned long long)sh_acks, (unsigned long long)sh_rearm_acks,
            (unsigned long long)sh_rearms, (unsigned long long)sh_rearm_timeouts, sh_rearm_max_s * 1000,
            (unsigned long long)sh_events_kind[2], (unsigned long long)sh_events_kind[4],
            (unsigned long long)sh_rearm_busy);
    if (sym_parser) {
        uint8_t *d = avr->data + sym_parser + HFAM_MAX_PAYLOAD + HFAM_OVERHEAD + 2;
        fprintf(f, ",\n \"fw_parser\": {\"crc_errors\": %u, \"garbage\": %u}", d[0] | (d[1] << 8), d[2] | (d[3] << 8));
    }
    if (sym_rx_overruns) /* received bytes the firmware dropped: its RX ring was full */
        fprintf(f, ",\n \"fw_rx_overruns\": %u", avr->data[sym_rx_overruns] | (avr->data[sym_rx_overruns + 1] << 8));
    fprintf(f, "}\n");
    fclose(f);
    rename(tmp, stats_path);
}

static double wall_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int parse_list(const char *s, double *out, int max) {
    int n = 0;
    while (s && *s && n < max) {
        char *end;
        double val = strtod(s, &end);
        if (end == s) { fprintf(stderr, "error: bad number list %s\n", s); exit(2); }
        out[n++] = val;
        s = *end == ',' ? end + 1 : end;
    }
    return n;
}

static void parse_faults(const char *s) {
    char buf[512];
    snprintf(buf, sizeof buf, "%s", s);
    for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        char *eq = strchr(tok, '=');
        if (!eq) { fprintf(stderr, "error: --fault %s: expected key=value\n", tok); exit(2); }
        *eq = 0;
        double val = atof(eq + 1);
        if (!strcmp(tok, "drop")) f_drop = val;
        else if (!strcmp(tok, "corrupt")) f_corrupt = val;
        else if (!strcmp(tok, "garbage")) f_garbage = val;
        else if (!strcmp(tok, "duplicate")) f_duplicate = val;
        else if (!strcmp(tok, "disconnect_after_s")) f_disconnect_s = val;
        else { fprintf(stderr, "error: --fault: unknown fault %s\n", tok); exit(2); }
    }
    faults_on = f_drop > 0 || f_corrupt > 0 || f_garbage > 0 || f_duplicate > 0;
}

int main(int argc, char **argv) {
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
#define OPT(name) (!strcmp(a, name) && val && ++i)
        if (OPT("--elf")) elf_path = val;
        else if (OPT("--stats")) stats_path = val;
        else if (OPT("--pace")) { pace_realtime = !strcmp(val, "realtime"); pace_lockstep = !strcmp(val, "lockstep"); }
        else if (OPT("--lockstep-ticks")) lockstep_ticks = (unsigned)atoi(val);
        else if (OPT("--lockstep-free-run-s")) lockstep_free_run_s = atof(val);
        else if (OPT("--speed")) speed = atof(val);
        else if (OPT("--max-sim-s")) max_sim_s = atof(val);
        else if (OPT("--sym-encoder")) sym_encoder = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-bss-end")) sym_bss_end = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-parser")) sym_parser = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-probe")) sym_probe = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-po-e")) sym_po_e = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-tr-k")) sym_tr_k = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-ev-kind")) sym_ev_kind = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-heat-n")) sym_heat_n = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--sym-rx-overruns")) sym_rx_overruns = (uint16_t)strtoul(val, NULL, 0);
        else if (OPT("--tick-log")) { tick_log = fopen(val, "wb"); if (!tick_log) { perror(val); return 2; } }
        else if (OPT("--taps")) { n_taps = parse_list(val, taps, 32); hand_mode = n_taps ? HAND_TAP : HAND_HOLD; }
        else if (OPT("--hold-m")) { hand_mode = HAND_HOLD; hold_m = atof(val); }
        else if (OPT("--sweep")) { hand_mode = HAND_SWEEP; n_sweep = parse_list(val, sweep_v, 32); }
        else if (OPT("--sweep-amp-m")) sweep_amp_m = atof(val);
        else if (OPT("--grip-N")) grip_N = atof(val);
        else if (OPT("--fault")) parse_faults(val);
        else if (OPT("--seed")) rng_state = (unsigned)atoi(val);
        else if (!strcmp(a, "--selfhost")) selfhost = 1;
        else if (OPT("--decimation")) sh_decimation = atoi(val) < 1 ? 1 : atoi(val);
        else if (OPT("--profile")) profile = atoi(val); /* 1: the tick (GPIOR0 mark); 3: frames' own code; 5: the main loop during re-arm uploads */
        else { fprintf(stderr, "error: unknown or incomplete option %s\n", a); return 2; }
    }
    if (getenv("FW_SIM_TRACE_FROM")) trace_from = strtoull(getenv("FW_SIM_TRACE_FROM"), NULL, 0);
    if (!elf_path) { fprintf(stderr, "error: --elf FILE is required\n"); return 2; }
    if (pace_lockstep && !(lockstep_ticks >= 1 && lockstep_ticks <= 255 && lockstep_free_run_s >= 0)) {
        fprintf(stderr, "error: --lockstep-ticks must be 1..255 and --lockstep-free-run-s >= 0\n");
        return 2;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf_path, &fw) != 0) { fprintf(stderr, "error: cannot read firmware %s\n", elf_path); return 2; }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) { fprintf(stderr, "error: simavr has no atmega328p core\n"); return 2; }
    avr_init(avr);
    avr->log = getenv("FW_SIM_LOG") ? atoi(getenv("FW_SIM_LOG")) : LOG_NONE;
    fw.frequency = F_CPU_HZ;
    avr_load_firmware(avr, &fw);
    avr->frequency = F_CPU_HZ;
    avr->vcc = avr->avcc = avr->aref = 5000;
    if (sym_bss_end)
        for (unsigned a = sym_bss_end; a <= RAM_END; a++) avr->data[a] = PAINT; /* stack painting */

    pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3);
    adc_irq = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, 0);
    set_pins(0);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook, NULL);
    for (size_t k = 0; k < N_ISR; k++) {
        avr_irq_t *irq = avr_get_interrupt_irq(avr, (uint8_t)isr[k].vec);
        if (!irq) continue;
        avr_irq_register_notify(irq + AVR_INT_IRQ_PENDING, isr_pending, (void *)k);
        avr_irq_register_notify(irq + AVR_INT_IRQ_RUNNING, isr_running, (void *)k);
    }
    avr_register_io_write(avr, A_GPIOR0, gpior0_write, NULL);
    x = x_target = 0.0; /* powered up at the home position: the encoder's zero */
    if (hand_mode == HAND_SWEEP) x = sweep_amp_m, x_target = x;
    enc_true = enc_emitted = enc_c0 = enc_count_of(x);
    set_pins(enc_true);
    set_adc(0, ACCEL_OFFSET);
    set_adc(1, grip_N / GRIP_SCALE);
    avr_cycle_timer_register(avr, PHYS_CYCLES, phys_cb, NULL);
    sweep_mark_true = enc_true;

    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGPIPE, SIG_IGN);
    if (!selfhost) {
        master_fd = posix_openpt(O_RDWR | O_NOCTTY);
        if (master_fd < 0 || grantpt(master_fd) || unlockpt(master_fd)) { perror("error: pty"); return 2; }
        const char *name = ptsname(master_fd);
        slave_fd = open(name, O_RDWR | O_NOCTTY); /* kept open: the pty survives host close/reopen */
        struct termios tio;
        tcgetattr(master_fd, &tio); cfmakeraw(&tio); tcsetattr(master_fd, TCSANOW, &tio);
        tcgetattr(slave_fd, &tio); cfmakeraw(&tio); tcsetattr(slave_fd, TCSANOW, &tio);
        fcntl(master_fd, F_SETFL, fcntl(master_fd, F_GETFL) | O_NONBLOCK);
        printf("PORT %s\n", name);
        fflush(stdout);
    }
    pid_t parent = getppid();
    double t0 = wall_s(), last_stats = t0, max_lag = 0;
    avr_cycle_count_t next_service = SERVICE_CYCLES;
    int state = cpu_Running;
    double ls_wait_since = 0.0;
    while (!quit) {
        if (pace_lockstep && !selfhost) {
            pty_read();
            while (ls_release()) {}
            feed_uart();
            if (ls_must_wait()) {
                double now = wall_s();
                if (ls_wait_since == 0.0) { ls_wait_since = now; ls_waits++; }
                if (lockstep_free_run_s > 0 && now - ls_wait_since > lockstep_free_run_s) {
                    /* the host is gone or hung: run free in real time (the firmware watchdog acts as on a board) */
                    ls_free = 1;
                    ls_timeouts++;
                    ls_wait_wall_s += now - ls_wait_since;
                    ls_wait_since = 0.0;
                    t0 = now - avr->cycle / (double)F_CPU_HZ / speed;
                } else {
                    struct pollfd pfd = {master_fd, POLLIN, 0};
                    struct timespec ts = {0, 20000000}; /* wake for the stats file and the parent check */
                    ppoll(&pfd, master_fd >= 0 ? 1 : 0, &ts, NULL);
                    if (now - last_stats > 0.05) {
                        write_stats(0);
                        if (tick_log) fflush(tick_log);
                        last_stats = now;
                        if (getppid() != parent) break;
                    }
                    continue;
                }
            } else if (ls_wait_since != 0.0) {
                ls_wait_wall_s += wall_s() - ls_wait_since;
                ls_wait_since = 0.0;
            }
            if (!ls_free && !ls_render && ls_horizon > avr->cycle && next_service > ls_horizon) next_service = ls_horizon;
        }
        while (avr->cycle < next_service) {
            avr_cycle_count_t c_before = avr->cycle;
            uint32_t pc_before = avr->pc;
            state = avr_run(avr);
            if (trace_from && c_before >= trace_from)
                fprintf(stderr, "T %llu pc %x sp %x g %d\n", (unsigned long long)c_before, pc_before,
                        avr->data[0x5D] | (avr->data[0x5E] << 8), avr->data[A_GPIOR0]);
            if (profile == 3 ? frame_open && !isr_depth : profile == 5 ? !frame_open && !isr_depth && sh_rearm_off >= 0 : profile && avr->data[A_GPIOR0] == profile) /* 3: frames own code; 5: main loop during re-arms */
                prof[(pc_before >> 1) & 0x3FFF] += (uint32_t)(avr->cycle - c_before);
            if (tick_open || avr->data[A_GPIOR0] == 1) { /* everything the CPU ran between a compare match and its tick's end */
                unsigned w = (pc_before >> 1) & (NPC - 1);
                if (!cur_pc[w]) cur_touched[n_touched++] = (uint16_t)w;
                cur_pc[w] += (uint32_t)(avr->cycle - c_before);
            }
            if (state == cpu_Done || state == cpu_Crashed) break;
        }
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "error: firmware stopped (%s) at cycle %llu, pc 0x%x, sp 0x%x\n",
                    state == cpu_Done ? "done" : "crashed", (unsigned long long)avr->cycle, avr->pc,
                    avr->data[0x5D] | (avr->data[0x5E] << 8));
            break;
        }
        next_service = avr->cycle + SERVICE_CYCLES;
        uart_fix_byte_time();
        double sim_s = avr->cycle / (double)F_CPU_HZ;
        if (selfhost) selfhost_step();
        else {
            pty_read();
            if (f_disconnect_s >= 0 && attach_cycle && !disconnected &&
                (avr->cycle - attach_cycle) / (double)F_CPU_HZ > f_disconnect_s) {
                disconnected = 1; /* the link goes away: the host sees EIO/HUP; the MCU keeps running */
                close(master_fd); close(slave_fd); master_fd = slave_fd = -1;
            }
            if (!pty_flush() && pace_realtime) { pty_drops += (oq_head + QN - oq_tail) % QN; oq_tail = oq_head; }
            if (pace_lockstep) while (ls_release()) {}
        }
        feed_uart();
        if (max_sim_s > 0 && sim_s >= max_sim_s) break;
        if (hand_mode == HAND_SWEEP && selfhost && sweep_k >= n_sweep) break;
        double now = wall_s();
        if (!selfhost) {
            if (pace_realtime || (pace_lockstep && ls_free)) {
                double ahead = sim_s / speed - (now - t0);
                if (ahead > 0.0002) { /* ahead of the wall clock: sleep, but wake at once for host bytes */
                    struct pollfd pfd = {master_fd, POLLIN, 0};
                    struct timespec ts = {0, (long)(ahead * 1e9)};
                    ppoll(&pfd, master_fd >= 0 ? 1 : 0, &ts, NULL);
                } else if (-ahead > max_lag) max_lag = -ahead;
            } else {
                /* fast: run while the host keeps up; wait while it has unread telemetry or output is blocked */
                while (!quit && master_fd >= 0 && (pty_unread() > HOST_BACKLOG || oq_tail != oq_head)) {
                    struct pollfd pfd = {master_fd, POLLIN | POLLOUT, 0};
                    poll(&pfd, 1, 1);
                    pty_read();
                    pty_flush();
                }
            }
        }
        if (now - last_stats > 0.05) {
            write_stats(0);
            if (tick_log) fflush(tick_log);
            last_stats = now;
            if (getppid() != parent) break; /* the host program is gone: do not run on as an orphan */
        }
    }
    write_stats(1);
    if (tick_log) fclose(tick_log);
    if (profile)
        for (unsigned k = 0; k < 0x4000; k++)
            if (prof[k]) fprintf(stderr, "PROF %x %u\n", k * 2, prof[k]);
    if (master_fd >= 0) close(master_fd);
    if (slave_fd >= 0) close(slave_fd);
    return state == cpu_Crashed ? 3 : 0;
}
