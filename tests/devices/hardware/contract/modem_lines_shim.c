/* An LD_PRELOAD shim giving a pseudo-terminal the modem lines of a USB CDC ACM port.
 *
 * A pty has no DTR/RTS: ioctl(TIOCMGET/TIOCMSET/TIOCMBIS/TIOCMBIC) on it fails with ENOTTY. A vendor
 * library that opens "its" serial port asserts DTR (a CDC ACM device sees that as "a host is here");
 * on a pty that call fails, which some vendor builds treat as fatal. Preloaded into such a program, this
 * shim answers those four requests for a terminal whose real ioctl fails, keeps the line state per
 * process, and appends one line per call to the file named by $HFAM_MODEM_LOG ("TIOCMSET 0x002"), so a
 * test can check what the program did with DTR. Every other ioctl goes to the C library unchanged.
 *
 * Build: cc -shared -fPIC -o modem_lines_shim.so modem_lines_shim.c -ldl
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

static int modem_bits = 0;

static void log_call(const char *what, int value) {
    const char *path = getenv("HFAM_MODEM_LOG");
    if (!path) return;
    FILE *f = fopen(path, "a");
    if (!f) return;
    fprintf(f, "%s 0x%03x\n", what, value);
    fclose(f);
}

int ioctl(int fd, unsigned long request, ...) {
    static int (*real_ioctl)(int, unsigned long, ...) = 0;
    va_list ap;
    va_start(ap, request);
    void *arg = va_arg(ap, void *);
    va_end(ap);
    if (!real_ioctl) real_ioctl = (int (*)(int, unsigned long, ...))dlsym(RTLD_NEXT, "ioctl");
    int r = real_ioctl(fd, request, arg);
    if (r == 0 || !(request == TIOCMGET || request == TIOCMSET || request == TIOCMBIS || request == TIOCMBIC))
        return r;
    if (!isatty(fd)) return r;
    int *bits = (int *)arg;
    switch (request) {
    case TIOCMGET: *bits = modem_bits | TIOCM_DSR | TIOCM_CTS | TIOCM_CD; log_call("TIOCMGET", *bits); break;
    case TIOCMSET: modem_bits = *bits; log_call("TIOCMSET", modem_bits); break;
    case TIOCMBIS: modem_bits |= *bits; log_call("TIOCMBIS", modem_bits); break;
    case TIOCMBIC: modem_bits &= ~*bits; log_call("TIOCMBIC", modem_bits); break;
    }
    errno = 0;
    return 0;
}
