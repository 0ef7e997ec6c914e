/* Motor step response: the core's PD loop (motor.c, 1 ms period) driving the DC-motor model of
 * the posix and mps2 ports (generic/dcmotor.c) through the HAL. Prints, per step, the settling time
 * into +-0.1 mm of the target and the overshoot, measured on the grass (after the backlash),
 * and exits non-zero when the 0 -> 20 mm step misses settle <= 1 s or overshoot <= 0.2 mm.
 * Usage: bench_motor [--json] */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "../core/controller.h"
#include "../generic/dcmotor.h"

typedef struct { dc_params p; dc_state s; int16_t duty; } plant;

static int32_t enc(void *ctx, uint16_t px) { (void)px; plant *m = ctx; return dc_encoder(&m->p, &m->s); }
static void pwm(void *ctx, uint16_t px, int16_t d) { (void)px; ((plant *)ctx)->duty = d; }

typedef struct { double from_mm, to_mm, settle_s, overshoot_mm, final_err_mm; } step_result;

static step_result step(double from_um, double to_um)
{
    plant m = {.p = dc_default_params()};
    m.s.motor_um = m.s.grass_um = from_um;
    fw_hal hal = {.ctx = &m, .encoder_read = enc, .pwm_write = pwm};
    fw_motors mot;
    fw_motors_init(&mot, &hal, 1);
    fw_motor_set_target(&mot, 0, (uint16_t)to_um);
    double settle = 0.0, peak = 0.0, dir = to_um >= from_um ? 1.0 : -1.0;
    const double tol = 100.0;
    for (int k = 1; k <= 3000; k++) {   /* 3 s */
        fw_motors_tick(&mot, &hal, 1);
        dc_step(&m.p, &m.s, m.duty / (double)FW_PWM_MAX, FW_TICK_US * 1e-6);
        double err = m.s.grass_um - to_um;
        if (fabs(err) > tol)
            settle = k * 1e-3;
        if (err * dir > peak)
            peak = err * dir;
    }
    return (step_result){from_um / 1000, to_um / 1000, settle, peak / 1000,
                         (m.s.grass_um - to_um) / 1000};
}

int main(int argc, char **argv)
{
    int json = argc > 1 && strcmp(argv[1], "--json") == 0;
    const double steps[][2] = {{0, 20000}, {20000, 0}, {0, 10000}, {10000, 10500}, {5000, 5300}};
    step_result main_step = step(0, 20000);
    dc_params p = dc_default_params();
    if (json)
        printf("{\"kp\": %d, \"kd\": %d, \"ff\": %d, \"deadband\": %d, \"tick_us\": %u, "
               "\"steps\": [", FW_PD_KP, FW_PD_KD, FW_PD_FF, FW_PD_DEADBAND, FW_TICK_US);
    else
        printf("PD gains: Kp %d/256, Kd %d/256 per mille per count, feed-forward %d per mille, "
               "deadband %d count; period %u us\nplant: vmax %.0f um/s, tau %.3f s, Coulomb %.2f, "
               "stiction %.2f, backlash %.0f um, encoder %.1f um/count\n", FW_PD_KP, FW_PD_KD,
               FW_PD_FF, FW_PD_DEADBAND, FW_TICK_US, p.vmax_um_s, p.tau_s, p.coulomb, p.stiction,
               p.backlash_um, p.um_per_count);
    for (size_t i = 0; i < sizeof steps / sizeof steps[0]; i++) {
        step_result r = step(steps[i][0], steps[i][1]);
        if (json)
            printf("%s{\"from_mm\": %.3f, \"to_mm\": %.3f, \"settle_s\": %.3f, \"overshoot_mm\": "
                   "%.4f, \"final_error_mm\": %.4f}", i ? ", " : "", r.from_mm, r.to_mm,
                   r.settle_s, r.overshoot_mm, r.final_err_mm);
        else
            printf("step %5.1f -> %5.1f mm: settles within +-0.1 mm in %.3f s, overshoot %.4f mm, "
                   "final error %+.4f mm\n", r.from_mm, r.to_mm, r.settle_s, r.overshoot_mm,
                   r.final_err_mm);
    }
    int ok = main_step.settle_s <= 1.0 && main_step.overshoot_mm <= 0.2;
    if (json)
        printf("], \"ok\": %s}\n", ok ? "true" : "false");
    return !ok;
}
