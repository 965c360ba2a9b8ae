#!/usr/bin/env bash
# Set up everything `make demo` and `make test` need on a Debian machine:
# the system libraries open3d needs (only those missing), a virtual
# environment in .venv with the project and its Python dependencies, and the
# Khronos glTF validator (when npm is available) for the tests.
# As root it installs what is missing; otherwise it prints what to install.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3 || true)}
VENV=${VENV:-.venv}
if [ -z "$PYTHON" ]; then
  echo "bootstrap: no python3 found; install Python 3.11: apt-get install -y python3.11 python3.11-venv" >&2
  exit 1
fi

# --- system libraries -------------------------------------------------------
# library file -> Debian package
declare -A LIBS=(
  [libusb-1.0.so.0]=libusb-1.0-0
  [libGL.so.1]=libgl1
  [libEGL.so.1]=libegl1
  [libvulkan.so.1]=libvulkan1
)
missing=()
# Read the cache once: `ldconfig -p | grep -q` under pipefail fails at random
# (grep exits early and ldconfig dies of SIGPIPE).
libcache=$(ldconfig -p 2>/dev/null || true)
for lib in "${!LIBS[@]}"; do
  grep -qF "$lib" <<<"$libcache" || missing+=("${LIBS[$lib]}")
done
# Mesa's Vulkan drivers (lavapipe) for Open3D's Filament renderer on machines without a GPU.
if command -v dpkg-query >/dev/null && ! dpkg-query -W -f='${Status}' mesa-vulkan-drivers 2>/dev/null | grep -q "ok installed"; then
  missing+=(mesa-vulkan-drivers)
fi
if ! "$PYTHON" -c "import ensurepip, venv" >/dev/null 2>&1; then
  missing+=("python3-venv")
fi
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "bootstrap: installing system packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "bootstrap: missing system packages: ${missing[*]}" >&2
    echo "bootstrap: install them with:  sudo apt-get install -y ${missing[*]}" >&2
    exit 1
  fi
fi

# --- Python environment -----------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  echo "bootstrap: creating $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
echo "bootstrap: installing the project and its dependencies into $VENV"
"$VENV/bin/python" -m pip install -q -e ".[dev,train,ray]"

# --- glTF validator (tests only; skipped by the tests when absent) -----------
if [ "${WITH_VALIDATOR:-0}" = 1 ]; then
  if [ -d .tools/node/node_modules/gltf-validator ]; then
    :
  elif command -v npm >/dev/null; then
    echo "bootstrap: installing the Khronos glTF validator into .tools/node"
    npm install --silent --no-audit --no-fund --prefix .tools/node gltf-validator@2.0.0-dev.3.10 >/dev/null \
      || echo "bootstrap: could not install gltf-validator; its tests will be skipped" >&2
  else
    echo "bootstrap: npm not found; the glTF validator tests will be skipped (apt-get install -y nodejs npm)" >&2
  fi
fi
echo "bootstrap: ready"
