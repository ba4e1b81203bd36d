#!/usr/bin/env bash
# The main job end to end on the bundled volume: install what is missing, build, extract a corner-patch model from
# data/blobs.nrrd, and render it to an EXR with a PNG preview. Outputs go to build/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh build
out=build/demo
mkdir -p "$out"
build/extract/extract data/blobs.nrrd --iso 128 -o "$out/blobs.cip" --mc-mesh "$out/blobs-mc.ply" \
  --stats-json "$out/extract.json"
build/raycast/raycast "$out/blobs.cip" -o "$out/blobs.exr" --png "$out/blobs.png" --size 800x600 \
  --stats-json "$out/raycast.json"
echo "wrote $out/blobs.cip, $out/blobs-mc.ply, $out/blobs.exr and $out/blobs.png"
