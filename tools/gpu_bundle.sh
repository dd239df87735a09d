#!/usr/bin/env bash
# Packs the installed package with its interpreter, usd-core, numpy, pytest and the Debian libraries it links into
# .gpu/, for a machine that has a GPU driver but none of Debian's packages (a borrowed GPU: benchmarks and the test
# suite on real hardware). Image files are left out: libtessera_image_files.so brings about 260 libraries, so on such
# a machine textures fall back with a warning and AOVs are compared in memory, not written.
#   tools/gpu_bundle.sh            -> .gpu/bundle.tar.xz and .gpu/run.sh (what the other machine runs first)
# There: `source .gpu/run.sh` unpacks it once, sets the paths and the validation layer, and defines $TESSERA_PY.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=.venv
site=$($venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
base=$($venv/bin/python -c 'import sys; print(sys.base_prefix)')
version=$($venv/bin/python -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
root=$stage/gpu

# The interpreter and its standard library, less what a test or a benchmark never imports.
mkdir -p "$root/python/bin" "$root/python/lib" "$root/lib" "$root/lib-cxx" "$root/layers"
cp -L "$base/bin/python$version" "$root/python/bin/"
cp -L "$base/lib/libpython$version.so.1.0" "$root/lib/"
tar -C "$base/lib" -cf - --exclude site-packages --exclude test --exclude tests --exclude idlelib --exclude tkinter \
  --exclude turtledemo --exclude ensurepip --exclude lib2to3 --exclude 'config-*' --exclude __pycache__ --exclude '_tkinter*' \
  "python$version" | tar -C "$root/python/lib" -xf -

# Packages: ours without the image-file library, usd-core (less the Python bindings of schemas nobody imports:
# their plugInfo stays, libusd_ms holds every schema), numpy, and pytest's own.
packages=$root/site
mkdir -p "$packages"
for p in tessera pxr usd_core.libs numpy numpy.libs _pytest pytest pluggy iniconfig packaging py.py; do
  [ -e "$site/$p" ] && cp -a "$site/$p" "$packages/"
done
rm -f "$packages/tessera/libtessera_image_files.so"
for unused in UsdPhysics UsdSkel UsdMedia UsdVol UsdProc UsdUI UsdHydra UsdMtlx UsdAppUtils Usdviewq UsdSemantics UsdUtils \
              UsdRi UsdSkelImaging UsdImaging UsdImagingGL UsdBakeMtlx; do
  rm -rf "$packages/pxr/$unused"
done
find "$packages" -name __pycache__ -prune -exec rm -rf {} +
rm -rf "$packages/numpy/_core/tests" "$packages/numpy/tests" "$packages/numpy"/*/tests

# Libraries the extension, the interpreter's modules and the validation layer need beyond glibc. libstdc++ and
# libgcc_s wait in lib-cxx for a machine whose own are older than Debian 12's (newer ones are used as they are).
libs=()
for object in "$packages"/tessera/_tessera*.so "$base/lib/python$version"/lib-dynload/{_ctypes,_lzma,_bz2,zlib,_hashlib,_ssl,pyexpat}*.so \
              /usr/lib/x86_64-linux-gnu/libVkLayer_khronos_validation.so; do
  [ -e "$object" ] || continue
  while read -r path; do libs+=("$path"); done < <(ldd "$object" | awk '$3 ~ /^\// {print $3}')
done
for path in $(printf '%s\n' "${libs[@]}" | sort -u); do
  case "$(basename "$path")" in
    libc.so.*|libm.so.*|libdl.so.*|libpthread.so.*|librt.so.*|ld-linux*|libpython*) ;;
    libstdc++.so.*|libgcc_s.so.*) cp -L "$path" "$root/lib-cxx/" ;;
    *) cp -L "$path" "$root/lib/" ;;
  esac
done
# The validation layer, its manifest pointing beside itself.
cp -L /usr/lib/x86_64-linux-gnu/libVkLayer_khronos_validation.so "$root/layers/"
sed 's#"library_path": *"[^"]*"#"library_path": "./libVkLayer_khronos_validation.so"#' \
  /usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json > "$root/layers/VkLayer_khronos_validation.json"

# The C++ tests, linked again from build/py's objects without test_textures.cpp (which writes PNGs through
# OpenImageIO): ctest's renderer tests on the other machine's GPU.
objects=build/py/testenv/cpp/CMakeFiles/tessera_cpp_tests.dir
if [ -d "$objects" ]; then
  g++ -o "$root/tessera_cpp_tests" $(ls "$objects"/*.cpp.o | grep -v test_textures) build/py/plugin/libtessera_plugin.a \
    /usr/lib/x86_64-linux-gnu/libgtest_main.a build/py/renderer/libtessera_renderer.a build/py/builder/libtessera_builder.a \
    build/py/libmeshoptimizer.a -losdCPU -lzstd -lvulkan -ldl /usr/lib/x86_64-linux-gnu/libgtest.a -lpthread
fi

mkdir -p .gpu/gl
# NVIDIA's Vulkan driver needs the GL dispatch libraries (libglvnd) beside it; gpu_check.sh unpacks these where the
# machine lacks them (as Debian packages: unpacked into /, as a borrowed machine's README advises).
lists=$(mktemp -d) && mkdir -p "$lists/partial"
(cd .gpu/gl && apt-get -q -o Dir::State::Lists="$lists" update >/dev/null && \
 apt-get -q -o Dir::State::Lists="$lists" download libglvnd0 libgl1 libglx0 libegl1 libgles2 libopengl0 >/dev/null) || \
  echo "gpu_bundle.sh: could not fetch libglvnd's packages (no network?): .gpu/gl is empty" >&2
rm -rf "$lists"
tar -C "$stage" -cf - gpu | xz -T0 -6 > .gpu/bundle.tar.xz
cat > .gpu/run.sh <<EOF
# Sourced on the other machine from the repository root: unpacks the bundle once and sets the environment.
B=/tmp/tessera-gpu
[ -d \$B/gpu ] || { mkdir -p \$B && xz -dc .gpu/bundle.tar.xz | tar -C \$B -xf -; }
export LD_LIBRARY_PATH=\$B/gpu/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}
own_cxx=\$(ldconfig -p | awk '/libstdc\+\+\.so\.6 .*x86-64/ {print \$NF; exit}')
grep -aq GLIBCXX_3.4.30 "\$own_cxx" 2>/dev/null || export LD_LIBRARY_PATH=\$B/gpu/lib-cxx:\$LD_LIBRARY_PATH
export PYTHONHOME=\$B/gpu/python PYTHONPATH=\$B/gpu/site PYTHONUNBUFFERED=1
export VK_LAYER_PATH=\$B/gpu/layers
export TESSERA_PY=\$B/gpu/python/bin/python$version
EOF
ls -la .gpu
