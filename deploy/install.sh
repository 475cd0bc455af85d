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
#   5. systemctl daemon-reload, then enable (not start) ONLY if the installed configuration's
#      calibration is confirmed ([calibration] confirmed = true, written by
#      'elegant-stepping-leg config confirm' after a bring-up passed on the leg); otherwise it
#      says how to confirm it and to run 'systemctl enable --now' after (docs/deploy.md, "First
#      power-on"). --no-enable skips the enable in any case.
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
      -h|--help) sed -n '2,26p' "${BASH_SOURCE[0]}"; return 0 ;;
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
  # 5. systemd: enabled only once the configuration in force is confirmed
  host systemctl daemon-reload
  local installed=$etc/leg.toml
  # the file in force: the installed one; under --dry-run (nothing installed) the one that would be
  [ -e "$installed" ] || installed=$config
  local leg=/etc/elegant-stepping/leg.toml
  if [ "$enable" = 0 ]; then
    echo "install.sh: not enabling $unit (--no-enable)"
  elif calibration_confirmed "$installed"; then
    host systemctl enable "$unit"
  else
    echo "install.sh: NOT enabling $unit: the calibration in $leg is not confirmed ([calibration] confirmed = false)."
    echo "  Measure the leg and write the values into $leg (docs/deploy.md, section 3), then, on the leg:"
    echo "    elegant-stepping-leg bringup --config $leg --json report.json"
    echo "    sudo elegant-stepping-leg config confirm $leg --bringup report.json"
    echo "    sudo systemctl enable --now $unit"
    echo "  (docs/deploy.md, \"First power-on\")"
  fi
  echo "install.sh: done. Check the unit on a development machine with 'elegant-stepping dryrun'; once enabled and started: elegant-stepping-leg status, then elegant-stepping-leg arm (docs/deploy.md)"
}

# calibration_confirmed FILE: true if FILE's [calibration] table says confirmed = true (the
# daemon's own check is DeployConfig.armable_reason; this is only the installer's reading).
calibration_confirmed() {
  awk '
    /^[[:space:]]*\[/ { section = $0; gsub(/[[:space:]]|#.*/, "", section) }
    section == "[calibration]" && /^[[:space:]]*confirmed[[:space:]]*=[[:space:]]*true([[:space:]]|#|$)/ { yes = 1 }
    END { exit yes ? 0 : 1 }
  ' "$1"
}

# Only when executed, never when sourced.
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
  main "$@"
fi
