/* Replays every golden vector of firmware_proto/vectors/ (every .json) against the C core: message
 * encode/decode byte for byte, frames a receiver must drop, a stream with garbage, and a whole
 * table transfer through a controller (each answer byte-exact with the Python reference). */
#include <stdio.h>
#include <string.h>
#include "../core/cobs.h"
#include "../core/controller.h"
#include "../core/crc32.h"
#include "../core/le.h"
#include "ram_hal.h"

typedef struct {
    const char *name;
    const uint8_t *wire;
    size_t wire_len;
    uint8_t version, address;
    uint16_t seq;
    fw_msg msg;
} vec_frame;
typedef struct { const char *name; const uint8_t *wire; size_t wire_len; } vec_bytes;
typedef struct {
    const char *name;
    const uint8_t *request;
    size_t request_len;
    const uint8_t *answer;
    size_t answer_len;
} vec_step;

#include "vectors.h"

static int failures, checks;

#define CHECK(cond, ...) do { checks++; if (!(cond)) { failures++; \
    printf("FAIL %s:%d: ", __FILE__, __LINE__); printf(__VA_ARGS__); printf("\n"); } } while (0)

static uint8_t wire[FW_MAX_WIRE + FW_WIRE_SLACK];

/* Encode a frame as the controller does: header + payload in place, CRC, COBS, delimiter. */
static size_t encode(const vec_frame *v)
{
    uint8_t *body = wire + FW_WIRE_SLACK;
    fw_put_header(body, v->version, v->address, v->msg.type, v->seq);
    size_t n = fw_msg_pack(&v->msg, body + FW_HEADER_SIZE);
    return fw_frame_wrap(wire, FW_HEADER_SIZE + n);
}

/* Decoded body equals the vector's meaning: header fields, and the payload re-packed equals the
 * meaning packed (which the encode check ties to the wire bytes). */
static void check_body(const char *name, const uint8_t *body, size_t n, const vec_frame *v)
{
    CHECK(n >= FW_HEADER_SIZE, "%s: body of %zu bytes", name, n);
    if (n < FW_HEADER_SIZE)
        return;
    CHECK(body[0] == v->version && body[1] == v->address && body[2] == v->msg.type
          && fw_get16(body + 3) == v->seq, "%s: header differs", name);
    fw_msg m;
    int rc = fw_msg_unpack(body[2], body + FW_HEADER_SIZE, n - FW_HEADER_SIZE, &m);
    CHECK(rc == FW_MSG_OK, "%s: payload does not decode (%d)", name, rc);
    if (rc != FW_MSG_OK)
        return;
    static uint8_t a[FW_MAX_PAYLOAD], b[FW_MAX_PAYLOAD];
    size_t na = fw_msg_pack(&m, a), nb = fw_msg_pack(&v->msg, b);
    CHECK(na == nb && memcmp(a, b, na) == 0, "%s: decoded fields differ from the meaning", name);
}

static void test_messages(void)
{
    for (size_t i = 0; i < sizeof message_vectors / sizeof message_vectors[0]; i++) {
        const vec_frame *v = &message_vectors[i];
        size_t n = encode(v);
        CHECK(n == v->wire_len && memcmp(wire, v->wire, n) == 0, "%s: encoding differs", v->name);
        fw_rx rx;
        memset(&rx, 0, sizeof rx);
        size_t body = 0;
        for (size_t k = 0; k < v->wire_len; k++) {
            size_t b = fw_rx_byte(&rx, v->wire[k]);
            CHECK(b == 0 || k == v->wire_len - 1, "%s: frame ended early", v->name);
            body = b ? b : body;
        }
        check_body(v->name, rx.buf, body, v);
    }
}

static void test_framing(void)
{
    CHECK(fw_crc32((const uint8_t *)crc_check_input, strlen(crc_check_input)) == crc_check_value,
          "CRC-32/ISO-HDLC check value");
    for (size_t i = 0; i < sizeof rejected_vectors / sizeof rejected_vectors[0]; i++) {
        const vec_bytes *r = &rejected_vectors[i];
        fw_rx rx;
        memset(&rx, 0, sizeof rx);
        size_t got = 0;
        for (size_t k = 0; k < r->wire_len; k++)
            got |= fw_rx_byte(&rx, r->wire[k]);
        CHECK(got == 0 && rx.frames == 0 && rx.bad + rx.oversized == 1,
              "rejected %s: frames %u bad %u oversized %u", r->name, (unsigned)rx.frames,
              (unsigned)rx.bad, (unsigned)rx.oversized);
    }
    fw_rx rx;
    memset(&rx, 0, sizeof rx);
    size_t found = 0;
    for (size_t k = 0; k < sizeof stream_bytes; k++) {
        size_t b = fw_rx_byte(&rx, stream_bytes[k]);
        if (b) {
            CHECK(found < sizeof stream_frames / sizeof stream_frames[0], "stream: extra frame");
            if (found < sizeof stream_frames / sizeof stream_frames[0])
                check_body(stream_frames[found].name, rx.buf, b, &stream_frames[found]);
            found++;
        }
    }
    CHECK(found == sizeof stream_frames / sizeof stream_frames[0], "stream: %zu frames", found);
}

static ram_hal hw;
static fw_controller ctl;

static void test_transfer(void)
{
    ram_hal_init(&hw);
    fw_config cfg = {.address = 3, .n_pixels = 16, .uid = 0x6A5D0001u, .max_chunk = 256,
                     .max_length_um = 20000};
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0, "boot");
    for (size_t i = 0; i < sizeof transfer_steps / sizeof transfer_steps[0]; i++) {
        const vec_step *s = &transfer_steps[i];
        hw.out_len = 0;
        fw_rx_feed(&ctl, s->request, s->request_len);
        CHECK(hw.out_len == s->answer_len && memcmp(hw.out, s->answer, s->answer_len) == 0,
              "transfer %s: answer differs (%zu bytes, expected %zu)", s->name, hw.out_len,
              s->answer_len);
        /* a retransmission gets the same bytes without executing twice */
        hw.out_len = 0;
        uint32_t writes = hw.nv.writes;
        fw_rx_feed(&ctl, s->request, s->request_len);
        CHECK(hw.out_len == s->answer_len && memcmp(hw.out, s->answer, s->answer_len) == 0
              && hw.nv.writes == writes, "transfer %s: retransmission differs", s->name);
    }
    /* after a reboot the committed table is still active: replay the last GET_STATUS */
    const vec_step *last = &transfer_steps[sizeof transfer_steps / sizeof transfer_steps[0] - 1];
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0, "reboot");
    hw.out_len = 0;
    fw_rx_feed(&ctl, last->request, last->request_len);
    CHECK(hw.out_len == last->answer_len && memcmp(hw.out, last->answer, hw.out_len) == 0,
          "status after reboot differs");
}

#define N_PATTERN_STEPS (sizeof pattern_steps / sizeof pattern_steps[0])

/* Feed one step's request; 1 when the answer is the step's bytes. */
static int answers_like(const vec_step *s)
{
    hw.out_len = 0;
    fw_rx_feed(&ctl, s->request, s->request_len);
    return hw.out_len == s->answer_len
           && (s->answer_len == 0 || memcmp(hw.out, s->answer, s->answer_len) == 0);
}

/* Pattern step i, checked to be a request of `type` (the vector file's order). */
static const vec_step *pattern_step(size_t i, const char *type)
{
    CHECK(i < N_PATTERN_STEPS && strstr(pattern_steps[i].name, type) != NULL,
          "pattern step %zu is not a %s", i, type);
    return &pattern_steps[i < N_PATTERN_STEPS ? i : 0];
}

/* Test patterns: the vector conversation byte for byte (and retransmitted), normal display
 * after a reboot in pattern mode, and the watchdog on hal millis across its wrap at 2^32. */
static void test_pattern(void)
{
    fw_config cfg = {.address = 3, .n_pixels = 16, .uid = 0x6A5D0001u, .max_chunk = 256,
                     .max_length_um = 20000};
    ram_hal_init(&hw);
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0, "boot");
    for (size_t i = 0; i < N_PATTERN_STEPS; i++) {
        const vec_step *s = &pattern_steps[i];
        CHECK(answers_like(s), "pattern %s: answer differs (%zu bytes, expected %zu)", s->name,
              hw.out_len, s->answer_len);
        CHECK(answers_like(s), "pattern %s: retransmission differs", s->name);
    }
    /* a power cut in pattern mode: after the boot SET_LEVEL moves pixels again */
    CHECK(answers_like(pattern_step(13, "PATTERN")) && ctl.pattern.active, "pattern again");
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0 && !ctl.pattern.active, "reboot in pattern mode");
    CHECK(answers_like(pattern_step(11, "SET_LEVEL")), "SET_LEVEL after the reboot");
    CHECK(answers_like(pattern_step(16, "GET_POSITIONS")), "targets table[level] after reboot");

    /* the watchdog: PATTERN of 5.0 s armed 4096 ms before millis wraps */
    ram_hal_init(&hw);
    hw.ms = 0xFFFFF000u;
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0, "boot");
    CHECK(answers_like(pattern_step(2, "PATTERN")), "PATTERN of 50 ds");
    CHECK(answers_like(pattern_step(3, "GET_POSITIONS")), "pattern targets");
    hw.ms += 4999u;
    CHECK(fw_poll(&ctl) == 0 && ctl.motors.target_um[1] == 5000 && ctl.motors.target_um[2] == 20000,
          "watchdog ended the pattern 1 ms early (ms %u)", (unsigned)hw.ms);
    hw.ms += 1u;
    CHECK(fw_poll(&ctl) == 1 && ctl.motors.target_um[1] == 0 && ctl.motors.target_um[2] == 0
          && !ctl.pattern.active, "watchdog did not end the pattern after 5000 ms (ms %u)",
          (unsigned)hw.ms);
    CHECK(fw_poll(&ctl) == 0, "watchdog ended the pattern twice");
    /* re-armed by each PATTERN; a frame after the deadline finds normal display already */
    CHECK(answers_like(pattern_step(2, "PATTERN")), "PATTERN (new seq after a poll)");
    hw.ms += 3000u;
    CHECK(answers_like(pattern_step(13, "PATTERN")), "PATTERN re-arms");
    hw.ms += 4000u;
    CHECK(fw_poll(&ctl) == 0 && ctl.motors.target_um[1] == 5000, "re-armed watchdog ran early");
    hw.ms += 1000u;
    hw.out_len = 0;
    fw_rx_feed(&ctl, pattern_steps[0].request, pattern_steps[0].request_len);   /* HELLO */
    CHECK(hw.out_len > 0 && !ctl.pattern.active && ctl.motors.target_um[1] == 0
          && ctl.motors.target_um[3] == 0, "a frame after the deadline saw the pattern");
}

#define N_LATCH_STEPS (sizeof latch_steps / sizeof latch_steps[0])

/* The frame latch: the vector conversation byte for byte (broadcasts answered by nothing), each
 * unicast step retransmitted; after each broadcast the unicast request before it is answered
 * from the reply cache still (a broadcast leaves it alone); a boot forgets what is staged. */
static void test_latch(void)
{
    fw_config cfg = {.address = 3, .n_pixels = 16, .uid = 0x6A5D0001u, .max_chunk = 256,
                     .max_length_um = 20000};
    ram_hal_init(&hw);
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0, "boot");
    for (size_t i = 0; i < N_LATCH_STEPS; i++) {
        const vec_step *s = &latch_steps[i];
        CHECK(answers_like(s), "latch %s: answer differs (%zu bytes, expected %zu)", s->name,
              hw.out_len, s->answer_len);
        if (s->answer_len)
            CHECK(answers_like(s), "latch %s: retransmission differs", s->name);
        else if (i > 0 && latch_steps[i - 1].answer_len)
            CHECK(answers_like(&latch_steps[i - 1]), "latch %s: the broadcast disturbed the "
                  "reply cache", s->name);
    }
    /* staged, then a reboot: the SHOW finds nothing staged */
    uint8_t level = 99;
    fw_latch_stage(&ctl.latch, 42, 0, &level, 1);
    CHECK(ctl.latch.any, "staged");
    CHECK(fw_boot(&ctl, &hw.hal, &cfg) == 0 && !ctl.latch.any, "a boot kept the staging");
}

/* COBS: the in-place encoder equals a separate-buffer encode, and decodes back (runs of 254). */
static void test_cobs_runs(void)
{
    static uint8_t in[1040], out[1100], scratch[1100];
    for (size_t n = 0; n <= 1037; n += (n < 600 ? 1 : 7)) {
        for (size_t i = 0; i < n; i++)
            in[i] = (uint8_t)((i % 300 == 299) ? 0 : 1 + (i * 7) % 255);
        size_t a = fw_cobs_encode(in, n, out);
        memcpy(scratch + 6, in, n);
        size_t b = fw_cobs_encode(scratch + 6, n, scratch);
        int same = a == b && memcmp(out, scratch, a) == 0;
        long d = fw_cobs_decode(out, a);
        CHECK(same && d == (long)n && memcmp(out, in, n) == 0,
              "cobs n=%zu", n);
    }
}

int main(void)
{
    test_messages();
    test_framing();
    test_transfer();
    test_pattern();
    test_latch();
    test_cobs_runs();
    printf("%d checks, %d failed: %zu message vectors, %zu rejected frames, %zu stream frames, "
           "%zu transfer steps, %zu pattern steps, %zu latch steps\n", checks, failures, sizeof message_vectors / sizeof message_vectors[0],
           sizeof rejected_vectors / sizeof rejected_vectors[0],
           sizeof stream_frames / sizeof stream_frames[0],
           sizeof transfer_steps / sizeof transfer_steps[0], N_PATTERN_STEPS,
           N_LATCH_STEPS);
    return failures != 0;
}
