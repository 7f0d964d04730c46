#!/usr/bin/env bash
# Stops the daemons slurm-up.sh started, by the pids it recorded (never by name, so a
# Slurm or munge started by someone else is left alone). Running it twice is fine.
set -euo pipefail

PIDS=/run/slurm/ci-daemons.pids
[ -f "$PIDS" ] || { echo "slurm-down: nothing recorded in $PIDS"; exit 0; }

# Reverse start order: slurmd, then slurmctld, then munged, which both still need.
# A zombie counts as gone: PID 1 in some containers never reaps daemons.
running() { [ -d "/proc/$1" ] && ! grep -q '^State:.Z' "/proc/$1/status" 2>/dev/null; }
tac "$PIDS" | while read -r name pid; do
  # Skip a pid that has since died or been reused by another program.
  if [ "$(cat "/proc/$pid/comm" 2>/dev/null)" != "$name" ] || ! running "$pid"; then continue; fi
  kill "$pid"
  for _ in $(seq 100); do running "$pid" || break; sleep 0.1; done
  running "$pid" && kill -9 "$pid"
  echo "slurm-down: stopped $name ($pid)"
done
rm -f "$PIDS"
