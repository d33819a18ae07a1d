"""Imports `livegesture generate` outputs in Blender and checks them against the npz of the same run
(run by scripts/test.sh; Debian's `blender` package, headless):

    blender -b --factory-startup --python runtime/tests/blender/check_import.py -- M.glb M.bvh M.npz

For each of the .glb (Blender's glTF importer) and the .bvh (Blender's BVH importer):
- one armature with the 55 SMPL-X joints, by name;
- one keyframe per npz frame (the F-curves' key count, and the action's frame range);
- at a few frames, every joint's rotation in the world equals the npz's (forward kinematics of the
  axis-angle, Y up, taken to Blender's Z up), within BOUND on the matrix entries. Comparing world
  rotations relative to the rest pose makes the check independent of how each importer orients its
  bones (the glTF importer's bone heuristic, the BVH importer's rest axes).
A broken expectation (the npz's poses of another frame) must fail the same comparison, so the check
cannot pass by comparing nothing.
With the face channel (the npz has `arkit`, docs/face.md), the .glb's `face` mesh must import with 52 shape
keys named as ARKit names them, each animated, and the key values at a few frames must equal the npz's
`arkit` (a wrong frame's values must not). Exit status 0 when every check passes, 1 otherwise.
"""
import ast
import builtins
import math
import sys
import zipfile
from array import array

import bpy
from mathutils import Matrix, Vector

NAMES = [
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw",
    "left_eye_smplhf", "right_eye_smplhf",
] + [f"{s}_{f}{k}" for s in ("left", "right") for f in ("index", "middle", "pinky", "ring", "thumb") for k in (1, 2, 3)]
PARENTS = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15, 20, 25,
    26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38, 21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49,
    50, 21, 52, 53,
]
BOUND = 2e-3  # max abs difference of rotation-matrix entries (f32 keys, BVH's 6 decimals in degrees)
# Y up (glTF, BVH) -> Blender's Z up: (x, y, z) -> (x, -z, y)
C = Matrix(((1.0, 0, 0), (0, 0, -1.0), (0, 1.0, 0)))


def read_poses(npz, key="poses"):
    """The npz's `poses` (or another float32 2-D key) as a list of frames (Blender's Python has no numpy
    here); None when the npz has no such key."""
    with zipfile.ZipFile(npz) as z:
        if f"{key}.npy" not in z.namelist():
            return None
        b = z.read(f"{key}.npy")
    assert b[:6] == b"\x93NUMPY", f"{npz}: poses.npy is not an npy file"
    hl = int.from_bytes(b[8:10], "little") if b[6] == 1 else int.from_bytes(b[8:12], "little")
    start = 10 + hl if b[6] == 1 else 12 + hl
    head = ast.literal_eval(b[start - hl:start].decode("latin1"))
    assert head["descr"] == "<f4" and not head["fortran_order"], f"{npz}: poses is {head}, expected <f4 C order"
    t, d = head["shape"]
    a = array("f")
    a.frombytes(b[start:start + 4 * t * d])
    if sys.byteorder != "little":
        a.byteswap()
    return [a[i * d:(i + 1) * d] for i in range(t)]


def aa_to_matrix(aa):
    v = Vector(aa)
    t = v.length
    if t < 1e-12:
        return Matrix.Identity(3)
    return Matrix.Rotation(t, 3, v / t)


def global_rotations(poses_row):
    g = [None] * 55
    for j in range(55):
        r = aa_to_matrix(poses_row[3 * j: 3 * j + 3])
        g[j] = r if PARENTS[j] < 0 else g[PARENTS[j]] @ r
    return [C @ m @ C.transposed() for m in g]


def max_abs(a, b):
    """The largest entry difference of two 3x3 matrices; infinite when any entry on either side is NaN or
    Inf (a NaN difference would otherwise be skipped by `e > worst` and pass `worst > BOUND`)."""
    d = [abs(a[i][k] - b[i][k]) for i in range(3) for k in range(3)]
    return max(d) if all(math.isfinite(x) for x in d) else math.inf


def self_check():
    """The comparison fails a non-finite matrix (issue 38: the old `max` of differences returned a
    finite value for a NaN entry after a larger one, and `nan > BOUND` is False)."""
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    bad = [[1.0, 0.0, 0.0], [0.0, float("nan"), 0.0], [0.0, 0.0, 1.0]]
    assert max_abs(bad, eye) == math.inf and max_abs(eye, bad) == math.inf
    assert max_abs(eye, eye) == 0.0


def world_deltas(arm, frame):
    """Each bone's world rotation relative to its rest: (W P) (W B)^-1, normalised."""
    bpy.context.scene.frame_set(frame)
    bpy.context.view_layer.update()
    w = arm.matrix_world
    out = {}
    for pb in arm.pose.bones:
        posed = (w @ pb.matrix).to_3x3().normalized()
        rest = (w @ pb.bone.matrix_local).to_3x3().normalized()
        out[pb.name] = posed @ rest.inverted()
    return out


def check(label, arm, poses, first_frame, failures):
    names = [b.name for b in arm.data.bones]
    if len(names) != 55 or sorted(names) != sorted(NAMES):
        failures.append(f"{label}: {len(names)} bones, expected the 55 SMPL-X joints (got {sorted(names)[:5]}...)")
        return
    action = arm.animation_data.action if arm.animation_data else None
    if action is None:
        failures.append(f"{label}: the armature has no action")
        return
    t_len = len(poses)
    keys = {len(fc.keyframe_points) for fc in action.fcurves}
    lo, hi = action.frame_range
    print(f"{label}: {len(names)} bones, {len(action.fcurves)} F-curves, keys per F-curve {sorted(keys)}, frames {lo:g}-{hi:g}")
    if keys != {t_len}:
        failures.append(f"{label}: F-curves hold {sorted(keys)} keyframes, expected {t_len} (the npz's frames)")
    if (round(lo), round(hi)) != (first_frame, first_frame + t_len - 1):
        failures.append(f"{label}: frame range {lo:g}-{hi:g}, expected {first_frame}-{first_frame + t_len - 1}")
    frames = sorted({0, 1, t_len // 3, t_len // 2, t_len - 1})
    worst, worst_at = 0.0, None
    shifted_worst = 0.0
    for t in frames:
        got = world_deltas(arm, first_frame + t)
        want = global_rotations(poses[t])
        other = global_rotations(poses[(t + t_len // 2) % t_len])  # deliberately the wrong frame
        for j, name in enumerate(NAMES):
            e = max_abs(got[name], want[j])
            if e > worst or worst_at is None:
                worst, worst_at = e, (t, name)
            shifted_worst = max(shifted_worst, max_abs(got[name], other[j]))
    print(f"{label}: world rotations of all 55 joints at frames {frames}: max |error| {worst:.2e} (at {worst_at}); "
          f"against the wrong frames {shifted_worst:.2e}")
    if worst > BOUND:
        failures.append(f"{label}: joint rotations differ from the npz by {worst:.2e} (> {BOUND}) at frame/joint {worst_at}")
    if t_len > 2 and shifted_worst <= BOUND:
        failures.append(f"{label}: the comparison does not tell frames apart (wrong frames differ by only {shifted_worst:.2e})")


ARKIT_FACE_BOUND = 1e-4


def check_face(glb, arkit, failures):
    """The imported face mesh: 52 ARKit shape keys, animated with the npz's weights."""
    faces = [o for o in bpy.data.objects if o.type == "MESH" and o.data.shape_keys is not None]
    if len(faces) != 1:
        failures.append(f"{glb}: {len(faces)} meshes with shape keys imported, expected 1 (the face)")
        return
    keys = faces[0].data.shape_keys
    names = [k.name for k in keys.key_blocks][1:]   # after the Basis
    if len(names) != 52 or names[0] != "eyeBlinkLeft" or names[-1] != "tongueOut" or "jawOpen" not in names:
        failures.append(f"{glb}: face shape keys {names[:3]}...{names[-2:]} ({len(names)}), expected the 52 ARKit names")
        return
    action = keys.animation_data.action if keys.animation_data else None
    curves = {c.data_path: c for c in (action.fcurves if action else [])}
    animated = [n for n in names if f'key_blocks["{n}"].value' in curves]
    if len(animated) != 52:
        failures.append(f"{glb}: {len(animated)} of the 52 face shape keys are animated")
        return
    t = len(arkit)
    worst, wrong = 0.0, 0.0
    for f in sorted({0, t // 3, t // 2, t - 1}):
        for j, n in enumerate(names):
            v = curves[f'key_blocks["{n}"].value'].evaluate(f)   # the glTF import starts at frame 0
            worst = max(worst, abs(v - arkit[f][j]))
            wrong = max(wrong, abs(v - arkit[(f + 7) % t][j]))
    print(f"face: 52 animated ARKit shape keys, worst |key - npz arkit| {worst:.2e} over 4 frames")
    if worst > ARKIT_FACE_BOUND:
        failures.append(f"{glb}: face shape key values differ from the npz's arkit by {worst:.2e} > {ARKIT_FACE_BOUND}")
    if wrong <= ARKIT_FACE_BOUND:
        failures.append(f"{glb}: the face comparison does not tell frames apart ({wrong:.2e})")


def armature_after(importer):
    before = set(bpy.data.objects)
    importer()
    arms = [o for o in bpy.data.objects if o not in before and o.type == "ARMATURE"]
    return arms


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if len(argv) != 3:
        print("usage: blender -b --python check_import.py -- M.glb M.bvh M.npz", file=sys.stderr)
        sys.exit(2)
    glb, bvh, npz = argv
    self_check()
    poses = read_poses(npz)
    if not all(math.isfinite(x) for row in poses for x in row):
        print(f"FAILED: {npz}: non-finite poses", file=sys.stderr)
        sys.exit(1)
    failures = []
    scene = bpy.context.scene
    # an empty scene at the motion's 30 fps (the glTF importer turns seconds into frames with it)
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o, do_unlink=True)
    scene.render.fps, scene.render.fps_base = 30, 1.0

    # Blender 3.4's glTF importer needs numpy (Debian: python3-numpy) and uses `np.bool`, which numpy
    # 1.24 (Debian 12) removed: give it back the builtin it stood for
    import numpy
    if "bool" not in numpy.__dict__:
        numpy.bool = bool
    arms = armature_after(lambda: bpy.ops.import_scene.gltf(filepath=glb))
    if len(arms) != 1:
        failures.append(f"{glb}: {len(arms)} armatures imported, expected 1")
    else:
        check("glb", arms[0], poses, 0, failures)

    arkit = read_poses(npz, "arkit")
    if arkit is not None:
        check_face(glb, arkit, failures)

    # Blender 3.4's BVH add-on opens its file with mode 'rU', which Python 3.11 removed: drop the 'U'
    real_open = builtins.open

    def open_without_u(file, mode="r", *a, **k):
        return real_open(file, mode.replace("U", "") if isinstance(mode, str) else mode, *a, **k)

    builtins.open = open_without_u
    try:
        arms = armature_after(lambda: bpy.ops.import_anim.bvh(
            filepath=bvh, global_scale=0.01, frame_start=1, use_fps_scale=False, update_scene_fps=True,
            rotate_mode="NATIVE"))
    finally:
        builtins.open = real_open
    if len(arms) != 1:
        failures.append(f"{bvh}: {len(arms)} armatures imported, expected 1")
    else:
        check("bvh", arms[0], poses, 1, failures)

    for f in failures:
        print(f"FAILED: {f}", file=sys.stderr)
    print("blender import check", "FAILED" if failures else "passed")
    sys.stdout.flush()
    sys.exit(1 if failures else 0)


try:
    main()
except SystemExit:
    raise
except BaseException as e:  # an importer's exception must fail the run, not leave Blender at exit 0
    import traceback
    traceback.print_exc()
    sys.exit(1)
