/* Teensy 4.1 wiring of the grass pixels: one row per pixel, in pixel order.
 * The paper (Teensy 4.1, DC motors with rotary encoders under PD control) does not publish its
 * pin map; this one is ours: PWM on PWM-capable pins, direction on a plain output (for an
 * H-bridge with PWM + DIR inputs such as a DRV8871 pair or a TB6612 channel), quadrature
 * encoder A/B on interrupt pins (every Teensy 4.1 digital pin is). Edit it for your board;
 * the number of rows is the pixel count the controller reports.
 *
 * The list is written once and expanded twice by the sketch: into PIXEL_PINS (PWM and DIR) and
 * into its static array of Encoder objects (the firmware has no heap, so the encoders are not
 * made at run time from a table). Each row is GRASS_PIXEL(pwm, dir, encoder A, encoder B). */
#ifndef GRASS_PINS_H
#define GRASS_PINS_H

#define GRASS_PIXELS(GRASS_PIXEL) \
    /*          pwm dir  A   B */ \
    GRASS_PIXEL(2, 3, 30, 31)     \
    GRASS_PIXEL(4, 5, 32, 33)     \
    GRASS_PIXEL(6, 9, 34, 35)     \
    GRASS_PIXEL(7, 10, 36, 37)    \
    GRASS_PIXEL(8, 11, 38, 39)    \
    GRASS_PIXEL(22, 12, 40, 41)   \
    GRASS_PIXEL(23, 16, 24, 25)   \
    GRASS_PIXEL(28, 17, 26, 27)

typedef struct {
    unsigned char pwm, dir;
} pixel_pins;

#define GRASS_PIN_ROW(pwm, dir, enc_a, enc_b) {pwm, dir},
static const pixel_pins PIXEL_PINS[] = {GRASS_PIXELS(GRASS_PIN_ROW)};
#undef GRASS_PIN_ROW

/* RS-485: Serial1 (RX1 pin 0, TX1 pin 1) with the transceiver's DE/RE on this pin; set
 * GRASS_USE_RS485 to 0 for USB Serial (one controller per USB port). */
#ifndef GRASS_USE_RS485
#define GRASS_USE_RS485 0
#endif
#define GRASS_RS485_DE_PIN 18
#define GRASS_RS485_BAUD 115200

/* This controller's bus address (1..247) and id: by default the numbering of
 * core/board_defaults.h (address 1: 0x6A5D0001); give each board of a display its own. */
#define GRASS_ADDRESS 1
#define GRASS_UID FW_DEFAULT_UID(GRASS_ADDRESS)

/* PWM: 20 kHz (above hearing), 10-bit. */
#define GRASS_PWM_HZ 20000
#define GRASS_PWM_BITS 10

#endif
