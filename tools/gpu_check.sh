#!/usr/bin/env bash
# The prepared device check for a machine with a real GPU (lent only now and then, for a
# few minutes): one run that builds, tests and measures the wgpu path and prints one table.
#
#   tools/gpu_check.sh            # the full check, under 8 minutes on one modern GPU
#   tools/gpu_check.sh --quick    # the same steps at toy sizes (lavapipe in CI, this machine)
#
# Steps (each logged to $OUT/<step>.log; the script goes on after a failure and exits 1 at
# the end if any step failed):
#   1. cargo build --release
#   2. PPB_REQUIRE_GPU=1 cargo test --release --test gpu: GPU/CPU parity and the GPU render
#   3. the paper-scale run: smoke-grid and the dense smoke at 512x512, 100,000 light paths x
#      128 passes, the paper's method (--method ppb), on the GPU with primary segments
#      rasterised (--gpu-primary auto) and gathered (--gpu-primary gather), rasterised with
#      the camera transmittance tracked on the GPU (--gpu-tr track), then on the CPU, with
#      --stats; the GPU images compared with the CPU's (rel_l1: float rounding for the
#      first two, noise for the tracked run, which draws its own transmittance)
#   4. the tube kernel: cloud-hg (HG g = 0.7, where the hybrid method's auto kernel is the
#      tube) at the same size, paths and passes, primary segments rasterised on the GPU,
#      then on the CPU; the images compared (float rounding: both devices draw the same
#      point on each chord)
#   5. ppb bench-gpu on the four public conformance scenes at full resolution
# Then one table: adapter, ms per pass on each device, their ratio, the GPU-vs-CPU
# difference, the time split of a pipelined GPU pass (estimate, overlap with the next
# pass's tracing, wait, upload), beam evaluations per second; and bench-gpu's table.
#
# The full check refuses a software adapter (lavapipe, llvmpipe: their times say nothing
# about a GPU) unless ALLOW_SOFTWARE=1. Environment: OUT (default out/gpu_check), PPB
# (default target/release/ppb), GPU_TESTS: a prebuilt `tests/gpu.rs` binary (from `cargo test
# --release --test gpu --no-run`). With GPU_TESTS set, step 1 is skipped and step 2 runs that
# binary: the lent machine has no Rust, so both binaries are built here and carried.
set -uo pipefail
cd "$(dirname "$0")/.."

QUICK=0
case "${1:-}" in
  --quick) QUICK=1 ;;
  "") ;;
  -h | --help) sed -n '2,31p' "$0"; exit 0 ;;
  *) echo "gpu_check: unknown argument $1 (--quick or nothing)" >&2; exit 2 ;;
esac
OUT=${OUT:-out/gpu_check}
PPB=${PPB:-target/release/ppb}
mkdir -p "$OUT"
# Mesa and wgpu want a private runtime directory; without one Mesa prints errors.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d)
  export XDG_RUNTIME_DIR
fi

if [ "$QUICK" = 1 ]; then
  SIZE=64x64 PATHS=4000 PASSES=4 BENCH=(--size 64x64 --passes 2 --light-paths 4000)
else
  SIZE=512x512 PATHS=100000 PASSES=128 BENCH=(--passes 4)
fi
FAILED=()
START=$SECONDS

# Runs a named step, its output in $OUT/<name>.log; a failure is recorded, not fatal.
step() {
  local name=$1
  shift
  local t0=$SECONDS
  echo "gpu_check: $name ..." >&2
  if "$@" >"$OUT/$name.log" 2>&1; then
    echo "gpu_check: $name ok ($((SECONDS - t0)) s)" >&2
  else
    echo "gpu_check: $name FAILED ($((SECONDS - t0)) s), see $OUT/$name.log:" >&2
    tail -n 15 "$OUT/$name.log" | sed 's/^/  | /' >&2
    FAILED+=("$name")
  fi
}

if [ -n "${GPU_TESTS:-}" ]; then
  step gpu-tests env PPB_REQUIRE_GPU=1 "$GPU_TESTS"
else
  step build cargo build --release
  step gpu-tests env PPB_REQUIRE_GPU=1 cargo test --release --test gpu
fi

SCENES=(scenes/conformance/smoke-grid/scene.toml scenes/bench/dense-smoke/scene.toml)
# Runs per scene. The quick check leaves out the dense smoke with transmittance tracked on
# the GPU: a fragment's ratio tracking through it exceeds a software adapter's loop limit
# (lavapipe ends an invocation's loops after 65,535 iterations), which ppb reports as an
# error rather than render wrong sums.
runs_for() {
  if [ "$QUICK" = 1 ] && [ "$1" = dense-smoke ]; then
    echo gpu gpu-gather cpu
  else
    echo gpu gpu-gather gpu-track cpu
  fi
}
for scene in "${SCENES[@]}"; do
  name=$(basename "$(dirname "$scene")")
  read -r -a RUNS <<<"$(runs_for "$name")"
  for run in "${RUNS[@]}"; do
    case $run in
      gpu) device=(--device gpu --gpu-primary auto) ;;
      gpu-gather) device=(--device gpu --gpu-primary gather) ;;
      gpu-track) device=(--device gpu --gpu-primary auto --gpu-tr track) ;;
      cpu) device=(--device cpu) ;;
    esac
    step "paper-$name-$run" "$PPB" render "$scene" --method ppb "${device[@]}" \
      --size "$SIZE" --light-paths "$PATHS" --passes "$PASSES" --quiet \
      --stats "$OUT/paper-$name-$run.json" -o "$OUT/paper-$name-$run.exr"
  done
  for run in "${RUNS[@]}"; do
    [ "$run" = cpu ] && continue
    step "compare-$name-$run" "$PPB" compare "$OUT/paper-$name-$run.exr" "$OUT/paper-$name-cpu.exr"
  done
done

TUBE=scenes/conformance/cloud-hg/scene.toml
for run in gpu cpu; do
  case $run in
    gpu) device=(--device gpu --gpu-primary raster) ;;
    cpu) device=(--device cpu) ;;
  esac
  step "tube-cloud-hg-$run" "$PPB" render "$TUBE" "${device[@]}" \
    --size "$SIZE" --light-paths "$PATHS" --passes "$PASSES" --quiet \
    --stats "$OUT/tube-cloud-hg-$run.json" -o "$OUT/tube-cloud-hg-$run.exr"
done
step compare-tube-cloud-hg "$PPB" compare "$OUT/tube-cloud-hg-gpu.exr" "$OUT/tube-cloud-hg-cpu.exr"

PUBLIC=()
for s in fog-box smoke-grid cloud-hg glass-caustic; do PUBLIC+=("scenes/conformance/$s/scene.toml"); done
step bench-gpu "$PPB" bench-gpu "${PUBLIC[@]}" --device gpu "${BENCH[@]}"

python3 - "$OUT" "$QUICK" "${SCENES[@]}" <<'EOF' || FAILED+=(summary)
import json, os, re, sys
out, quick, scenes = sys.argv[1], sys.argv[2] == "1", sys.argv[3:]
ok = True
adapter = None
print()
print(f"{'scene':<12} {'primary':<7} {'tr':<6} {'size':>8} {'paths':>7} {'passes':>6} {'CPU ms/pass':>12} {'GPU ms/pass':>12} "
      f"{'CPU/GPU':>8} {'rel_l1 GPU-CPU':>15} {'GPU est s':>10} {'overlap s':>10} {'wait s':>8} "
      f"{'upload s':>9} {'beam evals/s':>13}")
for scene in scenes:
    name = os.path.basename(os.path.dirname(scene))
    runs = {}
    for run in ("gpu", "gpu-gather", "gpu-track", "cpu"):
        try:
            with open(f"{out}/paper-{name}-{run}.json") as f:
                runs[run] = json.load(f)
        except (OSError, ValueError):
            runs[run] = None
    c = runs["cpu"]
    ms = lambda r: 1e3 * r["seconds"]["total"] / max(r["passes"], 1)
    for run in ("gpu", "gpu-gather", "gpu-track"):
        g = runs[run]
        if quick and name == "dense-smoke" and run == "gpu-track":
            continue  # not run in the quick check (runs_for)
        if not g or not c:
            print(f"{name:<12} (missing stats: see {out}/paper-{name}-*.log)")
            ok = False
            continue
        adapter = g.get("device")
        rel = "n/a"
        try:
            text = open(f"{out}/compare-{name}-{run}.log").read()
            m = re.search(r"^rel_l1\s+([0-9.eE+-]+)", text, re.M)
            rel = m.group(1) if m else "n/a"
        except OSError:
            pass
        gpu = g.get("gpu") or {}
        est = gpu.get("estimate_seconds", 0.0)
        evals = gpu.get("beam_evaluations", 0) / est if est > 0 else 0.0
        print(f"{name:<12} {gpu.get('primary') or '?':<7} {gpu.get('camera_tr') or '?':<6} "
              f"{g['width']}x{g['height']:<4} "
              f"{g['light_paths']:>7} {g['passes']:>6} "
              f"{ms(c):>12.1f} {ms(g):>12.1f} {ms(c) / max(ms(g), 1e-9):>8.2f} {rel:>15} "
              f"{est:>10.2f} {gpu.get('overlap_seconds', 0):>10.2f} {gpu.get('wait_seconds', 0):>8.2f} "
              f"{gpu.get('upload_seconds', 0):>9.2f} {evals:>13.3g}")
print(f"(ms/pass = the render's total wall time / passes, scene load and octree included; "
      f"GPU est = beam estimate on the device; overlap = its time hidden behind the next "
      f"pass's light tracing; wait = the CPU waiting for it)")
print(f"adapter: {adapter}")
try:
    t = {run: json.load(open(f"{out}/tube-cloud-hg-{run}.json")) for run in ("gpu", "cpu")}
    m = re.search(r"^rel_l1\s+([0-9.eE+-]+)", open(f"{out}/compare-tube-cloud-hg.log").read(), re.M)
    ms = {k: 1e3 * v["seconds"]["total"] / max(v["passes"], 1) for k, v in t.items()}
    print(f"tube kernel, cloud-hg ({t['gpu']['beam_kernel']} on the GPU, {t['cpu']['beam_kernel']} "
          f"on the CPU): {ms['cpu']:.1f} ms/pass on the CPU, {ms['gpu']:.1f} on the GPU, "
          f"rel_l1 GPU-CPU {m.group(1) if m else 'n/a'}")
except (OSError, ValueError, KeyError):
    print(f"tube kernel: missing stats, see {out}/tube-cloud-hg-*.log")
    ok = False
if adapter and "(Cpu)" in adapter and not quick and os.environ.get("ALLOW_SOFTWARE") != "1":
    print("gpu_check: the adapter is a software rasterizer; its times say nothing about a GPU "
          "(ALLOW_SOFTWARE=1 to accept)")
    ok = False
print()
try:
    print(open(f"{out}/bench-gpu.log").read().rstrip())
except OSError:
    ok = False
sys.exit(0 if ok else 1)
EOF

echo
if [ ${#FAILED[@]} -gt 0 ]; then
  echo "gpu_check: FAILED: ${FAILED[*]} ($((SECONDS - START)) s)" >&2
  exit 1
fi
echo "gpu_check: all steps passed ($((SECONDS - START)) s)" >&2
