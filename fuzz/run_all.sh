#!/bin/bash
# Runs each fuzz target in turn for SECS seconds (default 210) in fork mode, so a run
# goes on after a crash and collects every distinct one under artifacts/<target>/.
# Usage (from fuzz/): ./run_all.sh [SECS] [target...]
set -u
SECS=${1:-210}; shift || true
TARGETS=${*:-openvdb nanovdb octree_cache part exr gltf obj scene_toml usd}
BIN=${CARGO_TARGET_DIR:-target}/x86_64-unknown-linux-gnu/release
LOGS=${LOGS:-logs}
mkdir -p "$LOGS"
for t in $TARGETS; do
    mkdir -p corpus/$t artifacts/$t
    "$BIN/$t" corpus/$t -artifact_prefix=artifacts/$t/ -fork=1 -ignore_crashes=1 \
        -ignore_timeouts=1 -ignore_ooms=1 -max_total_time=$SECS -rss_limit_mb=4096 \
        -timeout=10 -print_final_stats=1 > "$LOGS/$t.log" 2>&1
    echo "$t done rc=$? $(grep -E '^#[0-9]+' "$LOGS/$t.log" | tail -1)"
done
