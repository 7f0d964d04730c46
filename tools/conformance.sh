#!/usr/bin/env bash
# Renders the conformance scenes at full resolution for several pass counts and prints
# rel_l1 against the Mitsuba references (../shared/conformance) with the wall time.
# Usage: tools/conformance.sh [out-dir]   (needs `cargo build --release` first)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/conformance}
mkdir -p "$out"
ppb=target/release/ppb
ref=${PPB_SHARED:-../shared}/conformance
printf '%-14s %7s %9s %9s %12s\n' scene passes seconds rel_l1 "rel_l1 4x4"
run() {
  local scene=$1 passes=$2 mask=${3:-}
  local exr="$out/$scene-$passes.exr"
  $ppb render "scenes/conformance/$scene/scene.toml" -q --passes "$passes" -o "$exr" --stats "$out/$scene-$passes.json"
  local secs
  secs=$(grep -m1 '"total"' "$out/$scene-$passes.json" | tr -dc '0-9.')
  local args=("$exr" "$ref/$scene/reference.exr" --block 4)
  [ -n "$mask" ] && args+=(--mask "$ref/$scene/$mask")
  local cmp
  cmp=$($ppb compare "${args[@]}")
  printf '%-14s %7s %9.1f %9s %12s\n' "$scene" "$passes" "$secs" \
    "$(echo "$cmp" | awk '/^rel_l1 /{print $2}')" "$(echo "$cmp" | awk '/block means/{print $NF}')"
}
for p in ${FOG_PASSES:-64 256 1024}; do run fog-box "$p"; done
for p in ${CAUSTIC_PASSES:-32 128 256}; do run glass-caustic "$p" emitter_mask.png; done
