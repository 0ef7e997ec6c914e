#define _POSIX_C_SOURCE 200809L
/* Fuzz driver for the C core: feeds random and mutated frames to controllers on one simulated
 * bus (RAM storage), built with -fsanitize=address,undefined so that any out-of-bounds access,
 * overflow or undefined behaviour aborts. Every answer must be a valid frame from the addressed
 * controller; the controller's invariants are checked after every frame.
 *
 * Also measures the time fw_rx_feed spends on one received byte (the worst case is the byte
 * that completes a frame: decode, CRC, handler), and times the heaviest frame there is (the
 * COMMIT of a full per-pixel transfer) on its own, repeated.
 *
 * Usage: fuzz [frames=1000000] [seed=1] */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "../core/cobs.h"
#include "../core/controller.h"
#include "../core/crc32.h"
#include "../core/le.h"
#include "ram_hal.h"

#define N_CTL 2
#define N_PIX 16

static uint64_t rng_state;
static uint32_t rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (uint32_t)(rng_state >> 11);
}
static uint32_t below(uint32_t n) { return n ? rnd() % n : 0; }

/* CPU time of this thread: time spent elsewhere (other processes) does not count. Only the
 * timing build (-DFUZZ_TIMING) reads the clock: the sanitizer build runs the same frames fast. */
static double now_us(void)
{
#ifdef FUZZ_TIMING
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
#else
    return 0.0;
#endif
}

static ram_hal hw[N_CTL];
static fw_controller ctl[N_CTL];
static fw_config cfg[N_CTL];
static long failures;

#define FAIL(...) do { failures++; if (failures < 10) { printf("FAIL: "); printf(__VA_ARGS__); printf("\n"); } } while (0)

/* One request body: a valid message of a random type with random fields, or a random type. */
static size_t make_body(uint8_t *b, uint16_t seq, uint32_t table_id, uint32_t total, uint32_t crc)
{
    uint8_t type = (uint8_t)(below(10) == 0 ? rnd() : 1 + below(11));
    uint8_t version = below(50) == 0 ? (uint8_t)rnd() : FW_PROTOCOL_VERSION;
    uint8_t addr = below(8) == 0 ? (uint8_t)rnd() : (uint8_t)(1 + below(N_CTL));
    if (type == FW_SHOW && below(2))
        addr = FW_BROADCAST_ADDRESS;
    fw_put_header(b, version, addr, type, seq);
    uint8_t *p = b + FW_HEADER_SIZE;
    size_t n = 0;
    switch (type) {
    case FW_TABLE_BEGIN: {
        int per_pixel = below(2);
        fw_put32(p, table_id);
        p[4] = (uint8_t)(below(8) == 0 ? rnd() : (uint32_t)per_pixel);
        fw_put16(p + 5, (uint16_t)(below(8) == 0 ? rnd() : per_pixel ? N_PIX : 1));
        fw_put32(p + 7, below(8) == 0 ? rnd() : total);
        fw_put32(p + 11, crc);
        n = 15;
        break;
    }
    case FW_TABLE_CHUNK: {
        uint32_t len = 1 + below(below(4) == 0 ? FW_MAX_CHUNK_DATA : 300);
        uint32_t off = below(4) == 0 ? rnd() : below(total + 1);
        fw_put32(p, below(4) == 0 ? rnd() : table_id);
        fw_put32(p + 4, off);
        for (uint32_t i = 0; i < len; i++)   /* mostly in range, sometimes over 20000 um */
            p[8 + i] = (uint8_t)(i % 2 ? below(below(20) ? 0x4F : 0x100) : rnd());
        n = 8 + len;
        break;
    }
    case FW_TABLE_COMMIT:
        fw_put32(p, below(4) == 0 ? rnd() : table_id);
        fw_put32(p + 4, below(3) == 0 ? rnd() : crc);
        n = 8;
        break;
    case FW_SET_LEVEL: {
        uint32_t len = 1 + below(below(8) == 0 ? FW_MAX_PAYLOAD - 2 : N_PIX + 2);
        fw_put16(p, (uint16_t)below(below(8) == 0 ? 0x10000 : N_PIX + 2));
        for (uint32_t i = 0; i < len; i++)
            p[2 + i] = (uint8_t)rnd();
        n = 2 + len;
        break;
    }
    case FW_GET_POSITIONS:
        fw_put16(p, (uint16_t)below(below(8) == 0 ? 0x10000 : N_PIX + 2));
        fw_put16(p + 2, (uint16_t)below(below(8) == 0 ? 0x10000 : N_PIX + 2));
        n = 4;
        break;
    case FW_PATTERN: {   /* mostly in range, sometimes over 20000 um, timeout 0 */
        uint32_t count = 1 + below(below(8) == 0 ? FW_MAX_PATTERN_PIXELS : N_PIX + 2);
        fw_put16(p, (uint16_t)(below(8) == 0 ? 0 : 1 + below(below(2) ? 50 : 0xFFFF)));
        fw_put16(p + 2, (uint16_t)below(below(8) == 0 ? 0x10000 : N_PIX + 2));
        for (uint32_t i = 0; i < count; i++)
            fw_put16(p + 4 + 2 * i, (uint16_t)(below(20) == 0 ? rnd() : below(20001)));
        n = 4 + 2 * count;
        break;
    }
    case FW_STAGE_LEVEL: {   /* a few frame numbers, so that SHOWs often find theirs */
        uint32_t len = 1 + below(below(8) == 0 ? FW_MAX_STAGE_PIXELS : N_PIX + 2);
        fw_put16(p, (uint16_t)below(4));
        fw_put16(p + 2, (uint16_t)below(below(8) == 0 ? 0x10000 : N_PIX + 2));
        for (uint32_t i = 0; i < len; i++)
            p[4 + i] = (uint8_t)rnd();
        n = 4 + len;
        break;
    }
    case FW_SHOW:
        fw_put16(p, (uint16_t)below(4));
        n = 2;
        break;
    default:   /* HELLO, GET_STATUS, PATTERN_END, unknown types: random short payloads sometimes */
        n = below(6) == 0 ? below(40) : 0;
        for (size_t i = 0; i < n; i++)
            p[i] = (uint8_t)rnd();
        break;
    }
    if (below(30) == 0)   /* wrong length for the type */
        n = below(FW_MAX_PAYLOAD + 1);
    return FW_HEADER_SIZE + n;
}

static uint8_t wire[FW_MAX_WIRE + FW_WIRE_SLACK + 64];
static double worst_byte_us, total_us;
static unsigned long long bytes_fed;
static int worst_type;
/* worst delimiter time per request type (1..7), other types (0), damaged (8), garbage (9) */
static double worst_by_class[10];

static int class_of(int type)
{
    return type == -1 ? 8 : type == -2 ? 9 : type >= 1 && type <= 7 ? type : 0;
}

/* Only a 0x00 (a delimiter) runs more than a buffer append: those bytes are timed one by
 * one; the others in runs. */
static unsigned long long delimiters;
static double delimiter_us;

static void feed(const uint8_t *data, size_t n, int type)
{
    size_t i = 0;
    while (i < n) {
        size_t run = 0;
        while (i + run < n && data[i + run] != 0)
            run++;
        if (run) {
            double t0 = now_us();
            for (int c = 0; c < N_CTL; c++)
                fw_rx_feed(&ctl[c], data + i, run);
            total_us += now_us() - t0;
            bytes_fed += run * N_CTL;
            i += run;
            continue;
        }
        for (int c = 0; c < N_CTL; c++) {
            double t0 = now_us();
            fw_rx_feed(&ctl[c], data + i, 1);
            double dt = now_us() - t0;
            total_us += dt;
            delimiter_us += dt;
            bytes_fed++;
            delimiters++;
            if (dt > worst_byte_us) {
                worst_byte_us = dt;
                worst_type = type;
            }
            if (dt > worst_by_class[class_of(type)])
                worst_by_class[class_of(type)] = dt;
        }
        i++;
    }
}

/* Every answer on the bus must be a valid frame from one of the controllers. */
static void check_answers(void)
{
    for (int c = 0; c < N_CTL; c++) {
        fw_rx rx;
        memset(&rx, 0, sizeof rx);
        size_t frames = 0;
        for (size_t i = 0; i < hw[c].out_len; i++) {
            size_t body = fw_rx_byte(&rx, hw[c].out[i]);
            if (!body)
                continue;
            frames++;
            fw_msg m;
            if (rx.buf[1] != cfg[c].address || !(rx.buf[2] & 0x80)
                || fw_msg_unpack(rx.buf[2], rx.buf + FW_HEADER_SIZE, body - FW_HEADER_SIZE, &m) != FW_MSG_OK)
                FAIL("controller %d answered an invalid frame (type 0x%02x)", c, rx.buf[2]);
        }
        if (rx.bad || rx.oversized || rx.len)
            FAIL("controller %d sent damaged bytes", c);
        (void)frames;
        hw[c].out_len = 0;
        const fw_controller *k = &ctl[c];
        if (k->active_bank != 0 && k->active_bank != 1 && k->active_bank != FW_NO_BANK)
            FAIL("active_bank %u", k->active_bank);
        if (k->xfer_open && k->xfer_received > k->xfer.total_bytes)
            FAIL("received %u of %u", (unsigned)k->xfer_received, (unsigned)k->xfer.total_bytes);
        if (k->pattern.active > 1 || (k->pattern.active && (k->pattern.timeout_ms == 0
                                                             || k->pattern.timeout_ms > 6553500u)))
            FAIL("pattern state active %u timeout %u ms", k->pattern.active,
                 (unsigned)k->pattern.timeout_ms);
        for (uint16_t p = 0; p < k->cfg.n_pixels; p++)
            if (k->motors.target_um[p] > k->cfg.max_length_um)
                FAIL("pixel %u target %u um over max_length_um", p, k->motors.target_um[p]);
        for (uint16_t p = k->cfg.n_pixels; p < FW_MAX_PIXELS; p++)
            if (fw_latch_has(&k->latch, p))
                FAIL("pixel %u staged beyond n_pixels %u", p, k->cfg.n_pixels);
        if (k->latch.any > 1)
            FAIL("latch any %u", k->latch.any);
    }
}

/* The heaviest frame: COMMIT of a full per-pixel transfer, to controller 2 (max_chunk 1016) (CRC + range check of the staged
 * data read back, header write, loading 16 tables). Returns the median time in us. */
static double time_commit(int reps, double *worst)
{
    static uint8_t data[N_PIX * FW_TABLE_BYTES];
    for (size_t i = 0; i < sizeof data; i += 2)
        fw_put16(data + i, (uint16_t)(i % 20000));
    uint32_t crc = fw_crc32(data, sizeof data);
    static double t[1000];
    *worst = 0;
    for (int r = 0; r < reps; r++) {
        uint8_t body[FW_MAX_BODY];
        uint16_t seq = (uint16_t)(r * 40);
        fw_put_header(body, 1, 2, FW_TABLE_BEGIN, seq++);
        fw_put32(body + 5, (uint32_t)r); body[9] = 1; fw_put16(body + 10, N_PIX);
        fw_put32(body + 12, sizeof data); fw_put32(body + 16, crc);
        fw_handle_body(&ctl[1], body, 20);
        for (uint32_t off = 0; off < sizeof data; off += 1016) {
            uint32_t len = sizeof data - off < 1016 ? (uint32_t)sizeof data - off : 1016;
            fw_put_header(body, 1, 2, FW_TABLE_CHUNK, seq++);
            fw_put32(body + 5, (uint32_t)r); fw_put32(body + 9, off);
            memcpy(body + 13, data + off, len);
            fw_handle_body(&ctl[1], body, 13 + len);
        }
        fw_put_header(body, 1, 2, FW_TABLE_COMMIT, seq++);
        fw_put32(body + 5, (uint32_t)r); fw_put32(body + 9, crc);
        size_t n = FW_HEADER_SIZE + 8;
        memcpy(wire + FW_WIRE_SLACK, body, n);
        size_t w = fw_frame_wrap(wire, n);
        static const uint8_t flush = 0;   /* end any garbage the fuzzing left in the receiver */
        fw_rx_feed(&ctl[1], &flush, 1);
        fw_rx_feed(&ctl[1], wire, w - 1);   /* all but the delimiter */
        hw[1].out_len = 0;
        double t0 = now_us();
        fw_rx_feed(&ctl[1], wire + w - 1, 1);   /* the byte that runs the COMMIT */
        t[r] = now_us() - t0;
        if (t[r] > *worst)
            *worst = t[r];
        if (ctl[1].active.table_id != (uint32_t)r || ctl[1].active_bank == FW_NO_BANK)
            FAIL("timed commit %d did not switch tables", r);
    }
    for (int i = 1; i < reps; i++)   /* insertion sort for the median */
        for (int j = i; j > 0 && t[j] < t[j - 1]; j--) {
            double x = t[j]; t[j] = t[j - 1]; t[j - 1] = x;
        }
    return t[reps / 2];
}

int main(int argc, char **argv)
{
    long frames = argc > 1 ? atol(argv[1]) : 1000000;
    rng_state = argc > 2 ? strtoull(argv[2], NULL, 0) : 1;
    rng_state = rng_state * 0x9E3779B97F4A7C15ull + 1;
    for (int c = 0; c < N_CTL; c++) {
        ram_hal_init(&hw[c]);
        cfg[c] = (fw_config){.address = (uint8_t)(c + 1), .n_pixels = N_PIX, .uid = (uint32_t)c,
                             .max_chunk = (uint16_t)(c ? 1016 : 256), .max_length_um = 20000};
        fw_boot(&ctl[c], &hw[c].hal, &cfg[c]);
    }
    static uint8_t body[FW_MAX_BODY + 64], garbage[2 * FW_MAX_WIRE];
    uint32_t table_id = 7, total = FW_TABLE_BYTES, crc = 0;
    long kinds[4] = {0};
    for (long f = 0; f < frames; f++) {
        if (below(1000) == 0) {   /* new transfer parameters, or a reboot */
            table_id = rnd();
            total = below(2) ? FW_TABLE_BYTES : N_PIX * FW_TABLE_BYTES;
            crc = rnd();
        }
        if (below(20000) == 0)
            for (int c = 0; c < N_CTL; c++)
                fw_boot(&ctl[c], &hw[c].hal, &cfg[c]);
        for (int c = 0; c < N_CTL; c++) {   /* time passes: test patterns' watchdogs run out */
            hw[c].ms += below(300);
            if (below(4) == 0)
                fw_poll(&ctl[c]);
        }
        uint16_t seq = (uint16_t)(below(4) == 0 ? f - 1 : f);   /* some retransmissions */
        size_t n = make_body(body, seq, table_id, total, crc);
        int kind = (int)below(4), type = body[2];
        kinds[kind]++;
        if (kind == 0 || kind == 1) {   /* valid CRC: reaches the handlers */
            if (kind == 1)   /* ... after mutating the body */
                for (uint32_t m = 1 + below(4); m > 0; m--) {
                    uint32_t at = below((uint32_t)n);
                    switch (below(3)) {
                    case 0: body[at] ^= (uint8_t)(1u << below(8)); break;
                    case 1: body[at] = (uint8_t)rnd(); break;
                    default: n = at > FW_HEADER_SIZE ? at : n; break;   /* truncate */
                    }
                }
            memcpy(wire + FW_WIRE_SLACK, body, n);
            size_t w = fw_frame_wrap(wire, n);
            feed(wire, w, type);
        } else if (kind == 2) {   /* a valid frame's wire bytes, damaged on the line */
            memcpy(wire + FW_WIRE_SLACK, body, n);
            size_t w = fw_frame_wrap(wire, n);
            for (uint32_t m = 1 + below(3); m > 0; m--) {
                uint32_t at = below((uint32_t)w);
                switch (below(4)) {
                case 0: wire[at] ^= (uint8_t)(1u << below(8)); break;
                case 1: wire[at] = 0; break;
                case 2: wire[at] = (uint8_t)rnd(); break;
                default: w = at + 1; break;
                }
            }
            feed(wire, w, -1);
        } else {   /* garbage, sometimes longer than any frame */
            size_t g = below(50) == 0 ? below(sizeof garbage) : below(64);
            for (size_t i = 0; i < g; i++)
                garbage[i] = below(16) == 0 ? 0 : (uint8_t)rnd();
            feed(garbage, g, -2);
        }
        check_answers();
    }
    /* the raw codec on random input */
    for (long i = 0; i < frames / 4; i++) {
        size_t n = below(sizeof garbage);
        for (size_t k = 0; k < n; k++)
            garbage[k] = (uint8_t)rnd();
        fw_msg m;
        if (fw_msg_unpack((uint8_t)rnd(), garbage, below(FW_MAX_PAYLOAD + 1), &m) == FW_MSG_OK) {
            uint8_t out[FW_MAX_PAYLOAD + 8];
            fw_msg_pack(&m, out);
        }
        fw_cobs_decode(garbage, n > FW_MAX_WIRE ? FW_MAX_WIRE : n);
    }
    double commit_worst, commit_median = time_commit(200, &commit_worst);
    printf("fuzz: %ld frames (%ld valid, %ld mutated with valid CRC, %ld damaged on the line, "
           "%ld garbage), %llu bytes x controller fed, %ld codec inputs, %ld failures\n",
           frames, kinds[0], kinds[1], kinds[2], kinds[3], bytes_fed, frames / 4, failures);
#ifdef FUZZ_TIMING
    static const char *names[10] = {"other type", "HELLO", "GET_STATUS", "TABLE_BEGIN",
                                     "TABLE_CHUNK", "TABLE_COMMIT", "SET_LEVEL", "GET_POSITIONS",
                                     "damaged on the line", "garbage"};
    printf("worst time of a frame's last byte, by what the frame was:");
    for (int k = 0; k < 10; k++)
        printf("%s %s %.1f us", k ? "," : "", names[k], worst_by_class[k]);
    printf("\n");
    printf("time per received byte (thread CPU time): mean %.3f us; per delimiter (the byte "
           "that completes a frame) mean %.3f us, worst %.1f us (frame type %d)\n",
           total_us / (double)bytes_fed, delimiter_us / (double)delimiters, worst_byte_us,
           worst_type);
    printf("heaviest frame (COMMIT of %d per-pixel tables, its last byte): median %.1f us, "
           "worst %.1f us of 200; motor loop period %u us\n", N_PIX, commit_median, commit_worst,
           FW_TICK_US);
#else
    (void)commit_median;
    printf("(sanitizer build: timing is measured by the fuzz_timing build)\n");
#endif
    return failures != 0;
}
