#!/usr/bin/env bash
# The Mitsuba twin of a scene folder: the same folder, its training photos rendered again by
# Mitsuba 3 from the exported ground truth with fipt's BRDF (`fipt_bsdf.py`), max_depth 7 and a
# box filter, as the reference scenes were. A run on the twin against a run on the folder says
# what fipt's results owe to the path tracer that rendered the photos. The val photos and the
# relighting set stay as they are. OUT/twin.json holds Mitsuba's renders scored against the
# folder's photos (`render_export.py`).
#
#   twin.sh SCENE OUT [SPP]        (SPP default 512)
#
# FIPT: the fipt-train binary (default target/release/fipt-train); PYTHON: a Python with
# Mitsuba 3.9.1 (default ~/.cache/fipt-tools/mitsuba/bin/python, which `bash .ci/test` installs).
set -euo pipefail
[ $# -ge 2 ] || { sed -n 2,13p "$0" >&2; exit 2; }
here=$(cd "$(dirname "$0")" && pwd)
scene=$(cd "$1" && pwd)
out=$2
spp=${3:-512}
fipt=${FIPT:-$here/../../target/release/fipt-train}
python=${PYTHON:-$HOME/.cache/fipt-tools/mitsuba/bin/python}
llvm=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
[ -f "$scene/train/transforms.json" ] || { echo "$scene: no train/transforms.json" >&2; exit 1; }
[ ! -e "$out" ] || { echo "$out: exists" >&2; exit 1; }
work=$(mktemp -d "${out%/}.tmp.XXXXXX")
trap 'rm -rf "$work"' EXIT
"$fipt" export --truth --scene "$scene" --split train --format mitsuba --out "$work/export" \
    --texels 4096 >/dev/null
variant=scalar_rgb
if [ -f "$llvm" ]; then variant=llvm_ad_rgb; export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-$llvm}; fi
"$python" "$here/render_export.py" "$work/export/scene.xml" --out "$work/render" --spp "$spp" \
    --variant "$variant" --bsdf fipt --reference "$scene/train/Image" >"$work/twin.json"
# The twin: the scene's files linked (copied across file systems), the photos replaced.
cp -al "$scene" "$work/twin" 2>/dev/null || { rm -rf "$work/twin"; cp -a "$scene" "$work/twin"; }
rm -rf "$work/twin/train/Image/"*.exr "$work/twin/train/Image/preview"
for f in "$work/render/"*.exr; do
    cp "$f" "$work/twin/train/Image/$(basename "$f" .exr)_0001.exr"
done
mv "$work/twin.json" "$work/twin/twin.json"
mv "$work/twin" "$out"
echo "$out: $(ls "$work/render" | wc -l) training photos rendered by Mitsuba ($variant, $spp spp)"
