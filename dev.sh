#!/usr/bin/env bash
# jiggle's one entry point for a fresh machine (Debian, Python >= 3.11):
#   ./dev.sh demo [jiggle demo options]   install everything, run the built-in demo (writes out/demo/)
#   ./dev.sh test [pytest options]        install everything, run the whole test suite
#   ./dev.sh install                      install only
# Installs, when missing: the system GL libraries for headless rendering (as root, or via sudo -n),
# a virtual environment in .venv with jiggle (an editable install of this checkout) and its test extras. Re-installs when
# pyproject.toml or setup.py change, or when .venv's jiggle is not this checkout's; a module added under rig/, sim/ or
# scenes/ needs none: the links jiggle/rig, jiggle/sim, jiggle/scenes put the stage folders inside the package
# (docs/contributing.md), and dev.sh stops with what to do when a clone lacks them.
# Also, when Python 3.11 is present and JIGGLE_BLENDER is not 0: Blender as a Python module (the extra
# "blender" of pyproject.toml, for tests/character/test_blender.py) in its own environment .venv/blender,
# because the bpy wheels pin numpy < 2; and the X11 client libraries bpy loads.
# Unless JIGGLE_BROWSER=0: Debian's chromium and chromium-driver, which the test extras' selenium drives
# headless for tests/app/test_view.py (`jiggle view` in a real browser; skipped with a reason without them).
# Unless JIGGLE_JS=0: Node.js and npm, and in tests/js/node_modules the JavaScript clients the tests check
# jiggle's glTF files with (the Khronos glTF-Validator and three.js) and pyright, the type checker that
# tests/test_checkout.py runs over the checkout (all pinned in tests/js/package-lock.json).
set -euo pipefail
cd "$(dirname "$0")"

say() { printf 'dev.sh: %s\n' "$*" >&2; }
die() { say "$*"; exit 2; }

SYSTEM_PKGS=(libegl1 libgl1-mesa-dri libopengl0)
BLENDER_PKGS=(libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libsm6 libxxf86vm1 libgl1)

want_blender() { [ "${JIGGLE_BLENDER:-1}" != 0 ] && command -v python3.11 >/dev/null 2>&1; }
want_blender && SYSTEM_PKGS+=("${BLENDER_PKGS[@]}")
BROWSER_PKGS=(chromium chromium-driver)
[ "${JIGGLE_BROWSER:-1}" != 0 ] && SYSTEM_PKGS+=("${BROWSER_PKGS[@]}")
want_js() { [ "${JIGGLE_JS:-1}" != 0 ]; }
want_js && ! command -v npm >/dev/null 2>&1 && SYSTEM_PKGS+=(nodejs npm)

pick_python() {
  for py in "${PYTHON:-}" python3.11 python3.12 python3.13 python3; do
    [ -n "$py" ] || continue
    command -v "$py" >/dev/null 2>&1 || continue
    if "$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
      echo "$py"; return 0
    fi
  done
  return 1
}

apt_install() {
  local runner=()
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
      runner=(sudo -n)
    else
      die "missing system packages: $*. Run as root: apt-get update && apt-get install -y $*"
    fi
  fi
  say "installing system packages: $*"
  DEBIAN_FRONTEND=noninteractive "${runner[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${runner[@]}" apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}

system_deps() {
  command -v dpkg-query >/dev/null 2>&1 || { say "not a Debian system: make sure EGL and Mesa (${SYSTEM_PKGS[*]}) are installed"; return 0; }
  local missing=()
  for p in "${SYSTEM_PKGS[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  local py; py=$(pick_python) || true
  if [ -z "$py" ]; then
    missing+=(python3 python3-venv)
  elif ! "$py" -c 'import ensurepip, venv' 2>/dev/null; then
    missing+=("$(basename "$py")-venv")
  fi
  [ ${#missing[@]} -eq 0 ] || apt_install "${missing[@]}"
}

# The stage folders inside the package: jiggle/rig -> ../rig, jiggle/sim -> ../sim, jiggle/scenes -> ../scenes,
# committed links (a clone made with git's core.symlinks=false holds them as small text files instead).
check_links() {
  local top
  for top in rig sim scenes; do
    if [ ! -L "jiggle/$top" ] || [ "$(readlink "jiggle/$top")" != "../$top" ] || [ ! -d "jiggle/$top" ]; then
      die "jiggle/$top is not the link to ../$top that the checkout needs (a clone without symbolic links?): run" \
          "'git config core.symlinks true && rm -f jiggle/$top && git checkout -- jiggle/$top'"
    fi
  done
}

# Whether .venv's jiggle is this checkout's (an editable install of another folder, or a broken one, is not).
installed_here() {
  local py="$PWD/.venv/bin/python" at
  at=$(cd / && "$py" -c 'import jiggle, os; print(os.path.realpath(jiggle.__file__))' 2>/dev/null) || return 1
  [ "$at" = "$(realpath jiggle/__init__.py)" ]
}

# MyoSuite's musculoskeletal models, the reference benchmarks/activation_reference.py checks muscle activation
# against (tests/jiggle/test_activation_reference.py). Without its dependencies: it declares mujoco < 4, jiggle runs
# mujoco 4, and its XML models load and compile there as they are (it needs nothing else but numpy).
MYO_SIM="myo-sim==0.2.4"

install() {
  check_links
  system_deps
  local py; py=$(pick_python) || die "Python >= 3.11 not found (set PYTHON=/path/to/python3.11)"
  if [ ! -x .venv/bin/python ]; then
    say "creating .venv with $("$py" --version)"
    "$py" -m venv .venv
  fi
  local stamp=.venv/.jiggle-install hash
  hash=$( (cat pyproject.toml setup.py; echo "$MYO_SIM") | sha256sum | cut -d' ' -f1)
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$hash" ] || ! installed_here; then
    say "installing jiggle and its dependencies into .venv (a few minutes the first time)"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e '.[test]'
    .venv/bin/python -m pip install -q --no-deps "$MYO_SIM"
    echo "$hash" > "$stamp"
  fi
  want_blender && blender_env || true
  want_js && js_env || true
}

# The JavaScript clients of tests/js (npm ci from its lock file), again when the lock file changes.
js_env() {
  command -v npm >/dev/null 2>&1 || { say "npm not found; the glTF-Validator, three.js and pyright tests will be skipped"; return 0; }
  local stamp=tests/js/node_modules/.jiggle-install hash
  hash=$(sha256sum tests/js/package-lock.json | cut -d' ' -f1)
  [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$hash" ] && return 0
  say "installing the glTF-Validator, three.js and pyright into tests/js/node_modules"
  if (cd tests/js && npm ci --no-audit --no-fund --loglevel=error >/dev/null); then
    echo "$hash" > "$stamp"
  else
    say "npm ci failed; the glTF-Validator, three.js and pyright tests will be skipped"
  fi
}

# Blender (bpy) in .venv/blender: the requirement of the extra "blender", read from pyproject.toml.
blender_env() {
  local req stamp=.venv/blender/.jiggle-bpy
  req=$(.venv/bin/python -c 'import tomllib; print(*tomllib.load(open("pyproject.toml", "rb"))["project"]["optional-dependencies"]["blender"], sep="\n")')
  [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$req" ] && return 0
  say "installing Blender as a Python module into .venv/blender (~375 MB; JIGGLE_BLENDER=0 skips it)"
  [ -x .venv/blender/bin/python ] || python3.11 -m venv .venv/blender
  local reqs; mapfile -t reqs <<< "$req"
  if .venv/blender/bin/python -m pip install -q "${reqs[@]}"; then
    echo "$req" > "$stamp"
  else
    say "bpy did not install; tests/character/test_blender.py will be skipped"
  fi
}

# Headless rendering through Mesa EGL (MuJoCo and VTK).
export MUJOCO_GL="${MUJOCO_GL:-egl}"
export VTK_DEFAULT_OPENGL_WINDOW="${VTK_DEFAULT_OPENGL_WINDOW:-vtkEGLRenderWindow}"
export PYOPENGL_PLATFORM="${PYOPENGL_PLATFORM:-egl}"

cmd="${1:-}"; [ $# -gt 0 ] && shift
case "$cmd" in
  install) install ;;
  demo)    install; exec .venv/bin/jiggle demo "$@" ;;
  test)    install; exec .venv/bin/python -m pytest "$@" ;;
  *) echo "usage: ./dev.sh demo|test|install [options]" >&2; exit 2 ;;
esac
