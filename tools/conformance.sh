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
# run SCENE PASSES|tSECONDS [MASK]: a pass count, or a time budget written as t600.
run() {
  local scene=$1 budget=$2 mask=${3:-}
  local exr="$out/$scene-$budget.exr" json="$out/$scene-$budget.json"
  local limit=(--passes "$budget")
  [[ $budget == t* ]] && limit=(--time "${budget#t}")
  $ppb render "scenes/conformance/$scene/scene.toml" -q "${limit[@]}" -o "$exr" --stats "$json"
  local secs passes
  secs=$(grep -m1 '"total"' "$json" | tr -dc '0-9.')
  passes=$(grep -m1 '"passes"' "$json" | tr -dc '0-9')
  # fog-near-light is compared with this repository's corrected re-render (docs/conformance.md).
  local dir="$ref/$scene"
  [ "$scene" = fog-near-light ] && dir=tests/data/conformance/$scene
  local args=("$exr" "$dir/reference.exr" --block 4)
  [ -n "$mask" ] && args+=(--mask "$dir/$mask")
  local cmp
  cmp=$($ppb compare "${args[@]}")
  printf '%-14s %7s %9.1f %9s %12s\n' "$scene" "$passes" "$secs" \
    "$(echo "$cmp" | awk '$1 == "rel_l1" && $2 != "of" {print $2}')" \
    "$(echo "$cmp" | awk '/block means/{print $NF}')"
}
# SCENES="fog-box glass-caustic smoke-grid cloud-hg fog-near-light" picks scenes; *_PASSES
# the budgets.
for s in ${SCENES:-fog-box glass-caustic smoke-grid cloud-hg fog-near-light}; do
  case $s in
    fog-box) for p in ${FOG_PASSES:-32 128 t300}; do run fog-box "$p"; done ;;
    glass-caustic) for p in ${CAUSTIC_PASSES:-32 128 t570}; do run glass-caustic "$p" emitter_mask.png; done ;;
    smoke-grid) for p in ${SMOKE_PASSES:-32 128 t300}; do run smoke-grid "$p"; done ;;
    cloud-hg) for p in ${CLOUD_PASSES:-32 128 t300}; do run cloud-hg "$p"; done ;;
    fog-near-light) for p in ${NEAR_PASSES:-32 128 t300}; do run fog-near-light "$p" emitter_mask.png; done ;;
  esac
done
