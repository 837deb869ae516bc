#!/usr/bin/env bash
# Hashes of every output file (report.json aside: it holds timings) of a fixed set of conversions:
# the sample and every shared model with the default options, two models with non-default options,
# textures on, and a sharded build. A refactor that must not change the output compares this
# script's output before and after:  tools/output_hashes.sh BIN OUTDIR > hashes.txt
set -euo pipefail
BIN=${1:?usage: output_hashes.sh BIN OUTDIR}
OUT=${2:?usage: output_hashes.sh BIN OUTDIR}
DATA=${BIMTILES_SHARED:-$(dirname "$0")/../../shared}/data
rm -rf "$OUT"; mkdir -p "$OUT"
run() { local name=$1; shift; "$BIN" convert "$@" --out "$OUT/$name" --quiet; }
run sample samples/sample_building.glb --max-tile-triangles 4000
for f in "$DATA"/*.glb "$DATA"/*.ifc; do
  run "$(basename "$f")" "$f"
done
run mini-options "$DATA/ISSUE_021_Mini_Project.glb" --compression none --max-tile-triangles 5000 \
  --lod-ratios 0.5,0.25 --dedup-tolerance-m 0.002
run railway-atlas "$DATA/LoD3_Railway.glb" --max-tile-triangles 3000 --texture-atlas on --embed-textures \
  --compression quantized
run airport-paper "$DATA/phnl_honolulu_airport.glb" --max-tile-triangles 8000 --error-metric paper-sse \
  --coarse-properties all --texture-format jpeg
run fzk-none "$DATA/AC20-FZK-Haus.ifc" --lod none --no-instancing
"$BIN" plan "$DATA/ISSUE_021_Mini_Project.glb" "$DATA/duplex.glb" --out "$OUT/sharded" --jobs 3 --max-tile-triangles 5000 --quiet >/dev/null
for j in 2 0 1; do "$BIN" build-job "$OUT/sharded" --job $j --quiet >/dev/null; done
"$BIN" merge "$OUT/sharded" --quiet >/dev/null
cd "$OUT"
find . -type f ! -name report.json ! -path '*/jobs/*' ! -name plan.json -print0 | sort -z | xargs -0 sha256sum
