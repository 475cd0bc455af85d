/*
 * LD_PRELOAD shim for linux.uml (User-Mode Linux 6.1) on hosts with a large XSAVE area.
 *
 * UML saves and restores its guest processes' FPU state with ptrace(PTRACE_GETREGSET /
 * PTRACE_SETREGSET, NT_X86_XSTATE) through a fixed 832-byte buffer (x87, SSE, AVX). Host
 * kernels since 5.16 refuse a SETREGSET that is not the whole XSAVE area (EFAULT), and hosts
 * with AVX-512 or AMX have a bigger one (10-11 KB), so UML dies at boot with
 * "ptrace set fp regs failed, errno = 14".
 *
 * This shim completes such a short SETREGSET: it takes the traced process's whole XSAVE area
 * (kept from UML's last GETREGSET of it, which the shim makes whole-sized; else read afresh),
 * lays UML's part over its head, takes the XSTATE_BV bits of the components UML's part
 * holds from UML and the others from the process, and sets the whole area. Components UML
 * does not know (AVX-512, AMX) are thus left as the host process last had them.
 * Everything else passes through unchanged.
 */
#define _GNU_SOURCE
#include <cpuid.h>
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/syscall.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

#ifndef NT_X86_XSTATE
#define NT_X86_XSTATE 0x202
#endif
#define XSAVE_MAX (64 * 1024)
#define XSTATE_BV_OFFSET 512

static unsigned char full_area[XSAVE_MAX] __attribute__((aligned(64)));

static long raw_ptrace(long req, long pid, void *addr, void *data)
{
    return syscall(SYS_ptrace, req, pid, addr, data);
}

/* XSTATE_BV bits of the components that lie wholly inside the first len bytes (cached:
 * CPUID is slow in a virtual machine). */
static uint64_t components_within(size_t len)
{
    static size_t cached_len;
    static uint64_t cached_mask;
    if (len == cached_len)
        return cached_mask;
    uint64_t mask = 0;
    if (len >= 512)
        mask |= 0x3; /* x87 and SSE: the legacy area */
    for (unsigned i = 2; i < 64; i++) {
        unsigned eax, ebx, ecx, edx;
        if (!__get_cpuid_count(0xd, i, &eax, &ebx, &ecx, &edx) || eax == 0)
            continue;
        if ((size_t)ebx + eax <= len) /* eax: size, ebx: standard-format offset */
            mask |= 1ULL << i;
    }
    cached_len = len;
    cached_mask = mask;
    return mask;
}

/* The whole XSAVE area of each traced process, as of UML's last GETREGSET of it: UML reads the
 * FPU state after every stop and writes it before every resume, so a short SETREGSET can be
 * completed from here without reading the area again. */
#define CACHE_N 16
#define AREA_MAX 16384
struct area {
    pid_t pid;
    size_t len; /* 0: not valid */
    unsigned long used;
    unsigned char bytes[AREA_MAX] __attribute__((aligned(64)));
};
static struct area cache[CACHE_N];
static unsigned long clock_tick;

static struct area *find(pid_t pid, int create)
{
    struct area *oldest = &cache[0];
    for (int i = 0; i < CACHE_N; i++) {
        if (cache[i].len && cache[i].pid == pid) {
            cache[i].used = ++clock_tick;
            return &cache[i];
        }
        if (cache[i].used < oldest->used)
            oldest = &cache[i];
    }
    if (!create)
        return NULL;
    oldest->pid = pid;
    oldest->len = 0;
    oldest->used = ++clock_tick;
    return oldest;
}

static long complete_set(pid_t pid, void *addr, struct iovec *iov, unsigned char *whole, size_t whole_len)
{
    uint64_t ours = components_within(iov->iov_len), bv_uml, bv_host;
    memcpy(&bv_uml, (char *)iov->iov_base + XSTATE_BV_OFFSET, 8);
    memcpy(&bv_host, whole + XSTATE_BV_OFFSET, 8);
    memcpy(whole, iov->iov_base, iov->iov_len);
    bv_host = (bv_uml & ours) | (bv_host & ~ours);
    memcpy(whole + XSTATE_BV_OFFSET, &bv_host, 8);
    struct iovec w = { whole, whole_len };
    return raw_ptrace(PTRACE_SETREGSET, pid, addr, &w);
}

long ptrace(enum __ptrace_request request, ...)
{
    va_list ap;
    va_start(ap, request);
    pid_t pid = va_arg(ap, pid_t);
    void *addr = va_arg(ap, void *);
    void *data = va_arg(ap, void *);
    va_end(ap);

    if (request == PTRACE_GETREGSET && (long)addr == NT_X86_XSTATE && data != NULL) {
        struct iovec *iov = data;
        if (iov->iov_len < AREA_MAX) {
            struct area *a = find(pid, 1);
            struct iovec whole = { a->bytes, AREA_MAX };
            a->len = 0;
            if (raw_ptrace(PTRACE_GETREGSET, pid, addr, &whole) < 0)
                return -1;
            size_t n = whole.iov_len < iov->iov_len ? whole.iov_len : iov->iov_len;
            memcpy(iov->iov_base, a->bytes, n);
            iov->iov_len = n;
            if (whole.iov_len > n)
                a->len = whole.iov_len;
            return 0;
        }
    }
    if (request == PTRACE_SETREGSET && (long)addr == NT_X86_XSTATE && data != NULL) {
        struct iovec *iov = data;
        if (iov->iov_len >= XSTATE_BV_OFFSET + 8) {
            struct area *a = find(pid, 0);
            if (a != NULL && a->len > iov->iov_len)
                return complete_set(pid, addr, iov, a->bytes, a->len);
            struct iovec whole = { full_area, sizeof full_area };
            if (raw_ptrace(PTRACE_GETREGSET, pid, addr, &whole) == 0 && whole.iov_len > iov->iov_len)
                return complete_set(pid, addr, iov, full_area, whole.iov_len);
        }
    }
    /* PEEK* requests return the word read; glibc's wrapper handles that. */
    if (request == PTRACE_PEEKTEXT || request == PTRACE_PEEKDATA || request == PTRACE_PEEKUSER) {
        long word;
        long rc = raw_ptrace(request, pid, addr, &word);
        if (rc < 0)
            return -1;
        errno = 0;
        return word;
    }
    return raw_ptrace(request, pid, addr, data);
}
