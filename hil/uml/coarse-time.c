/*
 * LD_PRELOAD for the firmware-sim process inside User-Mode Linux: a cheap gettimeofday().
 *
 * UML has no vDSO, so every gettimeofday() is a trapped system call (about 10-20 us). PyBullet
 * calls it about seven times per physics step for its internal profiler, which made a step
 * cost 110 us inside UML against 28 us outside. Here gettimeofday() returns the time read by a
 * real call at most 64 calls earlier (per thread): coarse, never going backwards. Only
 * gettimeofday() is replaced: clock_gettime(), which Python's time.monotonic() and our
 * pacing use, is untouched, and so is the physics.
 */
#define _GNU_SOURCE
#include <stddef.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <unistd.h>

static __thread struct timeval last;
static __thread unsigned calls;

int gettimeofday(struct timeval *restrict tv, void *restrict tz)
{
    if (tz != NULL)
        return (int)syscall(SYS_gettimeofday, tv, tz);
    if ((calls++ & 63u) == 0 || (last.tv_sec == 0 && last.tv_usec == 0)) {
        if (syscall(SYS_gettimeofday, &last, NULL) != 0)
            return -1;
    }
    if (tv != NULL)
        *tv = last;
    return 0;
}
