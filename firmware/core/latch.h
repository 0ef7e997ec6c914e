/* The frame latch (PROTOCOL.md section 3, "The frame latch: STAGE_LEVEL, SHOW"): levels staged
 * for one frame number, shown all at once by a SHOW of that frame (usually broadcast, so every
 * controller on every bus shows it together). RAM only: a boot starts with nothing staged.
 * Main context only (frames); what a SHOW moves goes through the controller's SET_LEVEL path. */
#ifndef FW_LATCH_H
#define FW_LATCH_H
#include <stdint.h>
#include "limits.h"

typedef struct {
    uint8_t any;                          /* some pixel is staged */
    uint16_t frame;                       /* the frame number they belong to */
    uint8_t level[FW_MAX_PIXELS];         /* staged levels */
    uint8_t staged[(FW_MAX_PIXELS + 7u) / 8u];   /* bit p % 8 of byte p / 8: pixel p staged */
} fw_latch_state;

void fw_latch_boot(fw_latch_state *s);
/* Stage levels[i] for pixel first + i of `frame` (the caller checked the range). A frame number
 * other than the one staged drops what that one staged first. */
void fw_latch_stage(fw_latch_state *s, uint16_t frame, uint16_t first, const uint8_t *levels,
                    uint16_t n);
/* Whether pixel p is staged (after fw_latch_take's check, to walk the pixels to show). */
static inline int fw_latch_has(const fw_latch_state *s, uint16_t p)
{
    return (s->staged[p / 8u] >> (p % 8u)) & 1u;
}
/* A SHOW of `frame`: 1 when that frame is staged (the caller then shows every staged pixel
 * with fw_latch_has / level[], and calls fw_latch_clear), else 0 after dropping what another
 * frame staged. */
int fw_latch_take(fw_latch_state *s, uint16_t frame);
/* Nothing staged any more. */
void fw_latch_clear(fw_latch_state *s);

#endif
