#!/usr/bin/env bash
# Packs what benchmarks/gpu_check.sh needs on a lent GPU machine (benchmarks/gpu_check.md says how to use it).
#
#   benchmarks/gpu_pack.sh            # after ./dev.sh install; writes .gpu/ (git-ignored)
#   benchmarks/gpu_pack.sh --kcache   # after a change to Warp kernels: the kernel cache alone, .gpu/kcache
#
# The device machine has Python 3.12, CUDA, NumPy, SciPy, Matplotlib, pytest, but no package registry and none of
# jiggle's other dependencies. This script, here:
#   1. downloads the cp312 manylinux wheels of those dependencies, at the versions of this checkout's .venv;
#   2. installs them into .gpu/site (pip --target for Python 3.12), keeping of VTK only the modules a bake loads
#      (pyvista's flying edges build the generated bodies: 247 MB of VTK's 600 MB);
#   3. fills a Warp kernel cache, .gpu/kcache: a CPU bake of every check case compiles the CPU kernels here, and
#      every module it loaded is compiled ahead of time for sm_90 (H100 / H200) with Warp's own NVRTC, so the
#      device spends its minutes measuring, not compiling (a module that misses the cache compiles there as usual);
#   4. copies the shared assets the check uses into .gpu/assets;
#   5. puts site + kcache in one tar.xz cut into parts of at most 55 MiB, .gpu/parts/p00, p01, ...: a call to the
#      device may send 64 MiB in all, the working tree (~6 MB) included, so the parts go over consecutive calls.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
PY=$ROOT/.venv/bin/python
GPU=$ROOT/.gpu
ASSETS=${JIGGLE_ASSETS:-$ROOT/../shared/assets}
[ -x "$PY" ] || { echo "gpu_pack: $PY not found; run ./dev.sh install first" >&2; exit 2; }

kcache() {
  # the kernel cache: CPU objects from a CPU run of the check's bakes, sm_90 cubins ahead of time
  rm -rf "$GPU/kcache"
  WARP_CACHE_PATH=$GPU/kcache JIGGLE_ASSETS=$GPU/assets OPENBLAS_NUM_THREADS=1 \
    "$PY" benchmarks/gpu_check.py "$GPU/precompile" --precompile 90
  echo "gpu_pack: kernel cache $(du -sh "$GPU/kcache" | cut -f1)"
}
if [ "${1:-}" = "--kcache" ]; then
  # after a change to the kernels: only the cache, carried on its own (.gpu/kcache, ~6 MB) next to the old parts
  kcache
  exit 0
fi

# what a bake, the tests and `jiggle batch` import that the device's image lacks (its own list: KINDS.md)
PKGS="warp-lang mujoco mujoco-core glfw pyopengl trimesh embreex pyvista pyvista-validation vtk scooby pooch
      platformdirs pygltflib dataclasses-json marshmallow deprecated usd-core defusedxml dask distributed tornado
      tblib zict locket partd"
mkdir -p "$GPU/whl"
FREEZE=$("$PY" -m pip freeze)
PLAT="--platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux_2_24_x86_64
      --platform manylinux_2_27_x86_64 --platform manylinux_2_28_x86_64 --platform manylinux_2_31_x86_64
      --platform manylinux_2_34_x86_64 --platform manylinux1_x86_64"
REQS=()
for p in $PKGS; do
  v=$(echo "$FREEZE" | grep -i -E "^${p//-/[-_]}==" | head -1 | cut -d= -f3)
  [ -n "$v" ] || { echo "gpu_pack: $p is not installed in .venv" >&2; exit 2; }
  REQS+=("$p==$v")
done
echo "gpu_pack: wheels for ${REQS[*]}"
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $PLAT -d "$GPU/whl" \
  "${REQS[@]}" 2>&1 | grep -v "^WARNING: Location" || true
rm -rf "$GPU/site" && mkdir -p "$GPU/site"
"$PY" -m pip install -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $PLAT \
  --target "$GPU/site" --no-compile "${REQS[@]}" --find-links "$GPU/whl" --no-index 2>&1 | grep -v "^WARNING: Location" || true
[ -d "$GPU/site/warp" ] && [ -d "$GPU/site/vtkmodules" ] || { echo "gpu_pack: the install into .gpu/site failed" >&2; exit 1; }

# VTK: the modules a bake loads (found with /proc/self/maps after a bake of the demo body), the Python files all
"$PY" - "$GPU/site/vtkmodules" <<'PYEOF'
import os, re, sys
keep = set("""CommonCache CommonComputationalGeometry CommonCore CommonDataModel CommonExecutionModel CommonMath
    CommonMisc CommonSystem CommonTransforms FiltersCellGrid FiltersCore FiltersGeneral FiltersGeometry FiltersReduction
    FiltersSources FiltersVerdict IOCellGrid IOCore IOLegacy ImagingCore ImagingSources ParallelCore WrappingPythonCore
    fmt kissfft loguru lz4 lzma pugixml scn sys token verdict zlib""".split())
folder = sys.argv[1]
for f in os.listdir(folder):
    m = re.match(r"(?:lib)?(?:vtk|viskores)([A-Za-z0-9_]+?)(?:3\.\d+)?(?:-[\d.]+)?(?:\.cpython-[^.]+)?\.so", f)
    if m and m.group(1) not in keep:
        os.remove(os.path.join(folder, f))
PYEOF
rm -rf "$GPU/site/bin" "$GPU/site/vtkmodules/web" "$GPU/site/vtkmodules/qt" "$GPU/site/vtkmodules/tk"
echo "gpu_pack: site $(du -sh "$GPU/site" | cut -f1)"

# assets the check bakes
mkdir -p "$GPU/assets/characters" "$GPU/assets/mocap/cmu_bvh"
for f in characters/CesiumMan.glb mocap/cmu_bvh/02_03.bvh mocap/cmu_bvh/05_02.bvh; do
  if [ -f "$ASSETS/$f" ]; then cp "$ASSETS/$f" "$GPU/assets/$f"; else echo "gpu_pack: $ASSETS/$f missing: the check skips it"; fi
done

kcache

rm -rf "$GPU/parts" && mkdir -p "$GPU/parts"
tar -C "$GPU" -cf - site kcache | xz -T0 -6 | split -b 55M -d - "$GPU/parts/p"
ls -la "$GPU/parts"
echo "gpu_pack: send each part in its own device call, then run benchmarks/gpu_check.sh (benchmarks/gpu_check.md)"
