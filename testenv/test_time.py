"""Time: Session.set_time and `tessera render --frames` re-sync only what varies in time; static meshes are not
synced again, meshes whose points are animated are rebuilt per frame (through the mesh cache)."""

import json
import subprocess
import sys

import numpy as np
import pytest

import tessera
from tessera import _tessera

DIRTY = _tessera.dirty
NO_HIT = 0xFFFFFFFF
RESOLUTION = (200, 100)  # the camera sees x in [-4, 4], y in [-2, 2]: 25 pixels per unit

QUAD = """
        point3f[] points = [(-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, 0.5, 0), (-0.5, 0.5, 0)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]"""

# Frames 1-3: /Mover slides one unit right per frame, /Morph grows, /Blink hides at frame 2, /Held keeps its
# one value (samples that hold), /Static and its parent never change; /Looks/Pulse turns from red to green.
ANIMATED = f"""#usda 1.0
(
    startTimeCode = 1
    endTimeCode = 3
)
def Camera "Camera" {{
    float horizontalAperture = 40
    float verticalAperture = 20
    double3 xformOp:translate = (0, 0, 10)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def Xform "Group" {{
    def Mesh "Static" {{{QUAD}
        double3 xformOp:translate = (-3, 1.2, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
}}
def Xform "Mover" {{
    double3 xformOp:translate.timeSamples = {{ 1: (-2, 0, 0), 2: (-1, 0, 0), 3: (0, 0, 0) }}
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Mesh "Quad" {{{QUAD}
    }}
}}
def Mesh "Morph" {{
    point3f[] points.timeSamples = {{
        1: [(1.75, -0.25, 0), (2.25, -0.25, 0), (2.25, 0.25, 0), (1.75, 0.25, 0)],
        2: [(1.5, -0.5, 0), (2.5, -0.5, 0), (2.5, 0.5, 0), (1.5, 0.5, 0)],
        3: [(1.25, -0.75, 0), (2.75, -0.75, 0), (2.75, 0.75, 0), (1.25, 0.75, 0)],
    }}
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
}}
def Mesh "Blink" {{{QUAD}
    token visibility.timeSamples = {{ 1: "inherited", 2: "invisible", 3: "inherited" }}
    double3 xformOp:translate = (3, 1.2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def Mesh "Held" (
    prepend apiSchemas = ["MaterialBindingAPI"]
) {{{QUAD}
    double3 xformOp:translate.timeSamples = {{ 1: (0, 1.2, 0), 3: (0, 1.2, 0) }}
    uniform token[] xformOpOrder = ["xformOp:translate"]
    rel material:binding = </Looks/Pulse>
}}
def Scope "Looks" {{
    def Material "Pulse" {{
        token outputs:surface.connect = </Looks/Pulse/Surface.outputs:surface>
        def Shader "Surface" {{
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.timeSamples = {{ 1: (0.8, 0.05, 0.05), 3: (0.05, 0.8, 0.05) }}
            token outputs:surface
        }}
    }}
}}
"""


@pytest.fixture
def animated(tmp_path):
    path = tmp_path / "animated.usda"
    path.write_text(ANIMATED)
    return path


def _mask(result, path):
    ids = result["primId"].ids()
    matching = [i for i in np.unique(ids) if i != NO_HIT and result.prim_path(int(i)) == path]
    return np.isin(ids, matching)


def test_frames_resync_only_what_varies(animated):
    # Refined (complexity 1.2): /Morph is then worth caching (an unrefined mesh this small is built every time).
    session = tessera.Session(animated, frame=1, validation=True, complexity=1.2)
    frames = {}
    for frame in (1, 2, 3):
        session.set_time(frame)
        result = session.render(camera="/Camera", resolution=RESOLUTION, aovs=("primId", "color"))
        assert not result.errors, result.errors
        frames[frame] = result, dict(session.index.last_synced)

    first, synced = frames[1]
    assert "/Group/Static" in synced
    # The four unit quads (/Group/Static, /Mover/Quad, /Blink, /Held) are one mesh, built once and shared.
    assert (first.stats["meshes_built"] + first.stats["meshes_cached"], first.stats["meshes_shared"]) == (2, 3)
    # Frame 2: the transform, the points and the visibility that changed; the shader input moved too (its samples
    # at 1 and 3 interpolate). /Held's samples hold the same value: nothing. /Group/Static: nothing.
    second, synced = frames[2]
    assert synced == {"/Mover/Quad": DIRTY.TRANSFORM, "/Morph": DIRTY.POINTS, "/Blink": DIRTY.VISIBILITY,
                      "/Looks/Pulse": DIRTY.PARAMS}
    # (Built, or loaded: another test's mesh may have the same content, in the test run's shared mesh cache.)
    assert second.stats["meshes_built"] + second.stats["meshes_cached"] == 1, "only the mesh whose points move is built again"
    assert second.stats["synced"] == {"mesh": 3, "material": 1}
    third, synced = frames[3]
    assert synced == {"/Mover/Quad": DIRTY.TRANSFORM, "/Morph": DIRTY.POINTS, "/Blink": DIRTY.VISIBILITY,
                      "/Looks/Pulse": DIRTY.PARAMS}
    assert session.index.sync_counts["mesh"] == 5 + 3 + 3

    # The images follow: /Mover one unit (25 px) right per frame, /Morph's area (1/4, 1, 9/4 units), /Blink gone
    # at frame 2 only, /Held from red to green.
    centres = [np.nonzero(_mask(frames[f][0], "/Mover/Quad"))[1].mean() for f in (1, 2, 3)]
    assert np.diff(centres) == pytest.approx([25, 25], abs=1)
    areas = [_mask(frames[f][0], "/Morph").sum() for f in (1, 2, 3)]
    assert areas[1] == pytest.approx(4 * areas[0], rel=0.15) and areas[2] == pytest.approx(9 * areas[0], rel=0.15)
    assert [_mask(frames[f][0], "/Blink").any() for f in (1, 2, 3)] == [True, False, True]
    red, green = first["color"].pixels[20, 100, :3], third["color"].pixels[20, 100, :3]  # /Held's centre
    assert red[0] > 3 * red[1] and green[1] > 3 * green[0], (red, green)
    assert np.array_equal(_mask(first, "/Group/Static"), _mask(third, "/Group/Static"))

    # Back to frame 1: the points are those already built, so the cache serves them.
    session.set_time(1)
    again = session.render(camera="/Camera", resolution=RESOLUTION, aovs=("primId",))
    assert again.stats["meshes_built"] == 0 and again.stats["meshes_cached"] == 1
    assert np.array_equal(again["primId"].ids(), first["primId"].ids())
    session.set_time(1)
    assert session.render(camera="/Camera", resolution=RESOLUTION).stats["synced"] == {}, "the same time syncs nothing"


def test_an_edit_between_frames_is_followed_too(animated):
    session = tessera.Session(animated, frame=1, validation=True)
    session.render(camera="/Camera", resolution=RESOLUTION)
    session.stage.GetPrimAtPath("/Group/Static").GetAttribute("xformOp:translate").Set((-3, -1.2, 0))
    session.set_time(2)
    result = session.render(camera="/Camera", resolution=RESOLUTION, aovs=("primId",))
    assert dict(session.index.last_synced) == {"/Group/Static": DIRTY.TRANSFORM, "/Mover/Quad": DIRTY.TRANSFORM,
                                               "/Morph": DIRTY.POINTS, "/Blink": DIRTY.VISIBILITY, "/Looks/Pulse": DIRTY.PARAMS}
    rows = np.nonzero(_mask(result, "/Group/Static"))[0]
    assert rows.mean() == pytest.approx(50 + 1.2 * 25 - 0.5, abs=1), "the edited static mesh moved down"


def run(*args):
    return subprocess.run([sys.executable, "-m", "tessera.cli", *map(str, args)], capture_output=True, text=True, timeout=300)


def test_cli_renders_a_sequence(animated, tmp_path):
    stats_file = tmp_path / "stats.json"
    done = run("render", animated, "-o", tmp_path / "seq" / "out.####.png", "--frames", "1-3", "--resolution", "200x100",
               "--aov", "primId", "--stats", stats_file)
    assert done.returncode == 0, done.stderr
    written = sorted(p.name for p in (tmp_path / "seq").iterdir())
    assert written == ["out.0001.png", "out.0002.png", "out.0003.png"]
    stats = json.loads(stats_file.read_text())
    assert [f["frame"] for f in stats["frames"]] == [1, 2, 3]
    assert [f["meshes_built"] + f["meshes_cached"] + f["meshes_shared"] for f in stats["frames"]] == [5, 1, 1]
    assert stats["frames"][1]["synced"] == {"mesh": 3, "material": 1}
    assert "frame 2 -> " in done.stderr
    first = tessera.read_image(str(tmp_path / "seq" / "out.0001.png"))
    second = tessera.read_image(str(tmp_path / "seq" / "out.0002.png"))
    assert not np.array_equal(first, second)

    done = run("render", animated, "-o", tmp_path / "step.#.exr", "--frames", "1-3x2", "--resolution", "32x16")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "step.1.exr").exists() and (tmp_path / "step.3.exr").exists() and not (tmp_path / "step.2.exr").exists()


def test_cli_frames_errors(animated, tmp_path):
    done = run("render", animated, "-o", tmp_path / "out.exr", "--frames", "1-3")
    assert done.returncode == 1 and "needs '#' in the output name" in done.stderr and "out.exr" in done.stderr
    assert not list(tmp_path.glob("*.exr"))
    done = run("render", animated, "-o", tmp_path / "out.#.exr", "--frames", "3-1")
    assert done.returncode == 2 and "comes before the first" in done.stderr
    done = run("render", animated, "-o", tmp_path / "out.#.exr", "--frames", "1-3", "--frame", "2")
    assert done.returncode == 2 and "not allowed with" in done.stderr
    done = run("render", animated, "-o", tmp_path / "out.#.exr", "--frames", "1.5")
    assert done.returncode == 1 and "frame 1.5 is not whole" in done.stderr
