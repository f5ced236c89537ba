#!/usr/bin/env bash
# Packs the Blender add-on into a zip that Blender installs (Edit > Preferences > Add-ons >
# Install...): scripts/package-blender-addon.sh [OUT.zip]  (default out/spreadlet_blender.zip)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out/spreadlet_blender.zip}"
mkdir -p "$(dirname "$out")"
out="$(cd "$(dirname "$out")" && pwd)/$(basename "$out")"
rm -f "$out"
(cd blender && python3 -c '
import sys, zipfile, pathlib
with zipfile.ZipFile(sys.argv[1], "w", zipfile.ZIP_DEFLATED) as z:
    for p in sorted(pathlib.Path("spreadlet_blender").rglob("*.py")):
        z.write(p)
' "$out")
echo "wrote $out"
