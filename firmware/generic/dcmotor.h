/* A DC motor driving one grass pixel through a gear with backlash: the plant that the ports
 * without real motors (posix, mps2) and the motor bench simulate. Units: micrometres of grass
 * length, seconds, duty -1..1.
 *
 *   dv/dt = (vmax * (u - coulomb * sign(v)) - v) / tau      while moving
 *   the motor stays at rest while |u| <= stiction               (static friction)
 *   grass = motor position, followed with a dead zone of +-backlash/2
 *   encoder = floor(motor position / um_per_count)             (encoder on the motor side)
 *
 * tau is the mechanical time constant (rotor + gear inertia over the motor's damping). */
#ifndef DCMOTOR_H
#define DCMOTOR_H
#include <stdint.h>

typedef struct {
    double vmax_um_s;     /* no-load speed at full duty */
    double tau_s;         /* mechanical time constant (inertia) */
    double coulomb;       /* Coulomb (sliding) friction, as duty */
    double stiction;      /* static friction, as duty */
    double backlash_um;   /* gear backlash, total play */
    double um_per_count;  /* encoder resolution */
    double min_um, max_um;  /* end stops of the mechanism */
    double substep_s;     /* integration step (s) */
} dc_params;

typedef struct {
    double motor_um, v_um_s, grass_um;
} dc_state;

/* The parameters of the paper-like pixel used everywhere (posix port, bench, tests). */
dc_params dc_default_params(void);
/* Advance by dt seconds with duty u (-1..1), in substeps of at most substep_s. */
void dc_step(const dc_params *p, dc_state *s, double u, double dt);
int32_t dc_encoder(const dc_params *p, const dc_state *s);
/* At rest: not moving. */
int dc_at_rest(const dc_state *s);

#endif
