/* Torn motor targets: the motor loop (fw_tick) runs from a timer signal, SIGALRM every 20 us
 * (how a Linux process models a SysTick), while the main context sets targets as SET_LEVEL
 * frames do (fw_motor_set_target) and reads positions as GET_POSITIONS does
 * (fw_motor_position). Every tick checks, for every pixel, that the pair it shares with the
 * main context is whole: target (counts) == fw_um_to_counts(target_um). Built with the posix
 * port's critical sections (ports/posix/irq.c) none may be torn; built with test/irq_none.c
 * (no sections) the same run shows how often the tick lands between the two stores.
 *
 * Usage: irq_torn [SECONDS]   prints "irq_torn: T ticks, S targets set, N torn pairs seen"
 * and exits 1 when N > 0 (2 when too few ticks ran to tell). */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/time.h>
#include <time.h>
#include "ram_hal.h"

#define N_PIX 16u

static ram_hal hw;
static fw_controller ctl;
static volatile sig_atomic_t ticks, torn;

static void on_tick(int sig)
{
    (void)sig;
    fw_tick(&ctl);
    for (uint16_t p = 0; p < N_PIX; p++)
        if (ctl.motors.target[p] != fw_um_to_counts(ctl.motors.target_um[p]))
            torn = torn + 1;
    ticks = ticks + 1;
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

int main(int argc, char **argv)
{
    double seconds = argc > 1 ? atof(argv[1]) : 1.0;
    ram_hal_init(&hw);
    fw_config cfg = {.address = 1, .n_pixels = N_PIX, .uid = 1u, .max_chunk = 256,
                     .max_length_um = 20000};
    if (fw_boot(&ctl, &hw.hal, &cfg) < 0) {
        fprintf(stderr, "irq_torn: boot failed\n");
        return 2;
    }
    struct sigaction sa = {.sa_handler = on_tick};
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_RESTART;
    sigaction(SIGALRM, &sa, NULL);
    struct itimerval every = {{0, 20}, {0, 20}};
    setitimer(ITIMER_REAL, &every, NULL);
    unsigned long set = 0;
    uint32_t sum = 0;
    double end = now_s() + seconds;
    while (now_s() < end) {
        for (uint32_t i = 0; i < 4096; i++, set++) {
            uint16_t p = (uint16_t)(set % N_PIX);
            /* every value changes both fields of the pair */
            fw_motor_set_target(&ctl.motors, p, (uint16_t)((set * 7919u) % 20001u));
            if ((i & 63u) == 0) {
                uint16_t target_um;
                sum += fw_motor_position(&ctl.motors, &hw.hal, p, &target_um) + target_um;
            }
        }
    }
    struct itimerval off = {{0, 0}, {0, 0}};
    setitimer(ITIMER_REAL, &off, NULL);
    printf("irq_torn: %ld ticks, %lu targets set, %ld torn pairs seen (checksum %u)\n",
           (long)ticks, set, (long)torn, (unsigned)sum);
    if (ticks < 1000)
        return 2;
    return torn > 0;
}
