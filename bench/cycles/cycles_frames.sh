#!/usr/bin/env bash
# Cycles stochastic frames, their 2048-spp reference and the Cycles + OIDN peer for a scene of
# bench/cycles/scenes.py (or a shared example's scene), made with ../shared/tools exactly as
# ../shared/examples/comets/stochastic/README.md describes.
#
#   bench/cycles/cycles_frames.sh OUT SCENE [RES]
#
# OUT/SCENE/ gets reference.exr, input.exr, camera.json, stochastic_{1,4,16}spp.exr (4 Cycles
# paths per sample, guides included) and cycles_{4,16,64}spp{,_oidn}.exr, the peer at the same
# paths. Needs Blender 3.4 (`blender`), and a python3 with numpy, OpenEXR, scipy, scikit-image
# and pyoidn (PYTHON, default python3). About 15 minutes on 2 cores at 512 x 512.
set -euo pipefail
OUT=$1; SCENE=$2; RES=${3:-512}
PY=${PYTHON:-python3}
HERE=$(cd "$(dirname "$0")" && pwd)
TOOLS=${SHARED_TOOLS:-$HERE/../../../shared/tools}
[ -f "$TOOLS/blender_refs.py" ] || { echo "cycles_frames: no $TOOLS/blender_refs.py (set SHARED_TOOLS)" >&2; exit 1; }
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
cp "$TOOLS"/*.py "$WORK"/
# Our scenes join the builder's table; everything else is the shared tools as they are.
"$PY" - "$WORK/blender_refs.py" "$HERE/scenes.py" <<'PYEOF'
import sys
path, scenes = sys.argv[1], sys.argv[2]
s = open(path).read()
table = "\nSCENES = dict(fence=fence, comets=comets)"
if table not in s:
    raise SystemExit("cycles_frames: blender_refs.py has no scene table where it is expected")
s = s.replace(table, f"\nexec(open({scenes!r}).read())" + table + "\nSCENES.update(EXTRA_SCENES)")
open(path, "w").write(s)
PYEOF
mkdir -p "$OUT"
if [ ! -f "$OUT/$SCENE/reference.exr" ]; then
    blender -b -noaudio --python "$WORK/blender_refs.py" -- "$OUT" "$SCENE" --res "$RES" --spp 2048
fi
blender -b -noaudio --python "$WORK/blender_stochastic.py" -- "$OUT" "$SCENE" --res "$RES" \
    --subframes 64 --seed 1 --sub-spp 4 --spp 1,4,16 --keep 1,4,16 --averages 16 --guides \
    --peer 4,16,64 --work "$WORK/work/$SCENE" --python "$PY"
"$PY" "$WORK/oidn_peer.py" "$WORK/work/$SCENE" "$OUT/$SCENE"
echo "cycles_frames: $OUT/$SCENE"
