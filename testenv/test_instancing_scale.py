"""Instancing at scale: PointInstancer arrays reach the renderer as arrays (composed there, relative to a batch
origin in double), instances cost a bounded number of bytes, and far-away or numerous instances still render right."""

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, Vt

NO_HIT = 0xFFFFFFFF


def _box(stage, path, size=(0.3, 0.2, 0.1)):
    """A box with distinct extents per axis (so that a wrong rotation or scale shows)."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    x, y, z = size
    mesh.CreatePointsAttr([(sx * x, sy * y, sz * z) for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)])
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])
    mesh.CreateSubdivisionSchemeAttr("none")
    return mesh


def _camera(stage, eye, target, clip=(0.1, 1000.0)):
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.CreateClippingRangeAttr(Gf.Vec2f(*clip))
    camera.AddTransformOp().Set(Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 1, 0)).GetInverse())


def _scatter(count, half: bool, seed=3):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-2.5, 2.5, (count, 3)).astype(np.float32)
    orientations = rng.normal(size=(count, 4))
    orientations /= np.linalg.norm(orientations, axis=1, keepdims=True)
    scales = rng.uniform(0.5, 1.6, (count, 3)).astype(np.float32)
    return positions, orientations.astype(np.float16 if half else np.float32), scales


def _instancer_stage(half: bool, offset=(0.0, 0.0, 0.0)):
    """Two prototypes (one placed by a transform of its own within the prototype), random orientations and
    non-uniform scales, every third instance hidden by invisibleIds; the instancer itself moved by `offset`."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    root = UsdGeom.Xform.Define(stage, "/World")
    root.AddTranslateOp().Set(Gf.Vec3d(*offset))
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Field")
    instancer.AddRotateXYZOp().Set(Gf.Vec3f(10, 20, 0))
    _box(stage, "/World/Field/Protos/Box")
    placed = UsdGeom.Xform.Define(stage, "/World/Field/Protos/Placed")
    placed.AddTranslateOp().Set(Gf.Vec3d(0.1, 0.2, 0.0))
    placed.AddScaleOp().Set(Gf.Vec3f(1.0, 0.5, 2.0))
    _box(stage, "/World/Field/Protos/Placed/Box", (0.1, 0.3, 0.2))
    instancer.CreatePrototypesRel().SetTargets(["/World/Field/Protos/Box", "/World/Field/Protos/Placed"])
    count = 60
    positions, orientations, scales = _scatter(count, half)
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions))
    if half:
        instancer.CreateOrientationsAttr(Vt.QuathArray.FromNumpy(orientations))
    else:
        instancer.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(orientations))
    instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(scales))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy((np.arange(count) % 2).astype(np.int32)))
    instancer.CreateInvisibleIdsAttr(Vt.Int64Array.FromNumpy(np.arange(0, count, 3, dtype=np.int64)))
    return stage, instancer


def _as_plain_prims(instancer_stage, instancer):
    """The same instances written out as one Xform per instance, with the matrices USD itself computes."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    time = Usd.TimeCode.Default()
    transforms = instancer.ComputeInstanceTransformsAtTime(  # the prototypes' own transforms included
        time, time, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask)
    world = UsdGeom.XformCache(time).GetLocalToWorldTransform(instancer.GetPrim())
    mask = instancer.ComputeMaskAtTime(time)
    proto_indices = instancer.GetProtoIndicesAttr().Get()
    for i, matrix in enumerate(transforms):
        if mask and not mask[i]:
            continue
        item = UsdGeom.Xform.Define(stage, f"/Item{i}")
        item.AddTransformOp().Set(matrix * world)
        if proto_indices[i] == 0:
            _box(stage, f"/Item{i}/Box")
        else:  # the prototype's own transform is in `matrix`: its child mesh sits at the prototype's origin
            _box(stage, f"/Item{i}/Box", (0.1, 0.3, 0.2))
    return stage


@pytest.mark.parametrize("half", [True, False], ids=["quath", "quatf"])
def test_point_instancer_arrays_place_instances_as_usd_computes_them(render, half):
    stage, instancer = _instancer_stage(half)
    _camera(stage, (0, 3, 9), (0, 0, 0))
    plain = _as_plain_prims(stage, instancer)
    _camera(plain, (0, 3, 9), (0, 0, 0))
    arrays = render(stage, resolution=(240, 160), aovs=("depth", "normal", "instanceId"))
    reference = render(plain, resolution=(240, 160), aovs=("depth", "normal", "instanceId"))
    assert arrays.stats["instances"] == reference.stats["instances"] == 40, "60 instances, 20 hidden by invisibleIds"
    assert arrays.stats["instance_batches"] == 2, "one batch per prototype, however many instances"
    depth, expected = arrays["depth"].pixels[..., 0], reference["depth"].pixels[..., 0]
    covered = np.isfinite(expected)
    assert covered.sum() > 2000
    assert np.array_equal(np.isfinite(depth), covered) or (np.isfinite(depth) != covered).sum() < 20, "the same silhouettes"
    both = covered & np.isfinite(depth)
    assert np.percentile(np.abs(depth[both] - expected[both]), 99) < 1e-3
    normals_agree = np.sum(arrays["normal"].pixels[..., :3][both] * reference["normal"].pixels[..., :3][both], axis=-1) > 0.999
    assert normals_agree.mean() > 0.99


def _expect_the_same_instances_and_depths(render, near, far):
    """The two stages, seen each by its camera, show the same instances at the same pixels and depths."""
    a = render(near, resolution=(240, 160), aovs=("instanceId", "depth"))
    b = render(far, resolution=(240, 160), aovs=("instanceId", "depth"))
    ids_a, ids_b = a["instanceId"].ids(), b["instanceId"].ids()
    assert (ids_a != NO_HIT).sum() > 2000
    assert (ids_a != ids_b).sum() <= 0.002 * ids_a.size, "the same instances cover the same pixels"
    depth_a, depth_b = a["depth"].pixels[..., 0], b["depth"].pixels[..., 0]
    both = np.isfinite(depth_a) & np.isfinite(depth_b)
    assert np.percentile(np.abs(depth_a[both] - depth_b[both]), 99) < 1e-3


def test_instances_far_from_the_origin_render_like_at_the_origin(render):
    near, _ = _instancer_stage(True)
    far, _ = _instancer_stage(True, offset=(3.0e6, -1.0e6, 2.0e6))
    _camera(near, (0, 3, 9), (0, 0, 0))
    _camera(far, (3.0e6, 1.0e6 * -1 + 3, 2.0e6 + 9), (3.0e6, -1.0e6, 2.0e6), clip=(0.1, 1000.0))
    _expect_the_same_instances_and_depths(render, near, far)


def _world_space_scatter_stage(shift):
    """An instancer at the world origin whose positions are authored in world space around `shift` (as a large
    world's scatter is): every position on a quarter-unit grid, which float holds exactly up to 2^22."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    instancer = UsdGeom.PointInstancer.Define(stage, "/Field")
    _box(stage, "/Field/Protos/Box")
    instancer.CreatePrototypesRel().SetTargets(["/Field/Protos/Box"])
    positions, orientations, _ = _scatter(40, False)
    positions = np.round(positions * 4) / 4 + np.array(shift, np.float32)
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    instancer.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(orientations))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(40, np.int32)))
    return stage


def test_world_space_instances_far_from_their_instancer_render_like_at_the_origin(render):
    """The instances lie 3e6 units from their instancer's origin, and so does the camera, off the float grid there
    (0.1 of a unit): the batch origin's low part must reach the instances near the camera."""
    shift = (3.0e6, -1.0e6, 2.0e6)
    eye, target = np.array([0.1, 3.1, 9.1]), np.array([0.1, 0.1, 0.1])
    near, far = _world_space_scatter_stage((0.0, 0.0, 0.0)), _world_space_scatter_stage(shift)
    _camera(near, eye, target)
    _camera(far, eye + shift, target + shift)
    _expect_the_same_instances_and_depths(render, near, far)


def test_a_hundred_thousand_instances_each_cover_their_pixels(render):
    """250 x 400 unit squares seen from above by an orthographic camera, 2 x 2 pixels each: every instance shows."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    quad = UsdGeom.Mesh.Define(stage, "/Field/Protos/Quad")
    quad.CreatePointsAttr([(-0.4, 0, -0.4), (0.4, 0, -0.4), (0.4, 0, 0.4), (-0.4, 0, 0.4)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 3, 2, 1])  # facing +Y
    quad.CreateSubdivisionSchemeAttr("none")
    instancer = UsdGeom.PointInstancer.Define(stage, "/Field")
    instancer.CreatePrototypesRel().SetTargets([quad.GetPath()])
    columns, rows = 400, 250
    x, z = np.meshgrid(np.arange(columns) + 0.5 - columns / 2, np.arange(rows) + 0.5 - rows / 2)
    positions = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], -1).astype(np.float32)
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(len(positions), np.int32)))
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    camera.CreateHorizontalApertureAttr(columns * 10.0)  # orthographic apertures are in tenths of a unit
    camera.CreateVerticalApertureAttr(rows * 10.0)
    camera.CreateClippingRangeAttr(Gf.Vec2f(1, 100))
    camera.AddTransformOp().Set(Gf.Matrix4d().SetLookAt(Gf.Vec3d(0, 10, 0), Gf.Vec3d(0, 0, 0), Gf.Vec3d(0, 0, -1)).GetInverse())
    result = render(stage, resolution=(2 * columns, 2 * rows), aovs=("instanceId", "primId"))
    assert result.stats["instances"] == rows * columns == 100_000
    ids = result["instanceId"].ids()
    assert len(np.unique(ids)) == 100_000, "every instance covers pixels, and nothing else does"
    assert np.array_equal(np.unique(ids), np.arange(100_000))
    assert len(np.unique(result["primId"].ids())) == 1, "one prim"
    assert result.stats["overflow_redraws"] == 1, "the cut list (room for 65536 instances at first) grew once"
    # What the instances cost on the GPU: a 48-byte transform and a batch word each, plus the lists of instances the
    # cut walks (here all of them) and of those the previous frame hid (bounded).
    assert 52 * 100_000 <= result.stats["instance_bytes"] <= 64 * 100_000


def test_a_hundred_thousand_hidden_instances_are_deferred_then_culled(render):
    """A wall hides 90,000 instances. The first frame draws the wall (large on screen) in its main pass and defers the
    small instances (more than the deferred list holds at first: it grows and the frame is drawn again); the second
    frame defers them on the previous frame's HZB; either way the post pass finds them hidden."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    wall = UsdGeom.Mesh.Define(stage, "/Wall")
    wall.CreatePointsAttr([(-50, -50, 0), (50, -50, 0), (50, 50, 0), (-50, 50, 0)])
    wall.CreateFaceVertexCountsAttr([4])
    wall.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    wall.CreateSubdivisionSchemeAttr("none")
    _box(stage, "/Field/Protos/Box", (0.02, 0.02, 0.02))
    instancer = UsdGeom.PointInstancer.Define(stage, "/Field")
    instancer.CreatePrototypesRel().SetTargets(["/Field/Protos/Box"])
    x, y = np.meshgrid(np.linspace(-1.4, 1.4, 300), np.linspace(-1.0, 1.0, 300))  # all in view
    positions = np.stack([x.ravel(), y.ravel(), np.full(x.size, -2.0)], -1).astype(np.float32)
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(len(positions), np.int32)))
    _camera(stage, (0, 0, 10), (0, 0, 0))
    import tessera

    session = tessera.Session(stage, validation=True)
    first = session.render(camera="/Camera", resolution=(160, 120), aovs=("primId",))
    second = session.render(camera="/Camera", resolution=(160, 120), aovs=("primId",))
    assert first.stats["instances"] == 90_001
    assert first.stats["occluded_instances"] == 90_000
    assert first.stats["overflow_redraws"] == 1, "the deferred list (room for 65536 at first) grew once"
    assert second.stats["occlusion_tested"] and second.stats["occluded_instances"] == 90_000
    assert second.stats["overflow_redraws"] == 0
    assert np.array_equal(first["primId"].ids(), second["primId"].ids())
    assert [e for e in second.errors if e.startswith("validation")] == []


def test_instances_with_nan_or_infinite_transforms_are_named_and_skipped(render):
    """A NaN or infinite position, orientation or scale leaves that instance out with a warning naming the instancer
    and the instances; the others draw where they would without it."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    instancer = UsdGeom.PointInstancer.Define(stage, "/Field")
    _box(stage, "/Field/Protos/Box")
    instancer.CreatePrototypesRel().SetTargets(["/Field/Protos/Box"])
    nan, inf = float("nan"), float("inf")
    positions = np.array([(-1.5, 0, 0), (nan, 0, 0), (0, 0, 0), (1.5, 0, 0), (3, inf, 0)], np.float32)
    orientations = np.array([(0, 0, 0, 1), (0, 0, 0, 1), (nan, 0, 0, 1), (0, 0, 0, 1), (0, 0, 0, 1)], np.float32)
    scales = np.array([(1, 1, 1), (1, 1, 1), (1, 1, 1), (2, 2, -inf), (1, 1, 1)], np.float32)
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions))
    instancer.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(orientations))
    instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(scales))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(5, np.int32)))
    _camera(stage, (0, 1, 6), (0, 0, 0))
    result = render(stage, resolution=(160, 80), aovs=("primId", "depth"))
    assert result.warnings == ["/Field: 4 instances have a NaN or infinite position, orientation or scale "
                               "(instance 1, 2, 3, 4); they are skipped"]
    # Only instance 0 is left: the same pixels as a stage holding it alone.
    alone = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(alone, UsdGeom.Tokens.y)
    _box(alone, "/Box").AddTranslateOp().Set(Gf.Vec3d(-1.5, 0, 0))
    _camera(alone, (0, 1, 6), (0, 0, 0))
    reference = render(alone, resolution=(160, 80), aovs=("primId", "depth"))
    covered = np.isfinite(reference["depth"].pixels[..., 0])
    assert covered.sum() > 200
    assert np.array_equal(np.isfinite(result["depth"].pixels[..., 0]), covered)
