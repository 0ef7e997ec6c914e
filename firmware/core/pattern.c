#include "pattern.h"
#include "le.h"

#define MS_PER_DS 100u

void fw_pattern_boot(fw_pattern_state *s, const fw_motors *m, uint16_t n_pixels)
{
    s->active = 0;
    for (uint16_t p = 0; p < n_pixels; p++)
        s->normal_um[p] = m->target_um[p];   /* only the main context writes target_um */
}

void fw_pattern_set_normal(fw_pattern_state *s, fw_motors *m, uint16_t pixel, uint16_t um)
{
    s->normal_um[pixel] = um;
    if (!s->active)
        fw_motor_set_target(m, pixel, um);
}

int fw_pattern_show(fw_pattern_state *s, fw_motors *m, const fw_pattern *p, uint16_t n_pixels,
                    uint16_t max_length_um, uint32_t now_ms, uint32_t *detail)
{
    uint16_t count = (uint16_t)(p->lengths_len / 2u);
    if (p->timeout_ds == 0) {
        *detail = 0;
        return FW_NAK_BAD_PAYLOAD;
    }
    if ((uint32_t)p->first_pixel + count > n_pixels) {
        *detail = n_pixels;
        return FW_NAK_BAD_PIXEL;
    }
    for (uint16_t i = 0; i < count; i++)
        if (fw_get16(p->lengths + 2u * i) > max_length_um) {
            *detail = i;
            return FW_NAK_VALUE_RANGE;
        }
    for (uint16_t i = 0; i < count; i++)
        fw_motor_set_target(m, (uint16_t)(p->first_pixel + i), fw_get16(p->lengths + 2u * i));
    s->active = 1;
    s->armed_ms = now_ms;
    s->timeout_ms = (uint32_t)p->timeout_ds * MS_PER_DS;
    return 0;
}

void fw_pattern_end(fw_pattern_state *s, fw_motors *m, uint16_t n_pixels)
{
    if (!s->active)
        return;
    s->active = 0;
    for (uint16_t p = 0; p < n_pixels; p++)
        fw_motor_set_target(m, p, s->normal_um[p]);
}

int fw_pattern_poll(fw_pattern_state *s, fw_motors *m, uint16_t n_pixels, uint32_t now_ms)
{
    if (!s->active || (uint32_t)(now_ms - s->armed_ms) < s->timeout_ms)
        return 0;
    fw_pattern_end(s, m, n_pixels);
    return 1;
}
