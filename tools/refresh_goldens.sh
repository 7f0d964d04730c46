#!/usr/bin/env bash
# Regenerates the golden renders of the paper scenes (tests/golden/<figure>.exr) and their
# measured noise and tolerances (tests/golden/tolerances.json), with the settings in
# tests/golden.rs: each scene is rendered with seeds 1 and 2; seed 1 becomes the golden,
# the rel_l1 of 8x8 block means between the two is the noise n, and the tolerance is 3 n.
#
#   tools/refresh_goldens.sh            # then review `git diff --stat` and commit
#
# Refuses to run (exit 1) unless `git status --porcelain` is empty: the goldens must come
# from a committed renderer and committed scenes, so the commit that updates them says
# exactly what they were rendered from.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ -n "$(git status --porcelain)" ]; then
  echo "refresh_goldens: the work tree is not clean (git status --porcelain):" >&2
  git status --porcelain >&2
  echo "refresh_goldens: commit or remove those changes first; goldens must come from a committed tree" >&2
  exit 1
fi

# Goldens whose pixels come out the same keep their files (the EXR header holds dates).
rm -f tests/golden/tolerances.json
PPB_REFRESH_GOLDENS=1 cargo test --release --test golden -- --nocapture
# The goldens must pass as written.
cargo test --release --test golden
git status --short tests/golden
echo "refresh_goldens: done; commit tests/golden/ (rendered from $(git rev-parse --short HEAD))"
