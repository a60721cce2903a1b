"""ROS bags in and out: the reader (TF chains, PoseStamped, merging, fusion), the writer, the CLI.

Bags are written here with rosbags' own writers, ROS 1 (``.bag``) and ROS 2 (folder)."""
import json
from pathlib import Path

import numpy as np
import pytest

from estimator.config import EstimatorConfig
from estimator.filter import SceneEstimator
from estimator.observations import Frame, ObservationReader, write_observations
from experiments.cli import main
from experiments.ros.reader import BagFrameReader, read_bag_frames
from experiments.ros.topics import default_topics, load_topics
from experiments.ros.writer import ESTIMATE_TOPIC
from helpers import TABLE_TOP, det, table_scene
from physics.errors import ObservationError
from physics.transforms import pose_compose, quat_from_axis_angle

rosbags = pytest.importorskip("rosbags")
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
NS = 1_000_000_000
TF = "tf2_msgs/msg/TFMessage"
POSE = "geometry_msgs/msg/PoseStamped"


def stamp(t):
    ns = int(round(t * NS))
    return T["builtin_interfaces/msg/Time"](sec=ns // NS, nanosec=ns % NS)


def tfs(t, *edges):
    """A TFMessage at ``t`` (s) of edges (parent, child, pose (7,))."""
    out = []
    for parent, child, p in edges:
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]))
        out.append(T["geometry_msgs/msg/TransformStamped"](
            header=T["std_msgs/msg/Header"](stamp=stamp(t), frame_id=parent), child_frame_id=child, transform=tr))
    return T[TF](transforms=out)


def pose_msg(t, frame_id, p):
    pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                                       orientation=T["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]))
    return T[POSE](header=T["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame_id), pose=pose)


def write_bag(path, messages):
    """``messages``: (topic, msgtype, log time s, message); ``.bag`` -> ROS 1, else ROS 2."""
    path = Path(path)
    ros1 = path.suffix == ".bag"
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import Writer
        writer = Writer(path, version=8)
    with writer:
        conns = {}
        for topic, msgtype, log_t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=TS)
            data = TS.serialize_ros1(msg, msgtype) if ros1 else TS.serialize_cdr(msg, msgtype)
            writer.write(conns[topic], int(round(log_t * NS)), data)
    return str(path)


def P(x, y, z, q=(0, 0, 0, 1)):
    return np.array([x, y, z, *q], dtype=float)


SCENE_OBJECTS = ({"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}, "mass": 0.2,
                  "pose": {"position": [0.1, 0.0, TABLE_TOP + 0.05]}},
                 {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "mass": 0.2,
                  "pose": {"position": [-0.1, 0.1, TABLE_TOP + 0.03]}})
WORLD_TABLE = P(0.0, 0.0, 0.6, tuple(quat_from_axis_angle(np.array([0, 0, 1.0]), 0.3)))
TABLE_CAMERA = P(0.5, -0.2, 0.7, tuple(quat_from_axis_angle(np.array([0, 1.0, 0]), 0.6)))
CAMERA_TAG = P(0.05, 0.02, 0.9, tuple(quat_from_axis_angle(np.array([1.0, 0, 0]), 0.2)))


def cup_at(t):
    return P(0.1 + 0.1 * t, 0.0, TABLE_TOP + 0.05)


def multi_source_messages():
    """Static world->table->camera; dynamic world->cup on /tf; the box as a tag seen by the camera
    (camera->box_tag on /tf) and as a PoseStamped in the table frame; 30 Hz for 0.5 s; the PoseStamped
    messages are logged 0.05 s late (out of order within the 0.1 s window)."""
    msgs = [("/tf_static", TF, 0.0, tfs(0.0, ("world", "table_link", WORLD_TABLE), ("table_link", "camera", TABLE_CAMERA)))]
    for k in range(15):
        t = k / 30
        msgs.append(("/tf", TF, t, tfs(t, ("world", "cup", cup_at(t)))))
        msgs.append(("/tf", TF, t + 0.001, tfs(t + 0.001, ("camera", "box_tag", CAMERA_TAG))))
        msgs.append(("/tracker/box", POSE, t + 0.05, pose_msg(t + 0.002, "table_link", P(0.01 * k, 0.1, 0.2))))
    return msgs


TOPICS = """\
world_frame: world
sources:
  - topic: /tf
    type: tf
    objects: {cup: cup, box_tag: box}
    position_std: 0.01
  - topic: /tracker/box
    type: pose
    object: box
    position_std: 0.02
"""


@pytest.fixture(params=["ros1.bag", "ros2"])
def multi_bag(request, tmp_path):
    bag = write_bag(tmp_path / request.param, multi_source_messages())
    topics = tmp_path / "topics.yaml"
    topics.write_text(TOPICS)
    return bag, str(topics)


def test_frames_chain_tf_and_posestamped_and_fuse(multi_bag):
    bag, topics_path = multi_bag
    frames = read_bag_frames(bag, load_topics(topics_path, ["table", "cup", "box"]))
    assert len(frames) == 15
    box_tag = pose_compose(pose_compose(WORLD_TABLE, TABLE_CAMERA), CAMERA_TAG)
    for k, f in enumerate(frames):
        t = k / 30
        assert f.t == pytest.approx(t + 0.002, abs=1e-9)        # the frame's latest stamp
        np.testing.assert_allclose(f.objects["cup"].position, cup_at(t)[:3], atol=1e-9)
        assert f.objects["cup"].position_std == 0.01
        tracked = pose_compose(WORLD_TABLE, P(0.01 * k, 0.1, 0.2))
        w1, w2 = 1 / 0.01 ** 2, 1 / 0.02 ** 2                   # inverse variance
        fused = (w1 * box_tag[:3] + w2 * tracked[:3]) / (w1 + w2)
        np.testing.assert_allclose(f.objects["box"].position, fused, atol=1e-9)
        assert f.objects["box"].position_std == pytest.approx((w1 + w2) ** -0.5, abs=1e-12)
        np.testing.assert_allclose(f.objects["box"].orientation, box_tag[3:], atol=1e-9)  # most precise source
    assert abs(frames[0].objects["box"].position_std - 0.008944271909999) < 1e-12


def test_object_seen_by_one_source_is_perceived(tmp_path):
    msgs = [("/tf_static", TF, 0.0, tfs(0.0, ("world", "table_link", WORLD_TABLE))),
            ("/tf", TF, 0.0, tfs(0.0, ("world", "cup", cup_at(0)))),
            ("/tracker/box", POSE, 0.1, pose_msg(0.1, "table_link", P(0.0, 0.1, 0.2)))]
    bag = write_bag(tmp_path / "one.bag", msgs)
    (tmp_path / "t.yaml").write_text(TOPICS)
    frames = read_bag_frames(bag, load_topics(str(tmp_path / "t.yaml"), ["table", "cup", "box"]))
    assert [sorted(f.objects) for f in frames] == [["cup"], ["box"]]
    assert frames[1].objects["box"].position_std == 0.02
    np.testing.assert_allclose(frames[1].objects["box"].position,
                               pose_compose(WORLD_TABLE, P(0.0, 0.1, 0.2))[:3], atol=1e-12)


def test_out_of_order_messages_are_sorted_and_too_late_ones_dropped(tmp_path):
    msgs = [("/tf", TF, 0.00, tfs(0.00, ("world", "cup", cup_at(0.00)))),
            ("/tf", TF, 0.10, tfs(0.10, ("world", "cup", cup_at(0.10)))),
            ("/tf", TF, 0.11, tfs(0.05, ("world", "cup", cup_at(0.05)))),   # 0.06 s late: sorted
            ("/tf", TF, 0.40, tfs(0.40, ("world", "cup", cup_at(0.40)))),
            ("/tf", TF, 0.41, tfs(0.20, ("world", "cup", cup_at(0.20))))]   # 0.21 s late: dropped
    bag = write_bag(tmp_path / "order", msgs)
    warnings = []
    reader = BagFrameReader(bag, default_topics(["table", "cup"]), warn=warnings.append)
    frames = list(reader)
    assert [round(f.t, 6) for f in frames] == [0.0, 0.05, 0.1, 0.4]
    assert reader.late == 1 and "0.200 s arrived more than 0.1 s late" in warnings[0]


def test_missing_transform_is_reported_with_time_and_frames(tmp_path):
    msgs = [("/tf", TF, 0.0, tfs(0.0, ("world", "cup", cup_at(0)))),
            ("/tf", TF, 0.5, tfs(0.5, ("camera", "cup", cup_at(0.5))))]          # camera is not in the tree
    bag = write_bag(tmp_path / "gap.bag", msgs)
    with pytest.raises(ObservationError) as exc:
        read_bag_frames(bag, default_topics(["table", "cup"]))
    msg = str(exc.value)
    assert msg.startswith(f"{bag}: /tf: t=0.500 s: no transform from 'world' to 'cup'")
    assert "'camera'" in msg
    warnings = []
    reader = BagFrameReader(bag, default_topics(["table", "cup"]), skip_bad_frames=True, warn=warnings.append)
    assert len(list(reader)) == 1 and reader.skipped == 1 and "t=0.500 s" in warnings[0]


def test_malformed_topics_file_and_missing_bag_are_located(tmp_path):
    bad = tmp_path / "topics.yaml"
    bad.write_text(TOPICS.replace("object: box", "object: bowl"))
    with pytest.raises(ObservationError, match=r"topics.yaml:9: sources\[1\].object: unknown object id 'bowl'"):
        load_topics(str(bad), ["table", "cup", "box"])
    bad.write_text(TOPICS.replace("position_std: 0.02", "position_std: -1"))
    with pytest.raises(ObservationError, match=r"topics.yaml:10: sources\[1\].position_std: must be > 0"):
        load_topics(str(bad), ["table", "cup", "box"])
    bad.write_text(TOPICS.replace("type: pose", "type: odometry"))
    with pytest.raises(ObservationError, match=r"topics.yaml:8: sources\[1\].type: must be one of tf, pose"):
        load_topics(str(bad), ["table", "cup", "box"])
    with pytest.raises(ObservationError, match="bag not found"):
        read_bag_frames(str(tmp_path / "nope.bag"), default_topics(["cup"]))
    (tmp_path / "junk.bag").write_text("not a bag")
    with pytest.raises(ObservationError, match="junk.bag: not a readable ROS 1 or ROS 2 bag"):
        read_bag_frames(str(tmp_path / "junk.bag"), default_topics(["cup"]))
    for not_a_bag in (bad, tmp_path):            # a YAML file, a folder without a ROS 2 bag
        with pytest.raises(ObservationError, match="not a readable ROS 1 or ROS 2 bag"):
            read_bag_frames(str(not_a_bag), default_topics(["cup"]))
    bag = write_bag(tmp_path / "b.bag", [("/tf", TF, 0.0, tfs(0.0, ("world", "cup", cup_at(0))))])
    bad.write_text(TOPICS)
    with pytest.raises(ObservationError, match=r"topics.yaml:7: sources\[1\].topic: topic /tracker/box is not in"):
        read_bag_frames(bag, load_topics(str(bad), ["table", "cup", "box"]))


# -- the no-topics-file convention equals JSONL; estimates written back; the command line ------------

def lift_frames(n=45):
    """A box lifted off the table and put back, 30 Hz, as frames (t from 0 s)."""
    out = []
    for k in range(n):
        t = round(k / 30, 4)
        z = TABLE_TOP + 0.03 + (0.2 if 0.5 <= t < 1.0 else 0.0)
        out.append(Frame(t, {"box": det([-0.1, 0.1, z])}))
    return out


def frames_to_tf_bag(path, frames, extra=()):
    """The same frames as world->object transforms on /tf (log time = stamp), plus a static chain."""
    msgs = [("/tf_static", TF, 0.0, tfs(0.0, ("world", "table_link", WORLD_TABLE))), *extra]
    for f in frames:
        if not f.objects:
            continue  # nothing perceived: no message (a bag has no empty frames)
        msgs.append(("/tf", TF, f.t, tfs(f.t, *[("world", oid, np.concatenate([d.position, d.orientation]))
                                                for oid, d in f.objects.items()])))
    msgs.sort(key=lambda m: m[2])
    return write_bag(path, msgs)


def estimates(scene, frames):
    with SceneEstimator(scene, EstimatorConfig.paper(), np.random.default_rng(0)) as est:
        return [b.to_json() for b in (est.update(f) for f in frames) if b is not None]


@pytest.mark.parametrize("name", ["conv.bag", "conv"])
def test_no_topics_file_gives_the_estimates_of_the_same_jsonl(tmp_path, name):
    scene = table_scene(*SCENE_OBJECTS[1:])
    frames = lift_frames()
    write_observations(str(tmp_path / "o.jsonl"), frames)
    from_jsonl = list(ObservationReader(str(tmp_path / "o.jsonl"), scene.object_ids))
    bag = frames_to_tf_bag(tmp_path / name, frames)
    from_bag = read_bag_frames(bag, default_topics(scene.object_ids))
    assert [f.t for f in from_bag] == [f.t for f in from_jsonl]
    for a, b in zip(from_bag, from_jsonl):
        assert a.to_json() == b.to_json()
    e_bag, e_jsonl = estimates(scene, from_bag), estimates(scene, from_jsonl)
    assert len(e_bag) > 5 and e_bag == e_jsonl


def test_particles_same_estimates_from_bag_and_jsonl(tmp_path):
    """Small K, seeded: the bag and the JSONL stream drive the filter identically."""
    scene = table_scene(*SCENE_OBJECTS[1:])
    frames = lift_frames(20)
    write_observations(str(tmp_path / "o.jsonl"), frames)
    bag = frames_to_tf_bag(tmp_path / "k.bag", frames)
    cfg = EstimatorConfig(particles=4, workers=0)
    runs = []
    for stream in (read_bag_frames(bag, default_topics(scene.object_ids)),
                   list(ObservationReader(str(tmp_path / "o.jsonl"), scene.object_ids))):
        with SceneEstimator(scene, cfg, np.random.default_rng(3)) as est:
            runs.append([b.to_json() for b in (est.update(f) for f in stream) if b is not None])
    assert runs[0] == runs[1] and len(runs[0]) >= 3


def write_scene(tmp_path):
    import yaml

    from physics.scene import scene_to_dict
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene_to_dict(table_scene(*SCENE_OBJECTS[1:]))))
    return str(path)


@pytest.mark.parametrize("out_name", ["annotated.bag", "annotated"])
def test_cli_end_to_end_with_bag_out(tmp_path, capsys, out_name):
    scene = write_scene(tmp_path)
    bag = frames_to_tf_bag(tmp_path / "in.bag", lift_frames(30))
    out, bag_out = tmp_path / "e.jsonl", tmp_path / out_name
    code = main(["run", "--scene", scene, "--bag", bag, "--out", str(out), "--bag-out", str(bag_out), "--quiet",
                 "--paper"])
    assert code == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) >= 5
    with AnyReader([bag_out]) as reader:
        assert set(reader.topics) == {"/tf", ESTIMATE_TOPIC}
        tf_msgs, strings = [], []
        for conn, log_ns, raw in reader.messages(connections=reader.connections):
            msg = reader.deserialize(raw, conn.msgtype)
            (tf_msgs if conn.topic == "/tf" else strings).append((log_ns, msg))
    assert len(tf_msgs) == len(strings) == len(lines)
    assert [json.loads(m.data) for _, m in strings] == lines
    for (log_ns, m), line in zip(tf_msgs, lines):
        assert log_ns == int(round(line["t"] * NS))
        assert [t.child_frame_id for t in m.transforms] == [f"estimate/{oid}" for oid in line["objects"]]
        assert all(t.header.frame_id == "world" for t in m.transforms)
        box = next(t for t in m.transforms if t.child_frame_id == "estimate/box").transform.translation
        assert [box.x, box.y, box.z] == line["objects"]["box"]["position"]


def test_cli_bad_input_exits_2_with_a_located_message(tmp_path, capsys):
    scene = write_scene(tmp_path)
    bag = frames_to_tf_bag(tmp_path / "in.bag", lift_frames(3))
    assert main(["run", "--scene", scene, "--bag", str(tmp_path / "missing.bag"), "--quiet", "--paper"]) == 2
    assert f"error: {tmp_path / 'missing.bag'}: bag not found" in capsys.readouterr().err
    topics = tmp_path / "topics.yaml"
    topics.write_text("sources:\n  - topic: /tf\n    type: tf\n    objects: {box: bowl}\n")
    assert main(["run", "--scene", scene, "--bag", bag, "--topics", str(topics), "--quiet", "--paper"]) == 2
    assert f"error: {topics}:4: sources[0].objects.box: unknown object id 'bowl'" in capsys.readouterr().err
    topics.write_text("sources:\n  - topic: /camera/tags\n    type: tf\n")
    assert main(["run", "--scene", scene, "--bag", bag, "--topics", str(topics), "--quiet", "--paper"]) == 2
    assert f"error: {topics}:2: sources[0].topic: topic /camera/tags is not in" in capsys.readouterr().err
    assert main(["run", "--scene", scene, "--bag", bag, "--bag-out", bag, "--quiet", "--paper"]) == 2
    assert f"error: --bag-out: {bag} is the same file as --bag {bag} (an input)" in capsys.readouterr().err
    other = frames_to_tf_bag(tmp_path / "other.bag", lift_frames(3))
    assert main(["run", "--scene", scene, "--bag", bag, "--bag-out", other, "--quiet", "--paper"]) == 2
    assert f"error: {other}: output bag already exists" in capsys.readouterr().err
    assert main(["run", "--scene", scene, "--observations", "o.jsonl", "--topics", str(topics), "--paper"]) == 2
    assert "error: --topics needs --bag" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["run", "--scene", scene, "--bag", bag, "--observations", "o.jsonl"])
    assert exc.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_hands_and_another_world_frame(tmp_path):
    """Hands come from TF frames named in the topics file; --world-frame 'map' (map -> world here)."""
    map_world = P(1.0, 2.0, 0.0, tuple(quat_from_axis_angle(np.array([0, 0, 1.0]), 0.5)))
    msgs = [("/tf_static", TF, 0.0, tfs(0.0, ("map", "world", map_world))),
            ("/tf", TF, 0.0, tfs(0.0, ("world", "cup", cup_at(0)), ("world", "r_hand", P(0.3, -0.1, 0.9))))]
    bag = write_bag(tmp_path / "h", msgs)
    topics = tmp_path / "t.yaml"
    topics.write_text("sources:\n  - {topic: /tf, type: tf, objects: {cup: cup}, position_std: 0.01}\n"
                      "hands: {r_hand: human/right}\n")
    (frame,) = read_bag_frames(bag, load_topics(str(topics), ["table", "cup"], world_frame="map"))
    np.testing.assert_allclose(frame.hands["human/right"], pose_compose(map_world, P(0.3, -0.1, 0.9))[:3], atol=1e-12)
    np.testing.assert_allclose(frame.objects["cup"].position, pose_compose(map_world, cup_at(0))[:3], atol=1e-12)
    (frame,) = read_bag_frames(bag, load_topics(str(topics), ["table", "cup"]))   # the file's world frame
    np.testing.assert_allclose(frame.hands["human/right"], [0.3, -0.1, 0.9], atol=1e-12)


def test_truncated_bag_is_an_input_error(tmp_path):
    bag = frames_to_tf_bag(tmp_path / "cut.bag", lift_frames(30))
    data = Path(bag).read_bytes()
    Path(bag).write_bytes(data[: len(data) // 2])
    with pytest.raises(ObservationError, match="cut.bag: "):
        read_bag_frames(bag, default_topics(["table", "box"]))


def test_window_zero_gives_one_frame_per_distinct_stamp(tmp_path):
    msgs = [("/tf", TF, 0.0, tfs(0.0, ("world", "cup", cup_at(0.0)))),
            ("/tf", TF, 0.0, tfs(0.0, ("world", "box_tag", P(0, 0, 1)))),
            ("/tf", TF, 0.005, tfs(0.005, ("world", "cup", cup_at(0.005))))]
    bag = write_bag(tmp_path / "w.bag", msgs)
    topics = tmp_path / "t.yaml"
    topics.write_text("window: 0\nsources:\n  - {topic: /tf, type: tf, objects: {cup: cup, box_tag: box}}\n")
    frames = read_bag_frames(bag, load_topics(str(topics), ["table", "cup", "box"]))
    assert [(f.t, sorted(f.objects)) for f in frames] == [(0.0, ["box", "cup"]), (0.005, ["cup"])]
    frames = read_bag_frames(bag, default_topics(["table", "cup", "box"]))     # 0.02 s window: one frame
    assert [(f.t, sorted(f.objects)) for f in frames] == [(0.005, ["cup"])]    # box_tag is not an object id


def test_pose_in_a_moving_frame_uses_the_transform_at_its_own_time(tmp_path):
    """The camera moves (world->camera on /tf); a PoseStamped in the camera frame is placed with the
    latest camera transform *at its stamp*, even when that transform was logged after it."""
    cam = {t: P(t, 0.0, 1.0, tuple(quat_from_axis_angle(np.array([0, 0, 1.0]), t))) for t in (0.0, 0.1, 0.2)}
    in_cam = P(0.3, 0.1, -0.2)
    msgs = [("/tf", TF, 0.0, tfs(0.0, ("world", "camera", cam[0.0]))),
            ("/tracker/box", POSE, 0.05, pose_msg(0.05, "camera", in_cam)),
            ("/tracker/box", POSE, 0.15, pose_msg(0.15, "camera", in_cam)),
            ("/tf", TF, 0.16, tfs(0.1, ("world", "camera", cam[0.1]))),     # logged 0.06 s late
            ("/tf", TF, 0.2, tfs(0.2, ("world", "camera", cam[0.2]))),
            ("/tracker/box", POSE, 0.25, pose_msg(0.25, "camera", in_cam))]
    bag = write_bag(tmp_path / "moving", msgs)
    topics = tmp_path / "t.yaml"
    topics.write_text("sources:\n  - {topic: /tracker/box, type: pose, object: box, position_std: 0.01}\n")
    frames = read_bag_frames(bag, load_topics(str(topics), ["table", "box"]))
    assert [round(f.t, 6) for f in frames] == [0.05, 0.15, 0.25]
    for f, t_cam in zip(frames, (0.0, 0.1, 0.2)):
        expected = pose_compose(cam[t_cam], in_cam)
        np.testing.assert_allclose(f.objects["box"].position, expected[:3], atol=1e-9)
        np.testing.assert_allclose(f.objects["box"].orientation, expected[3:], atol=1e-9)


# -- property-based: damaged bags and arbitrary topics files give frames or a located input error ----------

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st

from helpers import fuzz_settings, json_values  # noqa: E402
from physics.errors import InputError  # noqa: E402

_BAG_BYTES: dict[str, bytes] = {}


def _ros1_bag_bytes(tmp_path_factory) -> bytes:
    if "ros1" not in _BAG_BYTES:
        path = tmp_path_factory.mktemp("bag") / "clean.bag"
        write_bag(path, multi_source_messages())
        _BAG_BYTES["ros1"] = path.read_bytes()
    return _BAG_BYTES["ros1"]


@fuzz_settings(150)
@given(st.data())
def test_a_damaged_bag_gives_finite_frames_or_a_located_error(tmp_path_factory, data):
    clean = _ros1_bag_bytes(tmp_path_factory)
    damaged = bytearray(clean)
    if data.draw(st.booleans(), label="truncate"):
        damaged = damaged[:data.draw(st.integers(0, len(clean) - 1), label="length")]
    for _ in range(data.draw(st.integers(0, 8), label="flips")):
        if damaged:
            damaged[data.draw(st.integers(0, len(damaged) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path_factory.mktemp("damaged") / "d.bag"
    path.write_bytes(bytes(damaged))
    try:
        frames = read_bag_frames(str(path), default_topics(["table", "cup", "box"]),
                                 skip_bad_frames=data.draw(st.booleans(), label="skip"))
    except InputError as exc:
        assert str(path) in str(exc)
        return
    assert all(b.t > a.t for a, b in zip(frames, frames[1:]))
    for f in frames:
        assert np.isfinite(f.t) and all(np.isfinite(d.position).all() for d in f.objects.values())


@fuzz_settings(300)
@given(json_values())
def test_any_topics_file_gives_topics_or_a_located_error(tmp_path_factory, content):
    path = tmp_path_factory.mktemp("topics") / "topics.yaml"
    path.write_text(json.dumps(content))
    try:
        load_topics(str(path), ["table", "cup", "box"])
    except InputError as exc:
        assert str(path) in str(exc)
