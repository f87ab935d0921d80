/* A fake OpenHaptics HD library (libHD) for the Touch adapter's tests: the HD API's functions the adapter
 * calls, a 1 kHz scheduler thread, and a Touch-like endpoint (a 50 g point mass held by a hand that taps
 * along y, HD's up axis) in HD's frame and units (mm, N). Written for these tests; no OpenHaptics code.
 *
 * Environment: FAKEHD_VERSION (hdGetString(HD_VERSION), default "3.4.0"), FAKEHD_NAME (a device name
 * accepted besides "Default Device"), FAKEHD_BUSY=1 (hdInitDevice fails: another program has it),
 * FAKEHD_FAULT_AFTER=N (from tick N on: HD_COMM_ERROR on the error stack, no force applied: unplugged).
 * Instrumentation: fakehd_stats(double out[10]) = ticks, max period between callback starts (ns), max
 * callback duration (ns), periods over 2 ms, |force| applied last tick, the force (3), max |force| ever,
 * ticks with a force applied after the last callback stopped commanding.
 *
 * Build: cc -shared -fPIC -O2 -o libfakehd.so fake_hd.c -lpthread -lm
 */
#define _GNU_SOURCE
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef unsigned int HHD;
typedef unsigned int HDenum;
typedef unsigned int HDerror;
typedef unsigned int HDCallbackCode;
typedef unsigned long HDSchedulerHandle;
typedef HDCallbackCode (*HDSchedulerCallback)(void *);
typedef struct { HDerror errorCode; int internalErrorCode; HHD hHD; } HDErrorInfo;

#define HD_INVALID_HANDLE 0xFFFFFFFFu
#define HD_CURRENT_BUTTONS 0x2000
#define HD_CURRENT_POSITION 0x2050
#define HD_CURRENT_VELOCITY 0x2051
#define HD_VERSION 0x2500
#define HD_DEVICE_MODEL_TYPE 0x2501
#define HD_DEVICE_VENDOR 0x2503
#define HD_USABLE_WORKSPACE_DIMENSIONS 0x2551
#define HD_NOMINAL_MAX_FORCE 0x2603
#define HD_CURRENT_FORCE 0x2700
#define HD_FORCE_OUTPUT 0x4000
#define HD_DEVICE_FAULT 0x0300
#define HD_COMM_ERROR 0x0302
#define HD_ILLEGAL_BEGIN 0x0400

static pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
static pthread_t sched_thread;
static volatile int running = 0, inited = 0, force_enabled = 0, in_frame = 0;
static HDSchedulerCallback cb = 0;
static void *cb_data = 0;
static HDErrorInfo err = {0, 0, 0};
static double pos[3] = {0, 30, 0}, vel[3] = {0, 0, 0}, force[3] = {0, 0, 0}, frame_force[3] = {0, 0, 0};
static double t_s = 0;
static long ticks = 0, fault_after = -1;
static double max_period_ns = 0, max_cb_ns = 0, slow_periods = 0, max_force = 0;
static const double centre[3] = {0.0, 20.0, 0.0}; /* mm: the usable workspace's centre */
static char version[32] = "3.4.0";

static void set_error(HDerror code, int internal) { err.errorCode = code; err.internalErrorCode = internal; err.hHD = 0; }

static double hand_height_mm(double t) { /* one tap cycle of 1.65 s: 10 mm above to 5 mm below at 0.1 m/s */
    double h0 = 10.0, depth = 5.0, v = 100.0, dwell = 0.3, lift = 0.2, pause = 0.1;
    double down = (h0 + depth) / v, period = down + dwell + lift + pause, u = fmod(t, period);
    if (u < down) return h0 - v * u;
    u -= down;
    if (u < dwell) return -depth;
    u -= dwell;
    if (u < lift) return -depth + (h0 + depth) * 0.5 * (1 - cos(M_PI * u / lift));
    return h0;
}

static void step_physics(double dt) { /* mm, N, kg: a = F/m in m/s^2 = 1000 mm/s^2 per m/s^2 */
    const double m = 0.05, k = 400.0 /* N/m */, b = 3.0 /* N s/m */;
    double target[3] = {centre[0], centre[1] + hand_height_mm(t_s), centre[2]};
    for (int i = 0; i < 3; ++i) {
        double f = force[i] - k * (pos[i] - target[i]) * 1e-3 - b * vel[i] * 1e-3;
        vel[i] += f / m * 1e3 * dt;
        pos[i] += vel[i] * dt;
    }
    t_s += dt;
}

static double now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

static void *scheduler(void *arg) {
    (void)arg;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    double last_start = 0;
    while (running) {
        next.tv_nsec += 1000000;
        if (next.tv_nsec >= 1000000000) { next.tv_nsec -= 1000000000; next.tv_sec += 1; }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, 0);
        double start = now_ns();
        if (last_start > 0 && start - last_start > max_period_ns) max_period_ns = start - last_start;
        if (last_start > 0 && start - last_start > 2e6) slow_periods += 1;
        last_start = start;
        HDSchedulerCallback f = cb;
        if (f) {
            HDCallbackCode r = f(cb_data);
            double d = now_ns() - start;
            if (d > max_cb_ns) max_cb_ns = d;
            if (r == 0) cb = 0; /* HD_CALLBACK_DONE */
        } else {
            pthread_mutex_lock(&mu);
            force[0] = force[1] = force[2] = 0; /* no callback: the device holds no force */
            step_physics(1e-3);
            pthread_mutex_unlock(&mu);
        }
        ticks++;
    }
    return 0;
}

HHD hdInitDevice(const char *name) {
    const char *alt = getenv("FAKEHD_NAME");
    const char *v = getenv("FAKEHD_VERSION");
    if (v) { strncpy(version, v, sizeof version - 1); }
    const char *fa = getenv("FAKEHD_FAULT_AFTER");
    fault_after = fa ? atol(fa) : -1;
    if (getenv("FAKEHD_BUSY")) { set_error(HD_DEVICE_FAULT, 1); return HD_INVALID_HANDLE; }
    if (!name || !(strcmp(name, "Default Device") == 0 || (alt && strcmp(name, alt) == 0))) {
        set_error(HD_DEVICE_FAULT, 2);
        return HD_INVALID_HANDLE;
    }
    /* a fresh device: the library stays loaded across a test process's devices, its state must not */
    set_error(0, 0);
    ticks = 0;
    t_s = 0;
    for (int i = 0; i < 3; ++i) { vel[i] = 0; force[i] = 0; frame_force[i] = 0; pos[i] = centre[i]; }
    pos[1] += 10.0;
    inited = 1;
    return 0;
}
void hdDisableDevice(HHD h) { (void)h; inited = 0; force_enabled = 0; }
void hdMakeCurrentDevice(HHD h) { (void)h; }
HHD hdGetCurrentDevice(void) { return 0; }
void hdEnable(HDenum cap) { if (cap == HD_FORCE_OUTPUT) force_enabled = 1; }
void hdDisable(HDenum cap) { if (cap == HD_FORCE_OUTPUT) force_enabled = 0; }
HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback f, void *data, unsigned short prio) {
    (void)prio; cb_data = data; cb = f; return 1;
}
void hdUnschedule(HDSchedulerHandle h) { (void)h; cb = 0; }
void hdStartScheduler(void) {
    if (running) return;
    running = 1;
    pthread_create(&sched_thread, 0, scheduler, 0);
}
void hdStopScheduler(void) {
    if (!running) return;
    running = 0;
    pthread_join(sched_thread, 0);
    force[0] = force[1] = force[2] = 0;
}
HDErrorInfo hdGetError(void) { HDErrorInfo e = err; set_error(0, 0); return e; }
const char *hdGetErrorString(HDerror code) {
    switch (code) {
    case HD_DEVICE_FAULT: return getenv("FAKEHD_BUSY") ? "device in use by another application" : "no such device";
    case HD_COMM_ERROR: return "communication error (device unplugged?)";
    case HD_ILLEGAL_BEGIN: return "illegal begin frame";
    default: return "";
    }
}
const char *hdGetString(HDenum what) {
    if (what == HD_VERSION) { const char *v = getenv("FAKEHD_VERSION"); return v ? v : version; }
    if (what == HD_DEVICE_MODEL_TYPE) return "Touch (fake)";
    if (what == HD_DEVICE_VENDOR) return "fake";
    return "";
}
void hdBeginFrame(HHD h) {
    (void)h;
    if (in_frame) set_error(HD_ILLEGAL_BEGIN, 0);
    in_frame = 1;
    frame_force[0] = frame_force[1] = frame_force[2] = 0;
}
void hdEndFrame(HHD h) {
    (void)h;
    pthread_mutex_lock(&mu);
    int faulted = fault_after >= 0 && ticks >= fault_after;
    if (faulted) set_error(HD_COMM_ERROR, 0);
    for (int i = 0; i < 3; ++i) force[i] = (force_enabled && !faulted) ? frame_force[i] : 0.0;
    double m = sqrt(force[0] * force[0] + force[1] * force[1] + force[2] * force[2]);
    if (m > max_force) max_force = m;
    step_physics(1e-3);
    pthread_mutex_unlock(&mu);
    in_frame = 0;
}
void hdGetDoublev(HDenum what, double *out) {
    if (what == HD_CURRENT_POSITION) { out[0] = pos[0]; out[1] = pos[1]; out[2] = pos[2]; }
    else if (what == HD_CURRENT_VELOCITY) { out[0] = vel[0]; out[1] = vel[1]; out[2] = vel[2]; }
    else if (what == HD_USABLE_WORKSPACE_DIMENSIONS) {
        double d[6] = {-80, -40, -35, 80, 80, 35}; /* centre (0, 20, 0) mm */
        memcpy(out, d, sizeof d);
    } else if (what == HD_NOMINAL_MAX_FORCE) out[0] = 3.3;
}
void hdGetIntegerv(HDenum what, int *out) { if (what == HD_CURRENT_BUTTONS) out[0] = 0; }
void hdSetDoublev(HDenum what, const double *in) {
    if (what == HD_CURRENT_FORCE) { frame_force[0] = in[0]; frame_force[1] = in[1]; frame_force[2] = in[2]; }
}
void fakehd_stats(double *out) {
    out[0] = (double)ticks; out[1] = max_period_ns; out[2] = max_cb_ns; out[3] = slow_periods;
    out[4] = sqrt(force[0] * force[0] + force[1] * force[1] + force[2] * force[2]);
    out[5] = force[0]; out[6] = force[1]; out[7] = force[2]; out[8] = max_force; out[9] = pos[1];
}
void fakehd_reset_stats(void) { max_period_ns = 0; max_cb_ns = 0; slow_periods = 0; max_force = 0; }
