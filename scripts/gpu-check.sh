#!/usr/bin/env bash
# The GPU path on a real GPU, in one short window: builds (release), runs the GPU tests with
# SPREADLET_REQUIRE_GPU=1, then `spreadlet bench --device-check` (micro-benchmarks of the
# device's limits; thin lens, lens+motion and motion only at 1024x1024, 1920x1080 and
# 3840x2160 with the tiled and the global-atomic splat, median of 10 after warm-up,
# configurations interleaved), writing device-check.json and device-check.md into OUT.
#
#   scripts/gpu-check.sh [--quick] [--skip-tests] OUT
#
# --quick: small sizes and few runs (to test this script on a software device such as
# lavapipe; the report marks a software device as such). Meant for a fresh machine with an
# NVIDIA GPU and the Rust toolchain; finishes in a few minutes including the build.
set -euo pipefail
cd "$(dirname "$0")/.."

quick=""
skip_tests=""
out=""
for a in "$@"; do
  case "$a" in
    --quick) quick="--quick" ;;
    --skip-tests) skip_tests=1 ;;
    -h|--help) sed -n 2,12p "$0"; exit 0 ;;
    -*) echo "gpu-check: unknown option $a" >&2; exit 2 ;;
    *) out="$a" ;;
  esac
done
if [ -z "$out" ]; then
  echo "usage: scripts/gpu-check.sh [--quick] [--skip-tests] OUT" >&2
  exit 2
fi
mkdir -p "$out"
out="$(cd "$out" && pwd)"
start=$(date +%s)
step() { echo "[gpu-check $(( $(date +%s) - start )) s] $*" >&2; }

# The Vulkan loader: a fresh container may lack it; the repository can carry it as .deb files.
if [ -z "$(ldconfig -p 2>/dev/null | grep libvulkan || true)" ]; then
  step "no libvulkan: unpacking .gl/*.deb"
  shopt -s nullglob
  debs=(.gl/*.deb)
  shopt -u nullglob
  if [ ${#debs[@]} -eq 0 ]; then
    echo "gpu-check: no libvulkan and no .gl/*.deb to unpack" >&2
  fi
  for f in "${debs[@]}"; do dpkg -x "$f" /; done
  ldconfig || true
fi
# A Vulkan driver: NVIDIA's manifest where the container toolkit puts it, unless the loader is
# told otherwise or the system has an NVIDIA manifest (a software one alone is not enough:
# the loader would pick lavapipe).
nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
have() { compgen -G "$1" >/dev/null; }
if [ -z "${VK_DRIVER_FILES:-}${VK_ICD_FILENAMES:-}" ]; then
  if ! have "/usr/share/vulkan/icd.d/nvidia*.json" && ! have "/etc/vulkan/icd.d/nvidia*.json" \
     && { [ -e "$nvidia_icd" ] || { ! have "/usr/share/vulkan/icd.d/*.json" && ! have "/etc/vulkan/icd.d/*.json"; }; }; then
    export VK_DRIVER_FILES="$nvidia_icd"
    step "VK_DRIVER_FILES=$VK_DRIVER_FILES"
  fi
fi
export SPREADLET_REQUIRE_GPU=1
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/spreadlet-xdg-$(id -u)"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
fi
export SPREADLET_CACHE="${SPREADLET_CACHE:-$PWD/target/spreadlet-cache}"
command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader >&2 || true

tests=()
for f in runtime/tests/gpu_*.rs; do tests+=(--test "$(basename "$f" .rs)"); done
step "building (release): spreadlet and $(( ${#tests[@]} / 2 )) GPU test binaries"
cargo build --release -p spreadlet-cli --bin spreadlet 2>&1 | tail -n 2 >&2
cargo test --release -p spreadlet --no-run "${tests[@]}" 2>&1 | tail -n 1 >&2

tests_failed=""
if [ -z "$skip_tests" ]; then
  step "GPU tests (SPREADLET_REQUIRE_GPU=1), log in $out/gpu-tests.log"
  if ! cargo test --release -p spreadlet --no-fail-fast "${tests[@]}" >"$out/gpu-tests.log" 2>&1; then
    tests_failed=1
  fi
  grep -E "^test result|^     Running|FAILED|panicked" "$out/gpu-tests.log" >&2 || true
fi

step "device check${quick:+ (quick)}"
target/release/spreadlet bench --device-check "$out" $quick
step "done: $out/device-check.json, $out/device-check.md"
grep -E "^Device:|^- " "$out/device-check.md" >&2 || true
if [ -n "$tests_failed" ]; then
  echo "gpu-check: GPU tests FAILED (see $out/gpu-tests.log)" >&2
  exit 1
fi
