#!/usr/bin/env bash
# View-layer renders (`layers.exr`: Foreground and Background, each with Combined, Depth and
# Vector) of a scene of bench/cycles/scenes.py or a shared example's, made with Blender 3.4 by
# blender_layers.py beside what cycles_frames.sh makes (input.exr, reference.exr, camera.json).
#
#   bench/cycles/cycles_layers.sh OUT SCENE [RES] [PREFIXES]
#
# PREFIXES (comma-separated) name the foreground objects by their materials' names; each scene
# below has its own. About 30 s at 512 x 512 on 2 cores.
set -euo pipefail
OUT=$1; SCENE=$2; RES=${3:-512}
HERE=$(cd "$(dirname "$0")" && pwd)
TOOLS=${SHARED_TOOLS:-$HERE/../../../shared/tools}
[ -f "$TOOLS/blender_refs.py" ] || { echo "cycles_layers: no $TOOLS/blender_refs.py (set SHARED_TOOLS)" >&2; exit 1; }
case $SCENE in
    fence) DEFAULT=bar ;;
    comets) DEFAULT=comet ;;
    street) DEFAULT=car,lamp,pillar,ball ;;
    lights) DEFAULT=cube,ball ;;
    disc) DEFAULT=disc ;;
    pan) DEFAULT=post,ball,lamp0 ;;
    *) DEFAULT="" ;;
esac
PREFIXES=${4:-$DEFAULT}
[ -n "$PREFIXES" ] || { echo "cycles_layers: name the foreground's material prefixes for $SCENE" >&2; exit 1; }
blender -b -noaudio --python "$HERE/blender_layers.py" -- "$OUT" "$SCENE" --tools "$TOOLS" \
    --scenes "$HERE/scenes.py" --foreground "$PREFIXES" --res "$RES" --spp 64 | grep -v '^Fra:'
