/* A controller's configuration where its port is given none: written here once for every port
 * (posix, mps2, teensy41). The Python reference has the same defaults
 * (rigs/firmware.py: ControllerConfig, SIM_UID_BASE);
 * tests/firmware/test_board_defaults.py checks that the two agree. */
#ifndef FW_BOARD_DEFAULTS_H
#define FW_BOARD_DEFAULTS_H

#define FW_DEFAULT_ADDRESS 1u
/* Controller a reports uid FW_DEFAULT_UID_BASE + a (simulated buses number their controllers
 * so; a real board should be given its own, e.g. GRASS_UID in ports/teensy41/pins.h). */
#define FW_DEFAULT_UID_BASE 0x6A5D0000u
#define FW_DEFAULT_UID(address) (FW_DEFAULT_UID_BASE + (uint32_t)(address))
/* Pixels of a simulated controller (capped by the build's FW_MAX_PIXELS). */
#define FW_DEFAULT_PIXELS 16u
/* TABLE_CHUNK data bytes accepted (1..FW_MAX_CHUNK_DATA). */
#define FW_DEFAULT_MAX_CHUNK 256u
/* The longest grass the mechanism reaches: 20 mm, the paper's pixel. */
#define FW_DEFAULT_MAX_LENGTH_UM 20000u

#endif
