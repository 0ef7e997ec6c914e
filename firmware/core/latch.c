#include "latch.h"
#include <string.h>

void fw_latch_boot(fw_latch_state *s)
{
    fw_latch_clear(s);
    s->frame = 0;
}

void fw_latch_clear(fw_latch_state *s)
{
    s->any = 0;
    memset(s->staged, 0, sizeof s->staged);
}

void fw_latch_stage(fw_latch_state *s, uint16_t frame, uint16_t first, const uint8_t *levels,
                    uint16_t n)
{
    if (!s->any || s->frame != frame) {   /* a new frame */
        fw_latch_clear(s);
        s->frame = frame;
    }
    for (uint16_t i = 0; i < n; i++) {
        uint16_t p = (uint16_t)(first + i);
        s->level[p] = levels[i];
        s->staged[p / 8u] |= (uint8_t)(1u << (p % 8u));
    }
    if (n)
        s->any = 1;
}

int fw_latch_take(fw_latch_state *s, uint16_t frame)
{
    if (s->any && s->frame == frame)
        return 1;
    fw_latch_clear(s);
    return 0;
}
