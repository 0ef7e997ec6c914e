/* Critical sections of the posix port (core/hal.h): signals stand in for interrupts.
 *
 * This port runs fw_tick from its poll loop, in the same thread as the frame handlers, so no
 * signal handler touches a controller today (SIGINT/SIGTERM only set a flag). Blocking every
 * signal for the length of a section keeps the core correct if a tick ever moves into a timer
 * signal (setitimer/SIGALRM, as test/irq_torn.c does to check the sections), which is how a
 * Linux process models a SysTick. The previous state is "already masked by an outer section"
 * (1) or not (0), as PRIMASK's bit is on Cortex-M; the signal mask from before the outermost
 * section is kept here and put back when it ends. One thread only (sigprocmask). */
#include <signal.h>
#include "../../core/hal.h"

static sigset_t outside;               /* the mask before the outermost section */
static volatile sig_atomic_t masked;   /* inside a section */

fw_irqstatus fw_irq_save(void)
{
    if (masked)
        return 1u;
    sigset_t all;
    sigfillset(&all);
    sigprocmask(SIG_BLOCK, &all, &outside);
    masked = 1;
    return 0u;
}

void fw_irq_restore(fw_irqstatus flag)
{
    if (flag)
        return;   /* an inner section ends: the outer one still holds the signals */
    masked = 0;
    sigprocmask(SIG_SETMASK, &outside, NULL);
}
