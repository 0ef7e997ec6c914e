#include "dcmotor.h"
#include <math.h>

dc_params dc_default_params(void)
{
    return (dc_params){.vmax_um_s = 60000.0, .tau_s = 0.02, .coulomb = 0.03, .stiction = 0.05,
                       .backlash_um = 40.0, .um_per_count = 12.5, .min_um = -500.0,
                       .max_um = 20500.0, .substep_s = 1e-4};
}

static void substep(const dc_params *p, dc_state *s, double u, double h)
{
    if (s->v_um_s == 0.0 && fabs(u) <= p->stiction)
        return;   /* held by static friction */
    double dir = s->v_um_s != 0.0 ? (s->v_um_s > 0 ? 1.0 : -1.0) : (u > 0 ? 1.0 : -1.0);
    double a = (p->vmax_um_s * (u - p->coulomb * dir) - s->v_um_s) / p->tau_s;
    double v = s->v_um_s + a * h;
    if (v * dir < 0.0 && fabs(u) <= p->stiction)
        v = 0.0;   /* friction stops the motor, and static friction holds it */
    s->v_um_s = v;
    s->motor_um += v * h;
    if (s->motor_um < p->min_um || s->motor_um > p->max_um) {
        s->motor_um = s->motor_um < p->min_um ? p->min_um : p->max_um;
        s->v_um_s = 0.0;
    }
    double half = p->backlash_um / 2.0;
    if (s->motor_um - s->grass_um > half)
        s->grass_um = s->motor_um - half;
    else if (s->grass_um - s->motor_um > half)
        s->grass_um = s->motor_um + half;
}

void dc_step(const dc_params *p, dc_state *s, double u, double dt)
{
    u = u > 1.0 ? 1.0 : u < -1.0 ? -1.0 : u;
    int n = (int)ceil(dt / p->substep_s - 1e-9);
    for (int i = 0; i < n; i++)
        substep(p, s, u, dt / n);
}

int32_t dc_encoder(const dc_params *p, const dc_state *s)
{
    return (int32_t)floor(s->motor_um / p->um_per_count);
}

int dc_at_rest(const dc_state *s)
{
    return s->v_um_s == 0.0;
}
