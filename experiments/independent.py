"""Recordings made independently of the project's scenario simulator: hand-written MuJoCo scripts with
their own camera, tracker noise and object sizes, for checking the estimator on data that none of its
priors, thresholds or scenarios were fitted on.

Each recording is a short MJCF world (MuJoCo's soft contacts, friction pyramid and integrator, not
Bullet's), a scripted hand (a mocap body: a grasp is a weld switched on, a push is its collision
sphere), a pinhole camera whose visibility is decided by MuJoCo ray casts, and a tracker that
reports what the camera sees with Gaussian noise and a height bias. :func:`record` returns the scene
the estimator is given (a scene dict in the project's format, with nominal parameters), the
observation frames (dicts in the observation format) and the truth per frame. Nothing here imports
the estimator or the project's simulator: the only shared piece is the file format.

Units: metres, seconds; quaternions in the returned data are ``(x, y, z, w)`` (MuJoCo's are
``(w, x, y, z)``).

Recordings: :data:`~experiments.independent_recordings.RECORDINGS`.
"""
from __future__ import annotations

import math

import numpy as np

from experiments.independent_recordings import CAMERA, RECORDINGS, Body, HandScript, Recording

HZ = 30.0
"""Hz: the tracker's frame rate."""

TIME_STEP = 0.002
"""s: MuJoCo's integration step; a frame is taken at the first step at or after its time."""

HAND = "human/right"


# --------------------------------------------------------------------------------------------------
# the MuJoCo world


def _geoms(b: Body, contact: str) -> str:
    rgba = 'rgba="0.6 0.6 0.6 1"'
    if b.kind == "box":
        hx, hy, hz = (v / 2 for v in b.size)
        return f'<geom type="box" size="{hx} {hy} {hz}" {contact} {rgba}/>'
    if b.kind == "sphere":
        return f'<geom type="sphere" size="{b.radius}" {contact} {rgba}/>'
    if b.kind == "cylinder":
        return f'<geom type="cylinder" size="{b.radius} {b.height / 2}" {contact} {rgba}/>'
    if b.kind == "bin":
        sx, sy, sz = b.size
        w = b.wall
        walls = [((0, 0, -sz / 2 + w / 2), (sx / 2, sy / 2, w / 2)),
                 ((sx / 2 - w / 2, 0, 0), (w / 2, sy / 2, sz / 2)), ((-sx / 2 + w / 2, 0, 0), (w / 2, sy / 2, sz / 2)),
                 ((0, sy / 2 - w / 2, 0), (sx / 2 - w, w / 2, sz / 2)), ((0, -sy / 2 + w / 2, 0), (sx / 2 - w, w / 2, sz / 2))]
        return "".join(f'<geom type="box" pos="{c[0]} {c[1]} {c[2]}" size="{h[0]} {h[1]} {h[2]}" {contact} {rgba}/>'
                       for c, h in walls)
    raise ValueError(f"unknown body kind {b.kind!r}")


def _mjcf(rec: Recording) -> str:
    bodies = []
    for b in rec.bodies:
        condim = 6 if b.kind == "sphere" or b.rolling > 0 else 4
        # soft contacts of real-world stiffness (MuJoCo's defaults), friction: sliding, torsional, rolling
        contact = f'friction="{b.friction} 0.002 {b.rolling}" condim="{condim}"'
        if not b.static:
            contact += f' mass="{b.mass / (5 if b.kind == "bin" else 1)}"'
        pos = " ".join(str(v) for v in b.position)
        inner = _geoms(b, contact)
        if b.static:
            bodies.append(f'<body name="{b.id}" pos="{pos}">{inner}</body>')
        else:
            bodies.append(f'<body name="{b.id}" pos="{pos}"><freejoint name="{b.id}_free"/>{inner}</body>')
    hand = ""
    eq = ""
    if rec.hand is not None:
        bits = 'contype="2" conaffinity="0"' if rec.hand.collide else 'contype="0" conaffinity="0"'
        hp = " ".join(str(v) for v in rec.hand.start)
        hand = (f'<body name="hand" mocap="true" pos="{hp}"><geom type="sphere" size="{rec.hand.radius}" {bits} '
                f'rgba="1 0.8 0.6 1"/></body>')
        welds = [b.id for b in rec.bodies if not b.static]
        eq = "<equality>" + "".join(f'<weld name="grip_{w}" body1="hand" body2="{w}" active="false"/>'
                                    for w in welds) + "</equality>"
    return f"""<mujoco model="{rec.name}">
  <option timestep="{TIME_STEP}" integrator="implicitfast" cone="elliptic"/>
  <default><geom contype="1" conaffinity="3" solref="0.01 1"/></default>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1" friction="0.8 0.002 0.0005"/>
    {''.join(bodies)}
    {hand}
  </worldbody>
  {eq}
</mujoco>"""


def _smooth(t: float, t0: float, t1: float) -> float:
    s = min(max((t - t0) / max(t1 - t0, 1e-9), 0.0), 1.0)
    return 3 * s * s - 2 * s ** 3


def _hand_at(script: HandScript, t: float) -> np.ndarray:
    p0, t0 = np.asarray(script.start, float), 0.0
    for t1, p1 in script.waypoints:
        p1 = np.asarray(p1, float)
        if t <= t1:
            return p0 + (p1 - p0) * _smooth(t, t0, t1)
        p0, t0 = p1, t1
    return p0


def _quat_xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    q = np.array([q_wxyz[1], q_wxyz[2], q_wxyz[3], q_wxyz[0]], float)
    return -q if q[3] < 0 else q


def _sample_points(b: Body, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` points inside body ``b``, in its frame."""
    if b.kind in ("box", "bin"):
        return rng.uniform(-0.42, 0.42, (n, 3)) * np.asarray(b.size)
    if b.kind == "sphere":
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * (0.85 * b.radius * rng.random((n, 1)) ** (1 / 3))
    a = rng.uniform(0, 2 * math.pi, n)
    r = 0.85 * b.radius * np.sqrt(rng.random(n))
    return np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(-0.42, 0.42, n) * b.height], axis=1)


def record(name: str, seed: int = 0) -> tuple[dict, list[dict], list[dict]]:
    """Simulate recording ``name`` (see :data:`RECORDINGS`) with the tracker noise drawn from
    ``numpy.random.default_rng(seed)``. Returns ``(scene, frames, truth)``: the scene dict the
    estimator is given (nominal masses and frictions, initial poses as placed, not settled), the
    observation frames (30 Hz, format of ``observations.jsonl``), and per frame the true state
    ``{"t", "objects": {id: {"position", "orientation", "visible", "held"}}, "hand"}``."""
    import mujoco

    rec = RECORDINGS[name]
    rng = np.random.default_rng(seed)
    model = mujoco.MjModel.from_xml_string(_mjcf(rec))
    data = mujoco.MjData(model)
    ids = {b.id: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b.id) for b in rec.bodies}
    flicks = [b for b in rec.bodies if not b.static and any(b.velocity)]
    welds = {b.id: k for k, b in enumerate(b for b in rec.bodies if not b.static)}
    cam = np.asarray(CAMERA["position"], float)
    target = np.asarray(CAMERA["target"], float)
    fwd = (target - cam) / np.linalg.norm(target - cam)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tan_v = math.tan(math.radians(CAMERA["fov_deg"]) / 2)
    tan_h = tan_v * CAMERA["aspect"]
    points = {b.id: _sample_points(b, 24, np.random.default_rng(len(b.id) * 7919 + 17)) for b in rec.bodies}
    geom_body = model.geom_bodyid
    held: str | None = None

    def grip(oid: str, on: bool) -> None:
        if on:  # the weld keeps the relative pose of the moment (relpose set from the bodies' poses)
            k = welds[oid]
            hp, hq = data.mocap_pos[0].copy(), data.mocap_quat[0].copy()
            op, oq = data.xpos[ids[oid]].copy(), data.xquat[ids[oid]].copy()
            inv = np.empty(4)
            mujoco.mju_negQuat(inv, hq)
            rel_p = np.empty(3)
            mujoco.mju_rotVecQuat(rel_p, op - hp, inv)
            rel_q = np.empty(4)
            mujoco.mju_mulQuat(rel_q, inv, oq)
            model.eq_data[k, 3:6] = rel_p
            model.eq_data[k, 6:10] = rel_q
            model.eq_data[k, 10] = 1.0
        data.eq_active[welds[oid]] = int(on)

    if rec.hand is not None and rec.hand.holding:
        mujoco.mj_forward(model, data)
        grip(rec.hand.holding, True)
        held = rec.hand.holding
    frames: list[dict] = []
    truth: list[dict] = []
    n_frames = int(rec.duration * HZ)
    bias = {b.id: rec.height_bias * (0.5 + rng.random()) for b in rec.bodies}
    step = 0
    for j in range(n_frames + 1):
        t_frame = j / HZ
        while step * TIME_STEP < t_frame - 1e-12:
            t = step * TIME_STEP
            for b in flicks:
                if abs(t - b.flick_t) < TIME_STEP / 2:  # a flick: the ball rolls off at its velocity
                    j = model.body_jntadr[ids[b.id]]
                    dof = model.jnt_dofadr[j]
                    data.qvel[dof:dof + 3] = b.velocity
                    r = b.radius or 0.0
                    if r > 0:  # rolling, not sliding: spin about the horizontal axis across the motion
                        v = np.asarray(b.velocity, float)
                        data.qvel[dof + 3:dof + 6] = np.cross([0.0, 0.0, 1.0], v) / r
            if rec.hand is not None:
                data.mocap_pos[0] = _hand_at(rec.hand, t)
                if rec.hand.grasp and held is None and t >= rec.hand.grasp[0] and rec.hand.release and \
                        t < rec.hand.release[0]:
                    grip(rec.hand.grasp[1], True)
                    held = rec.hand.grasp[1]
                if rec.hand.release and held is not None and t >= rec.hand.release[0]:
                    grip(held, False)
                    held = None
            mujoco.mj_step(model, data)
            step += 1
        mujoco.mj_forward(model, data)
        objects_true, seen = {}, {}
        for b in rec.bodies:
            bid = ids[b.id]
            pos = data.xpos[bid].copy()
            R = data.xmat[bid].reshape(3, 3)
            pts = pos + points[b.id] @ R.T
            vis = 0
            for p in pts:
                d = p - cam
                rel = np.array([d @ right, d @ up, d @ fwd])
                if rel[2] <= 0.1 or abs(rel[0]) > tan_h * rel[2] or abs(rel[1]) > tan_v * rel[2]:
                    continue
                gid = np.array([-1], dtype=np.int32)
                dist = mujoco.mj_ray(model, data, cam, d, None, 1, -1, gid)
                if gid[0] >= 0 and geom_body[gid[0]] == bid and dist <= 1.0 + 1e-6:
                    vis += 1
            visible = vis / len(pts) >= 0.3
            q = _quat_xyzw(data.xquat[bid])
            objects_true[b.id] = {"position": pos.round(5).tolist(), "orientation": q.round(5).tolist(),
                                  "visible": bool(visible), "held": held == b.id}
            if visible and b.tracked and not b.static:
                noisy = pos + rng.normal(0, rec.position_std, 3) + [0, 0, bias[b.id]]
                det: dict = {"position": noisy.round(5).tolist()}
                if b.kind != "sphere":
                    ax = rng.normal(0, math.radians(rec.orientation_std_deg), 3)
                    half = np.linalg.norm(ax) / 2
                    dq = np.concatenate([ax / max(2 * half, 1e-12) * math.sin(half), [math.cos(half)]])
                    qn = _qmul(dq, q)
                    det["orientation"] = (qn / np.linalg.norm(qn)).round(5).tolist()
                seen[b.id] = det
        frame: dict = {"t": round(t_frame, 5), "objects": seen}
        hand_true = None
        if rec.hand is not None:
            hand_true = data.mocap_pos[0].copy()
            if t_frame <= rec.hand.tracked_until:
                frame["hands"] = {HAND: (hand_true + rng.normal(0, rec.hand_std, 3)).round(5).tolist()}
        if j > 0:  # the first frame at t = 0 is not reported (the stream starts at 1/HZ)
            frames.append(frame)
            truth.append({"t": round(t_frame, 5), "objects": objects_true,
                          "hand": None if hand_true is None else hand_true.round(5).tolist()})
    return _scene(rec), frames, truth


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def _scene(rec: Recording) -> dict:
    """The scene the estimator is given: the true shapes and initial poses, nominal parameters."""
    objects = []
    for b in rec.bodies:
        o: dict = {"id": b.id, "pose": {"position": list(b.position)}}
        if b.kind == "bin":
            o["container"] = {"size": list(b.size), "wall": b.wall}
        elif b.kind == "box":
            o["box"] = {"size": list(b.size)}
        elif b.kind == "sphere":
            o["sphere"] = {"radius": b.radius}
        else:
            o["cylinder"] = {"radius": b.radius, "height": b.height}
        if b.static:
            o["static"] = True
        else:
            o["mass"] = b.mass
            o["friction"] = b.friction
            if b.rolling:
                o["rolling_friction"] = b.rolling
        objects.append(o)
    return {"name": rec.name, "camera": dict(CAMERA), "objects": objects}


def write(name: str, out_dir: str, seed: int = 0) -> None:
    """Write recording ``name`` as ``scene.yaml``, ``observations.jsonl`` and ``truth.jsonl`` in
    ``out_dir``."""
    import json
    import os

    import yaml

    scene, frames, truth = record(name, seed)
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "scene.yaml"), "w", encoding="utf-8") as f:
        yaml.safe_dump(scene, f, sort_keys=False)
    for fname, rows in (("observations.jsonl", frames), ("truth.jsonl", truth)):
        with open(os.path.join(out_dir, fname), "w", encoding="utf-8") as f:
            for r in rows:
                f.write(json.dumps(r) + "\n")

