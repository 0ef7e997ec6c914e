/* Teensy 4.1 wiring of the grass pixels: one row per pixel, in pixel order.
 * The paper (Teensy 4.1, DC motors with rotary encoders under PD control) does not publish its
 * pin map; this one is ours: PWM on PWM-capable pins, direction on a plain output (for an
 * H-bridge with PWM + DIR inputs such as a DRV8871 pair or a TB6612 channel), quadrature
 * encoder A/B on interrupt pins (every Teensy 4.1 digital pin is). Edit it for your board;
 * the number of rows is the pixel count the controller reports. */
#ifndef GRASS_PINS_H
#define GRASS_PINS_H

typedef struct {
    unsigned char pwm, dir, enc_a, enc_b;
} pixel_pins;

static const pixel_pins PIXEL_PINS[] = {
    /* pwm dir  A   B */
    {2, 3, 30, 31},
    {4, 5, 32, 33},
    {6, 9, 34, 35},
    {7, 10, 36, 37},
    {8, 11, 38, 39},
    {22, 12, 40, 41},
    {23, 16, 24, 25},
    {28, 17, 26, 27},
};

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
