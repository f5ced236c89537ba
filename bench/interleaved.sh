#!/usr/bin/env bash
# Interleaved per-call timing of two or more spreadlet binaries on one input: each round runs
# every binary once in turn (A B A B ...), so a change of the machine's load hits all alike.
# Prints each binary's median and range of `spreadlet synth --stats` synthesis.times.total_ms,
# or with --reconstruct, of `spreadlet reconstruct --stats` reconstruction.times.total_ms on
# stochastic frames.
#
#   bench/interleaved.sh [--reconstruct] ROUNDS G-BUFFER.exr|FRAMES.exr CAMERA.json BINARY...
set -euo pipefail
command=synth section=synthesis
if [ "${1:-}" = "--reconstruct" ]; then
  command=reconstruct section=reconstruction
  shift
fi
if [ $# -lt 4 ]; then
  echo "usage: $0 [--reconstruct] ROUNDS G-BUFFER.exr|FRAMES.exr CAMERA.json BINARY..." >&2
  exit 2
fi
rounds=$1 gbuffer=$2 camera=$3
shift 3
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for ((r = 0; r < rounds; r++)); do
  k=0
  for bin in "$@"; do
    "$bin" "$command" --input "$gbuffer" --camera "$camera" --out "$work/out.exr" --backend cpu \
      --stats "$work/stats.json" -q
    python3 -c "import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]]['times']['total_ms'])" \
      "$work/stats.json" "$section" >> "$work/times.$k"
    k=$((k + 1))
  done
done
k=0
for bin in "$@"; do
  python3 - "$bin" "$work/times.$k" <<'PY'
import statistics, sys
times = sorted(float(line) for line in open(sys.argv[2]))
print(f"{sys.argv[1]}: median {statistics.median(times):.1f} ms "
      f"({times[0]:.1f}-{times[-1]:.1f}), {len(times)} rounds")
PY
  k=$((k + 1))
done
