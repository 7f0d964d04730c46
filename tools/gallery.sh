#!/usr/bin/env bash
# The paper's figures, rendered: every scenes/paper/*/scene.toml at full resolution.
#
#   tools/gallery.sh                 # all scenes -> docs/gallery/<figure>.png + table.md
#   tools/gallery.sh fig15-fractal-cloud fig19-sunset-cloud   # only these (their table rows)
#   tools/gallery.sh --table1        # the paper's Table 1 on these scenes -> table1.md
#
# Each scene renders with the passes and light paths of SETTINGS below, chosen so that a
# scene takes 1-5 minutes on the 2-core machine of table.md; a scene missing there renders
# with its own [render] settings. EXRs (and the PNG previews) go to out/gallery/ (ignored
# by git); the PNGs are copied to docs/gallery/. Wall time is the render's own
# `seconds.total` from `--stats` (scene load and octree build included).
#
# --table1 runs `ppb bench --method ppb` (the paper's pure method) on the scenes of the
# paper's Table 1 and the other paper scenes (fig03 at frame 32 of its VDB sequence), at
# full resolution and each scene's own light
# paths, and writes docs/gallery/table1.md. Set T1_PASSES / T1_REPEAT to change its work
# (defaults 4 passes, 3 interleaved runs per sampler).
#
# Environment: PPB (the binary, default target/release/ppb, built if missing), DEVICE
# (--device, default cpu: the table's times are CPU times), OUT and DOCS (the folders),
# QUICK=1 (a smoke test: 64x64, 2 passes of 2,000 light paths; point DOCS elsewhere).
set -euo pipefail
cd "$(dirname "$0")/.."

PPB=${PPB:-target/release/ppb}
DEVICE=${DEVICE:-cpu}
OUT=${OUT:-out/gallery}
DOCS=${DOCS:-docs/gallery}

# figure                        passes  light paths  extra render arguments
SETTINGS="
fig03-smoke-plume               384     100000       --frames 32
fig13a-smoke-low-density        256     100000
fig13b-smoke-high-density       256     100000
fig14-smoke-glass-sphere        112     50000
fig15-fractal-cloud             80      100000
fig16-cirrocumulus              160     100000
fig17-glass-rgb-caustics        96      10000
fig18-light-shafts              72      30000
fig19-sunset-cloud              128     50000
"

# The paper's Table 1 (seconds; PPB = Woodcock, OM = adaptive + its transmittance
# estimator): figure -> "total PPB / OM / ratio; FPS PPB / OM / ratio".
paper_row() {
  case "$1" in
    fig13a-*) echo "280 / 125 / 2.2 | 220 / 65 / 3.4" ;;
    fig13b-*) echo "1718 / 131 / 13.1 | 1659 / 72 / 23.0" ;;
    fig14-*) echo "1707 / 501 / 3.4 | 1447 / 239 / 6.1" ;;
    fig15-*) echo "219 / 127 / 1.7 | 159 / 67 / 2.4" ;;
    fig16-*) echo "2243 / 262 / 8.6 | 2161 / 181 / 11.9" ;;
    *) echo "- | -" ;;
  esac
}

settings_of() { # figure -> "passes lightpaths extra..." or empty
  awk -v f="$1" '$1 == f { $1 = ""; print; exit }' <<<"$SETTINGS"
}

machine() {
  local model
  model=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')
  echo "$(nproc) cores, ${model:-unknown CPU}"
}

ensure_binary() {
  if [ ! -x "$PPB" ]; then
    echo "gallery: building $PPB" >&2
    cargo build --release
  fi
}

json_field() { # file expr
  python3 -c "import json,sys; s=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$1" "$2"
}

table1() {
  ensure_binary
  mkdir -p "$DOCS"
  local scenes=() names=() f
  for f in scenes/paper/*/scene.toml; do
    scenes+=("$f")
  done
  local passes=${T1_PASSES:-4} repeat=${T1_REPEAT:-3} log=$OUT/table1.log
  mkdir -p "$OUT"
  echo "gallery: ppb bench --method ppb --passes $passes --repeat $repeat on ${#scenes[@]} scenes" >&2
  local start=$SECONDS
  # --frame 32: fig03's VDB sequence frame, as in the gallery; the other scenes have none.
  "$PPB" bench "${scenes[@]}" --method ppb --passes "$passes" --repeat "$repeat" --frame 32 | tee "$log"
  local took=$((SECONDS - start))
  {
    echo "# The paper's Table 1 on the paper scenes"
    echo
    echo "\`tools/gallery.sh --table1\`: \`ppb bench scenes/paper/*/scene.toml --method ppb --passes $passes"
    echo "--repeat $repeat --frame 32\` (the paper's pure method: all light through beams and photons), full"
    echo "resolution, each scene's own light paths per pass ([render].light_paths), Woodcock"
    echo "tracking (the paper's PPB) against adaptive free-path sampling (OM), each run $repeat times"
    echo "interleaved; the table shows each sampler's median run. FPS = free-path sampling,"
    echo "camera transmittance included, in thread-seconds / threads; lookups / free path is"
    echo "machine independent; fig03 is frame 32 of its VDB sequence. Machine: $(machine);"
    echo "$(date -u +%Y-%m-%d), $took s in all."
    echo
    echo "| scene | FPS Woodcock (s) | FPS adaptive (s) | FPS ratio (range) | total Woodcock (s) | total adaptive (s) | total ratio | lookups / free path W | A | ratio | paper: total PPB / OM / ratio | paper: FPS PPB / OM / ratio |"
    echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    awk 'NR > 1 && NF == 11 && $1 != "scene" { print }' "$log" | while read -r name fw fa r range tw ta tr lw la lr; do
      echo "| $name | $fw | $fa | $r ($range) | $tw | $ta | $tr | $lw | $la | $lr | $(paper_row "$name") |"
    done
    echo
    echo "Paper (6-core i7 980 + GTX 580, 128-256 passes of 100k-200k beams): total and FPS"
    echo "seconds of the whole render; ours are seconds of $passes passes, so compare the ratios."
    echo "Rates per thread-second (from the bench's second table):"
    echo
    echo '```'
    sed -n '/sampler   free paths/,$p' "$log"
    echo '```'
  } >"$DOCS/table1.md"
  echo "gallery: wrote $DOCS/table1.md" >&2
}

gallery() {
  ensure_binary
  mkdir -p "$OUT" "$DOCS"
  local figures=("$@") f
  if [ ${#figures[@]} -eq 0 ]; then
    for f in scenes/paper/*/scene.toml; do figures+=("$(basename "$(dirname "$f")")"); done
  fi
  local rows=() name s passes paths extra scene stats
  for name in "${figures[@]}"; do
    scene=scenes/paper/$name/scene.toml
    [ -f "$scene" ] || { echo "gallery: no $scene" >&2; exit 2; }
    s=$(settings_of "$name")
    args=()
    if [ -n "$s" ]; then
      read -r passes paths extra <<<"$s"
      [ "${QUICK:-0}" = 1 ] && { passes=2 paths=2000 extra="${extra:-} --size 64x64"; }
      args=(--passes "$passes" --light-paths "$paths")
      # shellcheck disable=SC2206
      [ -n "${extra:-}" ] && args+=($extra)
    else
      echo "gallery: $name has no SETTINGS row: its own [render] settings" >&2
    fi
    stats=$OUT/$name.json
    echo "gallery: $name ${args[*]}" >&2
    "$PPB" render "$scene" -o "$OUT/$name.exr" --stats "$stats" --device "$DEVICE" \
      --progress bar "${args[@]}"
    cp "$OUT/$name.png" "$DOCS/$name.png"
    rows+=("$(python3 - "$stats" "$name" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
name = sys.argv[2]
print(f"| {name} | {s['width']}x{s['height']} | {s['passes']} | {s['light_paths']:,} | "
      f"{s['method']} | {s['device']} | {s['seconds']['total']:.1f} | ![{name}]({name}.png) |")
PY
)")
  done
  {
    echo "# Gallery: the paper's figures"
    echo
    echo "\`tools/gallery.sh\` rendered every \`scenes/paper/*/scene.toml\` (what each shows: the"
    echo "comment at the top of the scene). Machine: $(machine); $(date -u +%Y-%m-%d)."
    echo "Wall time: the render's \`seconds.total\` from \`--stats\` (scene load and octree"
    echo "build included)."
    echo
    echo "| figure | resolution | passes | light paths / pass | method | device | wall time (s) | image |"
    echo "| --- | --- | --- | --- | --- | --- | --- | --- |"
    # Rows of figures not rendered this time stay as they were.
    {
      [ -f "$DOCS/table.md" ] && grep '^| fig[0-9]' "$DOCS/table.md" | while IFS= read -r row; do
        name=$(cut -d'|' -f2 <<<"$row" | tr -d ' ')
        [[ " ${figures[*]} " == *" $name "* ]] || printf '%s\n' "$row"
      done
      printf '%s\n' "${rows[@]}"
    } | sort
  } >"$DOCS/table.md.tmp"
  mv "$DOCS/table.md.tmp" "$DOCS/table.md"
  echo "gallery: wrote $DOCS/table.md" >&2
}

case "${1:-}" in
  --table1) table1 ;;
  -h | --help) sed -n '2,26p' "$0" | sed 's/^# \{0,1\}//' ;;
  *) gallery "$@" ;;
esac
