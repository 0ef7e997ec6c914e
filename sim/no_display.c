/* The X11 calls that Taichi's wheel links for its window (ti.GUI), for a machine without
 * libX11. grassd never opens a Taichi window, but the wheel's taichi_python module names
 * libX11.so.6, so without one Taichi cannot be imported at all. Built as libX11.so.6 into the
 * venv (the Makefile) and loaded by grassd.sim.backend only where the system has none.
 *
 * There is no display here: XOpenDisplay answers NULL, as libX11 does when it cannot open
 * one. Every other call needs a display it was never given, so it says so and aborts.
 */
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>

void *XOpenDisplay(const char *name);

void *XOpenDisplay(const char *name)
{
    (void)name;
    return NULL;
}

static void no_display(const char *call)
{
    fprintf(stderr, "grassd: %s without a display: this machine has no libX11 "
                    "(apt-get install libx11-6 for Taichi's window)\n", call);
    abort();
}

#define NEEDS_A_DISPLAY(name) \
    void name(void);          \
    void name(void) { no_display(#name); }

NEEDS_A_DISPLAY(XChangeProperty)
NEEDS_A_DISPLAY(XCloseDisplay)
NEEDS_A_DISPLAY(XCreateImage)
NEEDS_A_DISPLAY(XCreateSimpleWindow)
NEEDS_A_DISPLAY(XInternAtom)
NEEDS_A_DISPLAY(XKeysymToString)
NEEDS_A_DISPLAY(XLookupKeysym)
NEEDS_A_DISPLAY(XMapWindow)
NEEDS_A_DISPLAY(XNextEvent)
NEEDS_A_DISPLAY(XPending)
NEEDS_A_DISPLAY(XPutImage)
NEEDS_A_DISPLAY(XSelectInput)
NEEDS_A_DISPLAY(XSetWMProtocols)
NEEDS_A_DISPLAY(XStoreName)
