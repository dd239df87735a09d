#!/usr/bin/env bash
# Installs what Tessera needs on Debian 12 and builds it into .venv. Idempotent: each step checks first.
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian 12 (bookworm) packages: Vulkan loader + lavapipe + validation layer, glslang and spirv-opt, OpenImageIO,
# OpenColorIO, OpenSubdiv, GoogleTest, zstd (page files), and the compilers. Versions are those of Debian 12.
APT_PACKAGES=(build-essential cmake ninja-build pkg-config python3-venv libvulkan-dev mesa-vulkan-drivers
              vulkan-validationlayers glslang-tools spirv-tools libopenimageio-dev libopencolorio-dev libosd-dev libgtest-dev libzstd-dev)
missing=()
for package in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  echo "bootstrap: installing ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# Python packages, pinned, in the project's own virtual environment.
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check -r tools/requirements.txt

# meshoptimizer 0.22's C++ sources ship in the PyPI sdist meshoptimizer==0.2.30a0: fetched by name, checked
# against a pinned sha256, unpacked under build/deps (ignored by git, never committed).
MESHOPT_VERSION=0.2.30a0
MESHOPT_SHA256=36b18b61a95ba992de804b1e91e86be2ba185925e4e2c1481495f8c68a17f5db
MESHOPT_DIR=build/deps/meshoptimizer-$MESHOPT_VERSION
if [ ! -f "$MESHOPT_DIR/src/meshoptimizer.h" ]; then
  mkdir -p build/deps/download
  .venv/bin/python -m pip download -q --disable-pip-version-check --no-deps --no-binary :all: --no-build-isolation \
    "meshoptimizer==$MESHOPT_VERSION" -d build/deps/download
  echo "$MESHOPT_SHA256  build/deps/download/meshoptimizer-$MESHOPT_VERSION.tar.gz" | sha256sum --check --quiet
  tar xzf "build/deps/download/meshoptimizer-$MESHOPT_VERSION.tar.gz" -C build/deps
fi

# Build and install the package (incremental: the CMake build folder is build/py).
.venv/bin/python -m pip install -q --disable-pip-version-check --no-build-isolation --no-deps .
