#!/usr/bin/env bash
# Runs on a borrowed GPU machine, from the repository root, with .gpu/ from tools/gpu_bundle.sh beside it: proves the
# GPU path (the tests with the validation layer on) and measures it (the benchmark without). Each step is
# time-boxed and logs to $OUT/<step>.log; a failed smoke render stops the rest.
#   OUT=/some/dir tools/gpu_check.sh [steps...]     steps: smoke cpp bench pytest (default: all, in that order), and
#   antialiasing (bench render --cases antialiasing: what a pixel sample costs where the host adds each sample's colour),
#   build (bench build on two of the machine's cores, the builder issue's setting: its generated meshes),
#   edit (bench render --cases edit alone: a live edit's upload), raster (bench raster: where this device's compute
#   rasterizer stops beating hardware raster, not recorded), live (the live-edit and thread tests, which need no
#   image files: a short look at the upload and threading paths)
# NVIDIA's Vulkan driver (libGLX_nvidia.so.0) needs the GL dispatch libraries (libglvnd): on a machine without them,
# vkCreateInstance finds no driver ("Could not get 'vkCreateInstance' via 'vk_icdGetInstanceProcAddr'"). Debian's
# packages of them (.gpu/gl, from gpu_bundle.sh) are unpacked into / where libGLdispatch.so.0 is missing, which was
# enough on an H100 (the machine is borrowed and bare; never do this on one you keep).
set -uo pipefail
OUT=${OUT:-/tmp/tessera-gpu-out}
mkdir -p "$OUT"
nvidia=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$nvidia" ] && export VK_DRIVER_FILES=$nvidia
[ -d /usr/local/nvidia/lib64 ] && export LD_LIBRARY_PATH=/usr/local/nvidia/lib64${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
if ! ldconfig -p | grep -q 'libGLdispatch.so.0 ' && ls .gpu/gl/*.deb >/dev/null 2>&1; then
    for deb in .gpu/gl/*.deb; do dpkg -x "$deb" /; done
    ldconfig
fi
source .gpu/run.sh
steps=("$@")
[ ${#steps[@]} -gt 0 ] || steps=(smoke cpp bench pytest)

step() {  # step NAME SECONDS COMMAND...
    local name=$1 limit=$2
    shift 2
    echo "== $name ($(date +%T), at most ${limit}s)"
    timeout "$limit" "$@" > "$OUT/$name.log" 2>&1
    local rc=$?
    tail -n 25 "$OUT/$name.log"
    echo "== $name: exit $rc"
    return $rc
}

for s in "${steps[@]}"; do
    case $s in
    smoke)
        nvidia-smi -L 2>&1 | head -2
        step smoke 90 "$TESSERA_PY" -c "
import tessera
s = tessera.Session('testenv/testCube/cube.usda', validation=True)
print('device:', s.device_name, 'validation:', s.delegate.validation_enabled)
r = s.render(camera=s.camera_paths()[0], resolution=(256, 256), aovs=('color', 'primId'))
print('errors:', r.errors, 'warnings:', r.warnings)
print({k: r.stats[k] for k in ('visible_clusters', 'sw_triangles', 'hw_triangles') if k in r.stats})
assert not r.errors" || exit 1 ;;
    cpp) TESSERA_VALIDATION=1 step cpp 120 "$B/gpu/tessera_cpp_tests" --gtest_brief=1 ;;
    bench) step bench 260 "$TESSERA_PY" -c "import sys; from tessera.cli import main; sys.exit(main())" bench render \
               --cases density,brute,error,first-frame,edit --frames 5 --json "$OUT/bench_render.json" ;;
    raster) step raster 90 "$TESSERA_PY" -c "import sys; from tessera.cli import main; sys.exit(main())" bench raster \
               --json "$OUT/bench_raster.json" ;;
    edit) step edit 150 "$TESSERA_PY" -c "import sys; from tessera.cli import main; sys.exit(main())" bench render \
               --cases edit --frames 5 --json "$OUT/bench_edit.json" ;;
    live) TESSERA_VALIDATION=1 step live 120 "$TESSERA_PY" -m pytest -q -rf --tb=short -p no:cacheprovider testenv/test_live_edits.py \
               testenv/test_displacement.py -k "thread or another_edits or edits_beside or an_edit_uploads" ;;
    antialiasing) step antialiasing 150 "$TESSERA_PY" -c "import sys; from tessera.cli import main; sys.exit(main())" bench render \
               --cases antialiasing --frames 3 --json "$OUT/bench_antialiasing.json" ;;
    build) step build 150 taskset -c 0,1 "$TESSERA_PY" -c "import sys; from tessera.cli import main; sys.exit(main())" bench build \
               --json "$OUT/bench_build.json" ;;
    pytest) TESSERA_VALIDATION=1 step pytest 200 "$TESSERA_PY" -m pytest -q -rf --tb=line -p no:cacheprovider testenv ;;
    esac
done
