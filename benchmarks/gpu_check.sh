#!/usr/bin/env bash
# On a lent GPU machine (benchmarks/gpu_check.md): unpack the parts benchmarks/gpu_pack.sh made and that earlier
# device calls left in /tmp/jiggle_parts (or that are in .gpu/parts), then run benchmarks/gpu_check.py.
#
#   benchmarks/gpu_check.sh OUT [gpu_check.py options...]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: benchmarks/gpu_check.sh OUT [options]}; shift
PARTS=/tmp/jiggle_parts
SITE=/tmp/jiggle_gpu
mkdir -p "$PARTS"
[ -d .gpu/parts ] && cp -n .gpu/parts/p* "$PARTS"/ 2>/dev/null || true
if [ ! -d "$SITE/site" ]; then
  ls "$PARTS"/p* >/dev/null 2>&1 || { echo "gpu_check: no parts in $PARTS or .gpu/parts (benchmarks/gpu_check.md)" >&2; exit 2; }
  mkdir -p "$SITE"
  t=$SECONDS
  cat "$PARTS"/p* | xz -d -T0 | tar -x -C "$SITE"
  echo "gpu_check: unpacked $(du -sh "$SITE" | cut -f1) in $((SECONDS - t)) s"
fi
# a kernel cache carried on its own (.gpu/kcache, gpu_pack.sh --kcache) is newer than the one in the parts
if [ -d .gpu/kcache ]; then mkdir -p "$SITE/kcache" && cp -r .gpu/kcache/. "$SITE/kcache/"; fi
export PYTHONPATH=$SITE/site:$PWD${PYTHONPATH:+:$PYTHONPATH}
export WARP_CACHE_PATH=$SITE/kcache
export JIGGLE_ASSETS=${JIGGLE_ASSETS:-$PWD/.gpu/assets}
# the check renders nothing, and the machine has no libEGL (MuJoCo would load it at import)
export MUJOCO_GL=disable PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1
PY=${PYTHON:-python3}
"$PY" -c "import warp, mujoco, pxr, pyvista, embreex, trimesh, pygltflib; print('gpu_check: imports ok, warp', warp.__version__)"
"$PY" benchmarks/gpu_check.py "$OUT" "$@"
