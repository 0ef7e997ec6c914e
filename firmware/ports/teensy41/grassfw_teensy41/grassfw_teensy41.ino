// grassd controller firmware for Teensy 4.1: a thin layer over the portable C core (the same
// core/*.c that CI builds and tests as the posix and mps2-an500 ports, and generic/armcm_irq.c
// as the mps2 port has it). Build and flash:
// firmware/ports/teensy41/README.md. Pins, address and bus: pins.h.
//
//   bus      USB Serial, or Serial1 + DE pin for RS-485 (Serial1.transmitterEnable)
//   storage  two table banks in a file on the program flash (LittleFS_Program): a write goes
//            to the file and is synced, so a power cut keeps the old bytes or the new ones
//   motors   PWM + DIR per pixel, quadrature encoders (PJRC Encoder library), PD loop from
//            an IntervalTimer every 1 ms, above the bus in priority
//   memory   no heap: every object here is static, sized at compile time (PJRC's LittleFS
//            allocates its open file itself, once, in setup())
#include <Encoder.h>
#include <IntervalTimer.h>
#include <LittleFS.h>
#include "pins.h"

extern "C" {
#include "src/core/controller.h"
}

static const uint16_t N_PIXELS = sizeof(PIXEL_PINS) / sizeof(PIXEL_PINS[0]);

#if GRASS_USE_RS485
#define BUS Serial1
#else
#define BUS Serial
#endif

// The encoders: static objects, one per row of pins.h. PJRC's Encoder is meant to be a global:
// its constructor sets the pins' pull-ups and attaches their interrupts before setup() runs.
#define GRASS_ENCODER(pwm, dir, enc_a, enc_b) {enc_a, enc_b},
static Encoder encoders[] = {GRASS_PIXELS(GRASS_ENCODER)};
#undef GRASS_ENCODER
static_assert(sizeof encoders / sizeof encoders[0] == N_PIXELS, "one encoder per pixel");

static LittleFS_Program flashfs;
static File banks;
static IntervalTimer motor_timer;
static fw_controller ctl;
static fw_hal hal;

static void tx(void *, const uint8_t *data, size_t n)
{
    BUS.write(data, n);
    BUS.flush();   // RS-485: DE drops once the last bit is out
}

static int nv_read(void *, uint32_t off, uint8_t *buf, uint32_t n)
{
    if (!banks.seek(off))
        return -1;
    return banks.read(buf, n) == n ? 0 : -1;
}

static int nv_write(void *, uint32_t off, const uint8_t *data, uint32_t n)
{
    if (!banks.seek(off) || banks.write(data, n) != n)
        return -1;
    banks.flush();
    return 0;
}

static int nv_erase(void *ctx, uint32_t off, uint32_t n)
{
    uint8_t ff[16];
    memset(ff, FW_NV_ERASED, sizeof ff);
    for (uint32_t done = 0; done < n; done += sizeof ff) {
        uint32_t k = n - done < sizeof ff ? n - done : sizeof ff;
        if (nv_write(ctx, off + done, ff, k) < 0)
            return -1;
    }
    return 0;
}

// No file system: every storage access fails, answered NAK STORAGE_FAILED (no table).
static int nv_fail_read(void *, uint32_t, uint8_t *, uint32_t) { return -1; }
static int nv_fail_write(void *, uint32_t, const uint8_t *, uint32_t) { return -1; }
static int nv_fail_erase(void *, uint32_t, uint32_t) { return -1; }

static uint32_t now_ms(void *) { return millis(); }

// Critical sections of the core (core/hal.h): PRIMASK saved and set, then put back, in
// src/generic/armcm_irq.c (firmware/generic/, shared with the mps2 port).

// Encoder::read() ends with interrupts(), which would end a caller's critical section early:
// put the caller's PRIMASK back after it.
static int32_t encoder_read(void *, uint16_t p)
{
    fw_irqstatus flag = fw_irq_save();
    int32_t v = encoders[p].read();
    fw_irq_restore(flag);
    return v;
}

static void pwm_write(void *, uint16_t p, int16_t duty)
{
    const pixel_pins &pin = PIXEL_PINS[p];
    digitalWriteFast(pin.dir, duty < 0 ? HIGH : LOW);
    int32_t mag = duty < 0 ? -duty : duty;
    analogWrite(pin.pwm, (int)(mag * ((1 << GRASS_PWM_BITS) - 1) / FW_PWM_MAX));
}

static void motor_tick() { fw_tick(&ctl); }

static bool open_banks(uint32_t size)
{
    if (!flashfs.begin(256 * 1024))
        return false;
    banks = flashfs.open("banks.bin", FILE_WRITE_BEGIN);
    if (!banks)
        return false;
    if (banks.size() != size) {   // first start, or another pixel count: erased banks
        uint8_t ff[64];
        memset(ff, FW_NV_ERASED, sizeof ff);
        banks.truncate(0);
        for (uint32_t o = 0; o < size; o += sizeof ff)
            banks.write(ff, size - o < sizeof ff ? size - o : sizeof ff);
        banks.flush();
    }
    return true;
}

void setup()
{
    analogWriteResolution(GRASS_PWM_BITS);
    for (uint16_t p = 0; p < N_PIXELS; p++) {
        pinMode(PIXEL_PINS[p].dir, OUTPUT);
        analogWriteFrequency(PIXEL_PINS[p].pwm, GRASS_PWM_HZ);
        analogWrite(PIXEL_PINS[p].pwm, 0);
    }
#if GRASS_USE_RS485
    Serial1.begin(GRASS_RS485_BAUD);
    Serial1.transmitterEnable(GRASS_RS485_DE_PIN);
#else
    Serial.begin(115200);   // USB CDC: the baud rate is ignored
#endif
    hal = fw_hal{nullptr, tx, nv_read, nv_write, nv_erase, now_ms, encoder_read, pwm_write};
    fw_config cfg = fw_config_default(GRASS_ADDRESS, N_PIXELS);   // core/board_defaults.h
    cfg.uid = GRASS_UID;
    if (!open_banks(fw_banks_size(N_PIXELS))) {
        hal.nv_read = nv_fail_read;
        hal.nv_write = nv_fail_write;
        hal.nv_erase = nv_fail_erase;
    }
    fw_boot(&ctl, &hal, &cfg);
    motor_timer.priority(64);   // above USB and the UARTs (default 128)
    motor_timer.begin(motor_tick, FW_TICK_US);
}

void loop()
{
    uint8_t buf[64];
    int avail = BUS.available();
    if (avail > 0) {
        size_t want = (size_t)avail < sizeof buf ? (size_t)avail : sizeof buf;
        fw_rx_feed(&ctl, buf, BUS.readBytes((char *)buf, want));
    }
    fw_poll(&ctl);   // a test pattern's watchdog (the motor tick runs all the time here)
}
