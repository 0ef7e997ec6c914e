/* posix port: N controllers of the C core on one RS-485-style bus, served on a pseudo-terminal,
 * each with its storage in a file and DC-motor models for its pixels (generic/sim_pixels.c).
 *
 *   grassfw-posix --state-dir DIR [--count N | --addresses A,B,..] [--pixels P[,P2,..]]
 *                 [--link PATH] [--max-chunk B] [--baud BAUD] [--power-cut-at K[:KEEP]]
 *                 [--trace FILE]
 *
 * --count N: addresses 1..N (default 1); --addresses: these addresses instead. --pixels: one
 * pixel count for all (default FW_DEFAULT_PIXELS, 16), or one per controller. Controller a reports
 * uid FW_DEFAULT_UID(a); --max-chunk defaults to FW_DEFAULT_MAX_CHUNK (core/board_defaults.h).
 * --baud: pace the line as a UART at that rate would (8N1: 10 bit times per byte) both ways.
 * Prints the pty's path (the --link symlink if given) on stdout, then serves until SIGINT or
 * SIGTERM. Controller a (1..N) keeps its two banks in DIR/controller-<a>.eeprom (the layout of
 * rigs/eeprom.py, so either side reads the other's files) and its counters in
 * DIR/controller-<a>.stats ("boots B writes W"). --power-cut-at K: the K-th storage write or
 * erase of the process (1-based) stores only its first half (KEEP: "half", "none" or "all-but-
 * one" of its bytes), then the process exits with status 3, as a controller losing power in
 * the middle of that write. --trace FILE: whenever the bytes just received changed a
 * controller's motor targets, append "NS ADDRESS CHANGED" to FILE (NS: CLOCK_MONOTONIC in
 * nanoseconds, taken after the frame was handled; CHANGED: pixels whose target changed), so that
 * tests see when each controller of several processes moved (the frame latch's spread).
 *
 * Lines on stdin control the simulated line (tests): "unplug MS" closes the pty (the host sees
 * EIO), removes the link, power-cycles the controllers, prints "unplugged", and after MS
 * milliseconds opens a new pty behind the link and prints "plugged PATH". */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>
#include "../../core/controller.h"
#include "../../generic/sim_pixels.h"

#define EXIT_POWER_CUT 3

typedef struct unit {
    fw_controller ctl;
    fw_hal hal;
    int nv_fd, stats_fd;
    uint32_t boots, writes;
    sim_pixels pixels;
    uint16_t traced_um[FW_MAX_PIXELS];   /* targets at the last trace check (--trace) */
} unit;

static struct {
    int master, slave;
    char device[128];
    const char *link;
    long power_cut_at, writes, baud;
    int cut_keep;   /* 0: half of the write lands, 1: none of it, 2: all but its last byte */
    double line_free;   /* seconds (monotonic) when the paced line is free again */
    int trace_fd;       /* --trace FILE, or -1 */
    uint64_t t0_ms;
    volatile sig_atomic_t stop;
} bus = {.master = -1, .slave = -1, .trace_fd = -1};

static void die(const char *what)
{
    fprintf(stderr, "grassfw-posix: %s: %s\n", what, strerror(errno));
    exit(2);
}

static uint64_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* Hold until n more bytes have crossed a line of bus.baud (nothing when unpaced). */
static void pace(size_t n)
{
    if (!bus.baud)
        return;
    double now = now_s();
    bus.line_free = (bus.line_free > now ? bus.line_free : now) + (double)n * 10.0 / (double)bus.baud;
    double wait = bus.line_free - now;
    if (wait > 0) {
        struct timespec ts = {(time_t)wait, (long)((wait - (double)(time_t)wait) * 1e9)};
        nanosleep(&ts, NULL);
    }
}

/* ---- HAL ------------------------------------------------------------------------------- */

static void save_stats(unit *u)
{
    char line[64];
    int n = snprintf(line, sizeof line, "boots %10u writes %10u\n", u->boots, u->writes);
    if (pwrite(u->stats_fd, line, (size_t)n, 0) != n)
        die("cannot write the stats file");
}

static void hal_tx(void *ctx, const uint8_t *data, size_t n)
{
    (void)ctx;
    pace(n);
    if (bus.master >= 0 && write(bus.master, data, n) < 0) {
        /* nobody reading, or the pty buffer is full: the bytes are lost, as on a wire */
    }
}

static int hal_nv_read(void *ctx, uint32_t off, uint8_t *buf, uint32_t n)
{
    unit *u = ctx;
    return pread(u->nv_fd, buf, n, off) == (ssize_t)n ? 0 : -1;
}

static int nv_store(unit *u, uint32_t off, const uint8_t *data, uint32_t n)
{
    uint32_t keep = n;
    int cut = ++bus.writes == bus.power_cut_at;
    if (cut)
        keep = bus.cut_keep == 1 ? 0 : bus.cut_keep == 2 ? n - 1 : n / 2;   /* power fails */
    if (keep && pwrite(u->nv_fd, data, keep, off) != (ssize_t)keep)
        return -1;
    if (cut) {
        fprintf(stderr, "grassfw-posix: power cut at storage write %ld (%u of %u bytes at %u)\n",
                bus.writes, keep, n, off);
        _exit(EXIT_POWER_CUT);
    }
    u->writes++;
    save_stats(u);
    return 0;
}

static int hal_nv_write(void *ctx, uint32_t off, const uint8_t *data, uint32_t n)
{
    return nv_store(ctx, off, data, n);
}

static int hal_nv_erase(void *ctx, uint32_t off, uint32_t n)
{
    uint8_t ff[64];
    memset(ff, FW_NV_ERASED, sizeof ff);
    if (n > sizeof ff)
        return -1;   /* the core erases 4-byte magics only */
    return nv_store(ctx, off, ff, n);
}

static uint32_t hal_millis(void *ctx)
{
    (void)ctx;
    return (uint32_t)(now_ms() - bus.t0_ms);
}

static int32_t hal_encoder(void *ctx, uint16_t p)
{
    unit *u = ctx;
    return sim_pixels_encoder(&u->pixels, p);
}

static void hal_pwm(void *ctx, uint16_t p, int16_t duty)
{
    ((unit *)ctx)->pixels.duty[p] = duty;
}

/* ---- storage files --------------------------------------------------------------------- */

static int open_file(const char *dir, int address, const char *suffix, uint32_t size)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/controller-%d.%s", dir, address, suffix);
    int fd = open(path, O_RDWR | O_CREAT, 0644);
    if (fd < 0)
        die(path);
    off_t have = lseek(fd, 0, SEEK_END);
    if (size && have != (off_t)size) {   /* new, or laid out for another pixel count: erase */
        static uint8_t ff[4096];
        memset(ff, FW_NV_ERASED, sizeof ff);
        if (ftruncate(fd, 0) < 0)
            die(path);
        for (uint32_t o = 0; o < size; o += sizeof ff) {
            size_t k = size - o < sizeof ff ? size - o : sizeof ff;
            if (pwrite(fd, ff, k, o) != (ssize_t)k)
                die(path);
        }
    }
    return fd;
}

/* ---- the line -------------------------------------------------------------------------- */

static void plug(void)
{
    struct termios t;
    if (openpty(&bus.master, &bus.slave, bus.device, NULL, NULL) < 0)
        die("cannot create a pseudo-terminal");
    if (tcgetattr(bus.slave, &t) == 0) {
        cfmakeraw(&t);
        tcsetattr(bus.slave, TCSANOW, &t);
    }
    fcntl(bus.master, F_SETFL, fcntl(bus.master, F_GETFL) | O_NONBLOCK);
    fcntl(bus.master, F_SETFD, FD_CLOEXEC);
    fcntl(bus.slave, F_SETFD, FD_CLOEXEC);
    if (bus.link) {
        char tmp[4200];
        snprintf(tmp, sizeof tmp, "%s.new", bus.link);
        unlink(tmp);
        if (symlink(bus.device, tmp) < 0 || rename(tmp, bus.link) < 0)
            die(bus.link);
    }
}

static void unplug(void)
{
    close(bus.master);
    close(bus.slave);
    bus.master = bus.slave = -1;
    if (bus.link)
        unlink(bus.link);
}

static void boot(unit *u, const fw_config *cfg)
{
    u->boots++;
    save_stats(u);
    if (fw_boot(&u->ctl, &u->hal, cfg) < 0) {
        fprintf(stderr, "grassfw-posix: invalid controller configuration\n");
        exit(2);
    }
    for (uint16_t p = 0; p < cfg->n_pixels; p++)   /* the boot's targets: not a frame's */
        u->traced_um[p] = fw_target_um(&u->ctl, p);
}

/* --trace: one line when a frame just changed some of u's targets. */
static void trace_targets(unit *u, const fw_config *cfg)
{
    uint16_t changed = 0;
    for (uint16_t p = 0; p < cfg->n_pixels; p++) {
        uint16_t um = fw_target_um(&u->ctl, p);
        if (um != u->traced_um[p]) {
            u->traced_um[p] = um;
            changed++;
        }
    }
    if (!changed)
        return;
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    dprintf(bus.trace_fd, "%lld %u %u\n", (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec,
            cfg->address, changed);
}

static void on_signal(int sig)
{
    (void)sig;
    bus.stop = 1;
}

static long arg_long(const char *name, const char *v, long lo, long hi)
{
    char *end;
    long x = strtol(v, &end, 0);
    if (*v == 0 || *end != 0 || x < lo || x > hi) {
        fprintf(stderr, "grassfw-posix: %s must be %ld..%ld, got '%s'\n", name, lo, hi, v);
        exit(2);
    }
    return x;
}

/* A comma-separated list of numbers lo..hi into out (at most max); returns how many. */
static long arg_list(const char *name, const char *v, long lo, long hi, long *out, long max)
{
    char copy[2048];
    snprintf(copy, sizeof copy, "%s", v);
    long n = 0;
    for (char *save = NULL, *tok = strtok_r(copy, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        if (n == max) {
            fprintf(stderr, "grassfw-posix: %s: at most %ld values\n", name, max);
            exit(2);
        }
        out[n++] = arg_long(name, tok, lo, hi);
    }
    if (n == 0)
        arg_long(name, v, lo, hi);   /* reports the empty value */
    return n;
}

int main(int argc, char **argv)
{
    static long addresses[FW_MAX_ADDRESS], pixel_list[FW_MAX_ADDRESS];
    long count = 1, n_pixel_list = 1, max_chunk = FW_DEFAULT_MAX_CHUNK;
    int explicit_addresses = 0;
    const char *dir = NULL;
    pixel_list[0] = FW_DEFAULT_PIXELS < FW_MAX_PIXELS ? FW_DEFAULT_PIXELS : FW_MAX_PIXELS;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (v == NULL) {
            fprintf(stderr, "grassfw-posix: %s needs a value\n", a);
            return 2;
        }
        i++;
        if (!strcmp(a, "--count"))
            count = arg_long(a, v, 1, FW_MAX_ADDRESS);
        else if (!strcmp(a, "--addresses")) {
            count = arg_list(a, v, FW_MIN_ADDRESS, FW_MAX_ADDRESS, addresses, FW_MAX_ADDRESS);
            explicit_addresses = 1;
        } else if (!strcmp(a, "--pixels"))   /* FW_MAX_PIXELS: make POSIX_PIXELS=N to raise */
            n_pixel_list = arg_list("--pixels (this build's FW_MAX_PIXELS; make POSIX_PIXELS=N "
                                    "raises it)", v, 1, FW_MAX_PIXELS, pixel_list, FW_MAX_ADDRESS);
        else if (!strcmp(a, "--max-chunk"))
            max_chunk = arg_long(a, v, 1, FW_MAX_CHUNK_DATA);
        else if (!strcmp(a, "--baud"))
            bus.baud = arg_long(a, v, 300, 10000000);
        else if (!strcmp(a, "--power-cut-at")) {
            char k[32];
            snprintf(k, sizeof k, "%s", v);
            char *colon = strchr(k, ':');
            if (colon) {
                *colon = 0;
                const char *keep = colon + 1;
                bus.cut_keep = !strcmp(keep, "half") ? 0 : !strcmp(keep, "none") ? 1
                             : !strcmp(keep, "all-but-one") ? 2 : -1;
                if (bus.cut_keep < 0) {
                    fprintf(stderr, "grassfw-posix: --power-cut-at K:KEEP, KEEP is half, none "
                                    "or all-but-one, got '%s'\n", keep);
                    return 2;
                }
            }
            bus.power_cut_at = arg_long(a, k, 1, 1L << 30);
        }
        else if (!strcmp(a, "--state-dir"))
            dir = v;
        else if (!strcmp(a, "--link"))
            bus.link = v;
        else if (!strcmp(a, "--trace")) {
            bus.trace_fd = open(v, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
            if (bus.trace_fd < 0)
                die(v);
        }
        else {
            fprintf(stderr, "grassfw-posix: unknown option %s (see the comment in main.c)\n", a);
            return 2;
        }
    }
    if (dir == NULL) {
        fprintf(stderr, "grassfw-posix: --state-dir DIR is required (storage files live there)\n");
        return 2;
    }
    unit *units = calloc((size_t)count, sizeof *units);
    fw_config *cfgs = calloc((size_t)count, sizeof *cfgs);
    if (!units || !cfgs)
        die("out of memory");
    if (n_pixel_list != 1 && n_pixel_list != count) {
        fprintf(stderr, "grassfw-posix: --pixels needs one value or one per controller (%ld)\n",
                count);
        return 2;
    }
    bus.t0_ms = now_ms();
    for (long i = 0; i < count; i++) {
        unit *u = &units[i];
        int address = explicit_addresses ? (int)addresses[i] : (int)i + 1;
        long pixels = pixel_list[n_pixel_list == 1 ? 0 : i];
        uint32_t nv_size = fw_banks_size((uint16_t)pixels);
        u->nv_fd = open_file(dir, address, "eeprom", nv_size);
        u->stats_fd = open_file(dir, address, "stats", 0);
        sim_pixels_init(&u->pixels);
        u->hal = (fw_hal){u, hal_tx, hal_nv_read, hal_nv_write, hal_nv_erase, hal_millis,
                          hal_encoder, hal_pwm};
        cfgs[i] = fw_config_default((uint8_t)address, (uint16_t)pixels);
        cfgs[i].max_chunk = (uint16_t)max_chunk;
        boot(u, &cfgs[i]);
    }
    struct sigaction sa = {.sa_handler = on_signal};
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    plug();
    printf("%s\n", bus.link ? bus.link : bus.device);
    fflush(stdout);

    uint64_t last = now_ms(), replug_at = 0;
    int stdin_open = 1, idle = 1;
    char cmd[256];
    size_t cmd_len = 0;
    uint8_t buf[4096];
    while (!bus.stop) {
        struct pollfd fds[2] = {{.fd = bus.master, .events = POLLIN}, {.fd = stdin_open ? 0 : -1, .events = POLLIN}};
        int timeout = idle ? 100 : 1;
        if (replug_at)
            timeout = 1;
        if (poll(fds, 2, timeout) < 0 && errno != EINTR)
            die("poll");
        uint64_t now = now_ms();
        if (replug_at && now >= replug_at) {
            replug_at = 0;
            plug();
            printf("plugged %s\n", bus.device);
            fflush(stdout);
        }
        if (fds[1].revents) {
            ssize_t n = read(0, cmd + cmd_len, sizeof cmd - 1 - cmd_len);
            if (n <= 0)
                stdin_open = 0;
            else
                cmd_len += (size_t)n;
            char *nl;
            while ((nl = memchr(cmd, '\n', cmd_len)) != NULL) {
                *nl = 0;
                long ms;
                if (sscanf(cmd, "unplug %ld", &ms) == 1 && bus.master >= 0) {
                    unplug();
                    for (long i = 0; i < count; i++)
                        boot(&units[i], &cfgs[i]);
                    replug_at = now + (uint64_t)(ms > 0 ? ms : 1);
                    printf("unplugged\n");
                    fflush(stdout);
                }
                size_t used = (size_t)(nl - cmd) + 1;
                memmove(cmd, cmd + used, cmd_len - used);
                cmd_len -= used;
            }
            if (cmd_len == sizeof cmd - 1)
                cmd_len = 0;   /* an overlong line: drop it */
        }
        if (fds[0].fd >= 0 && (fds[0].revents & POLLIN)) {
            ssize_t n = read(bus.master, buf, sizeof buf);
            if (n > 0) {
                pace((size_t)n);
                for (long i = 0; i < count; i++) {
                    fw_rx_feed(&units[i].ctl, buf, (size_t)n);
                    if (bus.trace_fd >= 0)
                        trace_targets(&units[i], &cfgs[i]);
                }
                if (idle)
                    last = now;   /* motors were at rest and unpowered: nothing to catch up */
                idle = 0;
            }
        }
        /* a test pattern's watchdog (fw_poll) may move targets while no byte arrives */
        for (long i = 0; i < count; i++)
            if (fw_poll(&units[i].ctl) && idle) {
                idle = 0;
                last = now;   /* motors were at rest: nothing to catch up */
            }
        /* the motor loop: one PD period per elapsed millisecond, the plants in between */
        uint64_t due = now - last;
        if (idle) {
            last = now;
            continue;
        }
        if (due > 1000)
            due = 1000;
        last = now;
        int moving = 0;
        for (uint64_t k = 0; k < due; k++)
            for (long i = 0; i < count; i++) {
                fw_tick(&units[i].ctl);
                if (sim_pixels_step(&units[i].pixels, cfgs[i].n_pixels) && k + 1 == due)
                    moving = 1;
            }
        if (due)
            idle = !moving;
    }
    if (bus.link)
        unlink(bus.link);
    return 0;
}
