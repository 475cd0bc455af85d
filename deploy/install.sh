#!/usr/bin/env bash
# Install the controller daemon as a systemd service on the leg's computer (Debian, Ubuntu,
# Raspberry Pi OS). Run from a checkout of this repository, as root:
#
#     sudo bash deploy/install.sh [--config FILE] [--no-enable] [--dry-run] [--root DIR]
#
# Steps (each printed before it runs):
#   1. the system user and group 'elegant-stepping' (no login, home /var/lib/elegant-stepping);
#   2. a virtual environment in /opt/elegant-stepping/venv with this package installed into it,
#      (the core package only: the leg needs no simulator or plotting), and
#      /usr/local/bin/elegant-stepping-leg pointing at its command;
#   3. the unit /etc/systemd/system/elegant-stepping-controller.service, docs/deploy.md under
#      /usr/local/share/doc/elegant-stepping/, configs/sim.toml under /usr/local/share/elegant-stepping/
#      (for 'elegant-stepping dryrun' on this machine);
#   4. the leg's configuration /etc/elegant-stepping/leg.toml from --config FILE (default
#      configs/odrive-leg.toml), never over an existing one (that one holds your calibration:
#      the new file goes to leg.toml.new beside it);
#   5. systemctl daemon-reload, then enable (not start: start it once the leg is calibrated,
#      docs/deploy.md); --no-enable skips the enable.
#
# --dry-run prints the commands and runs none. --root DIR installs the files (steps 3 and 4, and
# the symlink of step 2) under DIR instead of /, for staging an image or a test; the user, the
# virtual environment and systemctl are then only printed. Nothing runs when this file is
# sourced or checked with 'bash -n'.
set -euo pipefail

main() {
  local here repo root="" dry=0 enable=1 config=""
  here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
  repo=$(dirname "$here")
  while [ $# -gt 0 ]; do
    case "$1" in
      --root) root=${2:?--root needs a folder}; shift 2 ;;
      --dry-run) dry=1; shift ;;
      --no-enable) enable=0; shift ;;
      --config) config=${2:?--config needs a file}; shift 2 ;;
      -h|--help) sed -n '2,23p' "${BASH_SOURCE[0]}"; return 0 ;;
      *) echo "install.sh: unknown option $1" >&2; return 2 ;;
    esac
  done
  config=${config:-$repo/configs/odrive-leg.toml}
  local user=elegant-stepping
  local venv=/opt/elegant-stepping/venv
  local unit=elegant-stepping-controller.service
  local etc=$root/etc/elegant-stepping
  local staged=0
  [ -n "$root" ] && staged=1

  # run CMD...: print it; run it unless --dry-run. host CMD...: the same, but only for a real
  # install (not under --root: users, venvs and systemctl belong to the running system).
  run() { printf '+ %s\n' "$*"; [ "$dry" = 1 ] || "$@"; }
  host() {
    if [ "$staged" = 1 ]; then printf '(skipped under --root) %s\n' "$*"; else run "$@"; fi
  }

  [ -f "$here/$unit" ] || { echo "install.sh: $here/$unit missing" >&2; return 1; }
  [ -f "$config" ] || { echo "install.sh: no configuration $config (give one with --config FILE)" >&2; return 1; }
  if [ "$dry" = 0 ] && [ "$staged" = 0 ] && [ "$(id -u)" != 0 ]; then
    echo "install.sh: run as root (or try --dry-run / --root DIR)" >&2; return 1
  fi

  # 1. the user
  if [ "$staged" = 1 ] || ! id -u "$user" >/dev/null 2>&1; then
    host useradd --system --user-group --home-dir /var/lib/elegant-stepping --no-create-home \
      --shell /usr/sbin/nologin "$user"
  fi
  # 2. the package, in its own virtual environment
  host python3 -m venv "$venv"
  host "$venv/bin/python" -m pip install --upgrade pip
  host "$venv/bin/python" -m pip install -c "$repo/constraints.txt" "$repo"
  run install -d -m 0755 "$root/usr/local/bin"
  run ln -sfn "$venv/bin/elegant-stepping-leg" "$root/usr/local/bin/elegant-stepping-leg"
  # 3. the unit and its documentation
  run install -d -m 0755 "$root/etc/systemd/system" "$root/usr/local/share/doc/elegant-stepping"
  run install -m 0644 "$here/$unit" "$root/etc/systemd/system/$unit"
  run install -m 0644 "$repo/docs/deploy.md" "$root/usr/local/share/doc/elegant-stepping/deploy.md"
  # the simulated leg's config, for 'elegant-stepping dryrun' on this machine
  run install -D -m 0644 "$repo/configs/sim.toml" "$root/usr/local/share/elegant-stepping/sim.toml"
  # 4. the configuration: readable by the daemon's group, never overwritten
  run install -d -m 0755 "$etc"
  local target=$etc/leg.toml
  if [ -e "$target" ]; then
    echo "install.sh: $target exists (your calibration); the new one goes to leg.toml.new"
    target=$etc/leg.toml.new
  fi
  run install -m 0640 "$config" "$target"
  host chgrp "$user" "$target"
  # 5. systemd
  host systemctl daemon-reload
  if [ "$enable" = 1 ]; then
    host systemctl enable "$unit"
  fi
  echo "install.sh: done. Calibrate (docs/deploy.md), check the unit on a development machine with 'elegant-stepping dryrun' (docs/deploy.md), bring the leg up with 'elegant-stepping-leg bringup', then: systemctl start $unit"
}

# Only when executed, never when sourced.
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
  main "$@"
fi
