"""Image files (textures read, AOVs written) go through libtessera_image_files.so, loaded on first use: a process that
reads and writes no image file never maps OpenImageIO or OpenColorIO, and a package without that library still
renders, with a clear message wherever a file was needed."""

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import tessera

from conftest import TESTENV

PACKAGE = Path(tessera.__file__).parent


MAPPED = """
def mapped(name):
    with open("/proc/self/maps") as maps:
        return name in maps.read()
"""


def run_python(code: str, *, package_root: Path | None = None) -> subprocess.CompletedProcess:
    """`code` in a fresh interpreter (mapped(name) says whether a library is loaded), validation on."""
    env = dict(os.environ, TESSERA_VALIDATION="1")
    if package_root is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(package_root), env.get("PYTHONPATH")]))
    return subprocess.run([sys.executable, "-c", MAPPED + textwrap.dedent(code)], env=env, capture_output=True, text=True, timeout=300)


def test_image_libraries_load_only_when_a_file_is_read_or_written(tmp_path):
    out = tmp_path / "cube.exr"
    result = run_python(f"""
        import tessera
        session = tessera.Session({str(TESTENV / "testCube" / "cube.usda")!r}, validation=True)
        result = session.render(camera=session.camera_paths()[0], resolution=(64, 64))
        assert not result.errors, result.errors
        assert not mapped("libOpenImageIO"), "an untextured render to memory loaded OpenImageIO"
        assert not mapped("libOpenColorIO"), "an untextured render to memory loaded OpenColorIO"
        result.write({str(out)!r})
        assert mapped("libtessera_image_files.so") and mapped("libOpenImageIO"), "writing a file did not load the library"
        print("ok")
    """)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"
    assert out.stat().st_size > 0


def test_a_package_without_the_image_library_still_renders_and_names_it(tmp_path):
    # The installed package, copied without libtessera_image_files.so (a machine without OpenImageIO).
    shutil.copytree(PACKAGE, tmp_path / "tessera", ignore=shutil.ignore_patterns("libtessera_image_files.so", "__pycache__"))
    textured = TESTENV / "testTextures" / "textures.usda"
    result = run_python(f"""
        import tessera, numpy as np
        assert tessera.__file__.startswith({str(tmp_path)!r}), tessera.__file__
        session = tessera.Session({str(textured)!r}, validation=True)
        result = session.render(camera=session.camera_paths()[0], resolution=(64, 64))
        assert not result.errors, result.errors
        texture_warnings = [w for w in result.warnings if "libtessera_image_files.so" in w]
        assert texture_warnings, result.warnings
        print(texture_warnings[0])
        assert np.count_nonzero(np.asarray(result["color"].pixels)[..., 3]) > 0, "nothing was drawn"
        try:
            result.write({str(tmp_path / "out.exr")!r})
        except tessera.ImageIoError as e:
            print("write:", e)
        else:
            raise AssertionError("writing an EXR without the image library did not fail")
    """, package_root=tmp_path)
    assert result.returncode == 0, result.stderr + result.stdout
    lines = result.stdout.strip().splitlines()
    # The texture's message names the material, the file and the library; the stage renders with the fallback.
    assert "texture '" in lines[0] and "cannot be read" in lines[0] and "fallback" in lines[0], lines[0]
    assert lines[1].startswith("write:") and "libtessera_image_files.so" in lines[1] and "OpenImageIO" in lines[1], lines[1]
