/* The controller state machine of PROTOCOL.md sections 3-4, the same as the Python reference
 * (rigs/firmware.py): feed it received bytes with fw_rx_feed, call fw_tick every
 * millisecond (FW_TICK_US). All state lives in one fw_controller (no heap, no globals), so a port may run
 * several on one bus. */
#ifndef FW_CONTROLLER_H
#define FW_CONTROLLER_H
#include <stdint.h>
#include "banks.h"
#include "board_defaults.h"
#include "frame.h"
#include "hal.h"
#include "latch.h"
#include "limits.h"
#include "motor.h"
#include "msg.h"
#include "pattern.h"

#define FW_VERSION_MAJOR 1
#define FW_VERSION_MINOR 0
#define FW_VERSION_PATCH 0

typedef struct {
    uint8_t address;          /* 1..247 */
    uint16_t n_pixels;        /* 1..FW_MAX_PIXELS; also the tables one bank holds */
    uint32_t uid;
    uint16_t max_chunk;       /* 1..FW_MAX_CHUNK_DATA */
    uint16_t max_length_um;   /* FW_DEFAULT_MAX_LENGTH_UM on the paper's pixel */
} fw_config;

/* The configuration of controller `address` with n_pixels, the rest board_defaults.h's. (Plain
 * assignments, so that a C++ port such as the Teensy sketch can call it too.) */
static inline fw_config fw_config_default(uint8_t address, uint16_t n_pixels)
{
    fw_config cfg;
    cfg.address = address;
    cfg.n_pixels = n_pixels;
    cfg.uid = FW_DEFAULT_UID(address);
    cfg.max_chunk = FW_DEFAULT_MAX_CHUNK;
    cfg.max_length_um = FW_DEFAULT_MAX_LENGTH_UM;
    return cfg;
}

typedef struct fw_controller {
    const fw_hal *hal;
    fw_config cfg;
    fw_rx rx;
    /* the active table */
    uint8_t active_bank;      /* 0, 1 or FW_NO_BANK */
    fw_bank_header active;
    uint16_t table[FW_MAX_PIXELS][FW_TABLE_ENTRIES];
    /* the open transfer */
    uint8_t xfer_open, xfer_bank;
    fw_table_begin xfer;
    uint32_t xfer_received;   /* distinct bytes arrived */
    uint8_t xfer_map[FW_MAX_TABLE_BYTES / 8];
    /* the last answer, for retransmissions */
    uint8_t last_valid;
    uint16_t last_seq;
    uint32_t last_crc;
    uint16_t last_len;
    uint8_t wire[FW_MAX_WIRE + FW_WIRE_SLACK];
    fw_motors motors;
    fw_pattern_state pattern;   /* test patterns: RAM only, normal display after a boot */
    fw_latch_state latch;       /* levels staged for a SHOW: RAM only, empty after a boot */
} fw_controller;

/* Power-on: check the configuration, select the active bank, load its table, forget all RAM
 * state, hold the motors where they are. Returns 0, or -1 for an invalid configuration.
 * Call it before the port starts calling fw_tick (it rewrites the hal and pixel count the tick
 * reads); the motor state itself is set inside critical sections (hal.h). */
int fw_boot(fw_controller *c, const fw_hal *hal, const fw_config *cfg);
/* Bytes received from the bus; answers go out through hal->tx. Returns the type byte of the
 * last frame these bytes completed with a valid CRC (to any address), or FW_RX_NO_FRAME: what a
 * port that times its bytes reports the costliest one by (ports/mps2). */
#define FW_RX_NO_FRAME (-1)
int fw_rx_feed(fw_controller *c, const uint8_t *data, size_t n);
/* Handle one CRC-checked body (header + payload). Returns the answer's wire length (at
 * c->wire; also sent with hal->tx), or 0 when nothing is answered (another address, a
 * broadcast: FW_BROADCAST_ADDRESS frames are carried out, never answered, and leave the
 * reply cache alone). */
size_t fw_handle_body(fw_controller *c, const uint8_t *body, size_t n);
/* One period of the motor loop (every FW_TICK_US; on a microcontroller from a timer interrupt
 * of higher priority than the UART, so that no frame can delay it). What it shares with the
 * frame handlers (the motors' targets) they only touch inside fw_irq_save / fw_irq_restore. */
void fw_tick(fw_controller *c);
/* The test pattern's watchdog (PROTOCOL.md section 3): call it from the main loop, often (a
 * pattern ends no later than its timeout plus the loop's period; every frame polls it too).
 * Returns 1 when it just ended a pattern, i.e. moved targets: a port whose motor loop rests
 * while no motor moves must wake it then. Main context, as fw_rx_feed. */
int fw_poll(fw_controller *c);
/* The target (um) pixel p's motor drives towards now (what GET_POSITIONS reports as target_um);
 * for a port that watches what frames change. Main context. */
uint16_t fw_target_um(const fw_controller *c, uint16_t p);

#endif
