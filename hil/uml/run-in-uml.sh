#!/usr/bin/env bash
# Run a command inside User-Mode Linux, whose kernel has SocketCAN, with vcan0 up.
#
# Usage: hil/uml/run-in-uml.sh [--timeout SECS] [--mem SIZE] [--cpu N] -- COMMAND [ARGS...]
#
# The guest's root file system is the host's / (hostfs, read-write); COMMAND runs as the same
# user, in the current directory, with the exported environment, and with
# ELEGANT_STEPPING_IN_UML=1. Its output comes out on stdout. This script exits with COMMAND's
# exit status, carried out of the VM through a file (linux.uml itself always exits 0);
# 124 if the time limit killed the VM, 125 if the VM ended without reporting a status.
#
# Needs the Debian/Ubuntu packages user-mode-linux and kmod:
#     apt-get install -y user-mode-linux kmod
set -uo pipefail
# (All in a function: bash reads a script as it runs, so an edit to this file cannot upset a run.)
main() {
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
TIMEOUT=${UML_TIMEOUT:-900}
MEM=${UML_MEM:-1536M}
CPU=${UML_CPU:-0}
while [ $# -gt 0 ]; do
  case "$1" in
    --timeout) TIMEOUT=$2; shift 2 ;;
    --mem) MEM=$2; shift 2 ;;
    --cpu) CPU=$2; shift 2 ;;
    --) shift; break ;;
    -*) echo "run-in-uml: unknown option $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[ $# -gt 0 ] || { echo "usage: $0 [--timeout S] [--mem M] [--cpu N] -- COMMAND [ARGS...]" >&2; exit 2; }
UML=$(command -v linux.uml) || {
  echo "run-in-uml: linux.uml not found; install it with: apt-get install -y user-mode-linux kmod" >&2; exit 127; }
command -v insmod >/dev/null || [ -x /usr/sbin/insmod ] || [ -x /sbin/insmod ] || {
  echo "run-in-uml: insmod not found; install it with: apt-get install -y kmod" >&2; exit 127; }

# Hosts with AVX-512/AMX have an XSAVE area bigger than UML 6.1 can restore; the shim (see
# xstate-shim.c) completes UML's short FPU restores. Built once with cc, cached.
PRELOAD=
if [ -z "${UML_NO_SHIM:-}" ]; then
  CACHE="${XDG_CACHE_HOME:-${HOME:-/root}/.cache}/elegant-stepping"
  SUM=$(cksum < "$HERE/xstate-shim.c" | cut -d' ' -f1)
  SHIM="$CACHE/uml-xstate-shim-$SUM.so"
  if [ ! -s "$SHIM" ]; then
    mkdir -p "$CACHE" && ${CC:-cc} -O2 -shared -fPIC -o "$SHIM.tmp.$$" "$HERE/xstate-shim.c" 2>"$CACHE/shim-build.log" \
      && mv -f "$SHIM.tmp.$$" "$SHIM" \
      || echo "run-in-uml: could not build $SHIM (see $CACHE/shim-build.log); on an AVX-512/AMX host UML will fail" >&2
  fi
  [ -s "$SHIM" ] && PRELOAD=$SHIM
fi
# For the guest: a cheap gettimeofday() (see coarse-time.c); hil uses it for the plant's process.
CACHE="${XDG_CACHE_HOME:-${HOME:-/root}/.cache}/elegant-stepping"
SUM=$(cksum < "$HERE/coarse-time.c" | cut -d' ' -f1)
COARSE="$CACHE/uml-coarse-time-$SUM.so"
if [ ! -s "$COARSE" ]; then
  mkdir -p "$CACHE" && ${CC:-cc} -O2 -shared -fPIC -o "$COARSE.tmp.$$" "$HERE/coarse-time.c" 2>>"$CACHE/shim-build.log" \
    && mv -f "$COARSE.tmp.$$" "$COARSE" || rm -f "$COARSE.tmp.$$"
fi
if [ -s "$COARSE" ]; then export ELEGANT_STEPPING_UML_COARSE_TIME="$COARSE"; fi

[ -x "$HERE/uml-init" ] || chmod +x "$HERE/uml-init" 2>/dev/null || {
  echo "run-in-uml: $HERE/uml-init is not executable" >&2; exit 126; }
JOB=$(mktemp -d "${TMPDIR:-/tmp}/es-uml.XXXXXX")
trap 'rm -rf "$JOB"' EXIT
export HOME="${HOME:-/root}"          # linux.uml panics at boot when $HOME is unset
export ELEGANT_STEPPING_IN_UML=1
export -p | grep -vE '^declare -x (PWD|OLDPWD|SHLVL|_|TMPDIR)=' > "$JOB/env.sh"
pwd > "$JOB/cwd"
printf '%q ' "$@" > "$JOB/cmd.sh"; echo >> "$JOB/cmd.sh"

# con0: never reads stdin (CI has none), writes to our stdout; all other consoles off.
# taskset: the UML kernel and its guest processes switch through ptrace all the time; on one
# CPU these switches are 3-4x cheaper than across CPUs.
# TMPDIR: linux.uml backs the guest's memory with a file there (/dev/shm: tmpfs, if usable).
MEMDIR=/dev/shm; [ -d "$MEMDIR" ] && [ -w "$MEMDIR" ] || MEMDIR=$JOB
TMPDIR="$MEMDIR" LD_PRELOAD="$PRELOAD" timeout --kill-after=15 "$TIMEOUT" taskset -c "$CPU" "$UML" mem="$MEM" \
  root=/dev/root rootfstype=hostfs rootflags=/ rw init="$HERE/uml-init" \
  con0=null,fd:1 con=null ssl=null quiet uml_dir="$JOB" es_job="$JOB" </dev/null 2>&1 \
  | grep --line-buffered -vE '^(SELinux: |mmapper_init|Failed to initialize ubd device 0|reboot: |sysrq: |random: )'
urc=${PIPESTATUS[0]}
if [ -s "$JOB/rc" ]; then
  exit "$(cat "$JOB/rc")"
fi
if [ "$urc" = 124 ] || [ "$urc" = 137 ]; then
  echo "run-in-uml: time limit of ${TIMEOUT} s reached; the VM was killed" >&2; exit 124
fi
echo "run-in-uml: the VM ended without reporting an exit status (linux.uml exit $urc)" >&2
exit 125
}
main "$@"
